//! Conditioned coupling layer (Dinh et al. 2017; Ardizzone et al. 2019, "Guided image
//! generation with conditional invertible neural networks"):
//!
//! `y_kept = x_kept`, `y_i = h(x_i; θ_i)` for the transformed dimensions, with
//! `θ = MLP([x_kept, c])`. The Jacobian is triangular, so `log|det| = Σ_i log|h'(x_i)|`,
//! and the inverse evaluates the same `θ` from `y_kept = x_kept`.
//!
//! Even layers keep the first `⌊d/2⌋` dimensions, odd layers the last ones, so every
//! dimension is transformed even when the mixing layers stay close to the identity.

use std::ops::Range;

use super::affine::AffineTransform;
use super::config::{CouplingKind, FlowConfig};
use super::error::FlowResult;
use super::mlp::{Mlp, MlpScratch};
use super::scalar::Scalar;
use super::spline::SplineTransform;
use super::weights::Weights;

#[derive(Clone, Copy, Debug)]
pub enum Transform {
    Affine(AffineTransform),
    Spline(SplineTransform),
}

impl Transform {
    pub fn new(kind: &CouplingKind) -> Self {
        match *kind {
            CouplingKind::Affine { scale_bound } => Self::Affine(AffineTransform { scale_bound }),
            CouplingKind::Spline { bins, tail_bound } => {
                Self::Spline(SplineTransform { bins, tail_bound })
            }
        }
    }

    fn scratch_len(&self) -> usize {
        match self {
            Self::Affine(_) => 0,
            Self::Spline(s) => s.scratch_len(),
        }
    }
}

#[derive(Clone, Debug)]
pub struct Coupling {
    transform: Transform,
    conditioner: Mlp,
    kept: Range<usize>,
    transformed: Range<usize>,
    params_per_dim: usize,
}

/// Buffers of one coupling evaluation.
#[derive(Clone, Debug)]
pub struct CouplingScratch<S> {
    input: Vec<S>,
    params: Vec<S>,
    transform: Vec<S>,
    mlp: MlpScratch<S>,
}

impl<S: Scalar> CouplingScratch<S> {
    pub fn new(coupling: &Coupling) -> Self {
        Self {
            input: vec![S::constant(0.0); coupling.conditioner.input_dim()],
            params: vec![S::constant(0.0); coupling.conditioner.output_dim()],
            transform: vec![S::constant(0.0); coupling.transform.scratch_len()],
            mlp: MlpScratch::new(&coupling.conditioner),
        }
    }
}

impl Coupling {
    /// Coupling layer `index` of `config`, parameters under `{prefix}.conditioner`.
    pub fn from_weights(
        weights: &mut Weights,
        prefix: &str,
        index: usize,
        config: &FlowConfig,
    ) -> FlowResult<Self> {
        let (d, kept_dim) = (config.state_dim, config.kept_dim());
        let (kept, transformed) = if index.is_multiple_of(2) {
            (0..kept_dim, kept_dim..d)
        } else {
            (d - kept_dim..d, 0..d - kept_dim)
        };
        Ok(Self {
            transform: Transform::new(&config.coupling),
            conditioner: Mlp::from_weights(
                weights,
                &format!("{prefix}.conditioner"),
                &config.conditioner_sizes(),
            )?,
            kept,
            transformed,
            params_per_dim: config.coupling.params_per_dim(),
        })
    }

    fn condition<S: Scalar>(&self, x: &[S], context: &[f64], scratch: &mut CouplingScratch<S>) {
        let kept = self.kept.len();
        scratch.input[..kept].copy_from_slice(&x[self.kept.clone()]);
        for (slot, c) in scratch.input[kept..].iter_mut().zip(context) {
            *slot = S::constant(*c);
        }
        self.conditioner
            .eval(&scratch.input, &mut scratch.mlp, &mut scratch.params);
    }

    /// Applies `h` (or `h⁻¹` when `inverse`) in place; returns the log-determinant.
    fn apply<S: Scalar>(
        &self,
        x: &mut [S],
        context: &[f64],
        scratch: &mut CouplingScratch<S>,
        inverse: bool,
    ) -> S {
        self.condition(x, context, scratch);
        let mut log_det = S::constant(0.0);
        let params = scratch.params.chunks_exact(self.params_per_dim);
        for (xi, theta) in x[self.transformed.clone()].iter_mut().zip(params) {
            let (value, ld) = match (&self.transform, inverse) {
                (Transform::Affine(t), false) => t.forward(*xi, theta),
                (Transform::Affine(t), true) => t.inverse(*xi, theta),
                (Transform::Spline(t), false) => t.forward(*xi, theta, &mut scratch.transform),
                (Transform::Spline(t), true) => t.inverse(*xi, theta, &mut scratch.transform),
            };
            *xi = value;
            log_det += ld;
        }
        log_det
    }

    /// `x ← coupling(x)`; returns `log|det ∂y/∂x|`.
    pub fn forward<S: Scalar>(
        &self,
        x: &mut [S],
        context: &[f64],
        scratch: &mut CouplingScratch<S>,
    ) -> S {
        self.apply(x, context, scratch, false)
    }

    /// `x ← coupling⁻¹(x)`; returns `log|det ∂x/∂y|`.
    pub fn inverse<S: Scalar>(
        &self,
        x: &mut [S],
        context: &[f64],
        scratch: &mut CouplingScratch<S>,
    ) -> S {
        self.apply(x, context, scratch, true)
    }
}
