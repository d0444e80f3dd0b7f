//! Conditioned coupling layer (Dinh et al. 2017; Ardizzone et al. 2019, "Guided image
//! generation with conditional invertible neural networks"):
//!
//! `y_kept = x_kept`, `y_i = h(x_i; θ_i)` for the transformed dimensions, with
//! `θ = MLP([x_kept, c])` ([`crate::flow::layers::conditioner`], which also pools local features of the
//! context's sets). The Jacobian is triangular, so `log|det| = Σ_i log|h'(x_i)|`,
//! and the inverse evaluates the same `θ` from `y_kept = x_kept`.
//!
//! Even layers keep the first `⌊d/2⌋` dimensions, odd layers the last ones, so every
//! dimension is transformed even when the mixing layers stay close to the identity.
//!
//! An affine coupling with a taper radius scales `θ` by `w(x_kept)`
//! ([`crate::flow::layers::taper`]); the records keep the conditioner's own outputs `θ̂`,
//! and each tangent applies `w` in its own dual numbers.

use std::ops::Range;

use crate::flow::checkpoint::config::{CouplingKind, FlowConfig};
use crate::flow::checkpoint::weights::Weights;
use crate::flow::error::FlowResult;
use crate::flow::layers::affine::AffineTransform;
use crate::flow::layers::conditioner::{
    Conditioner, ConditionerScratch, ConditionerTangentScratch,
};
use crate::flow::layers::spline::SplineTransform;
use crate::flow::layers::taper::Taper;
#[cfg(target_arch = "x86_64")]
use crate::math::simd::has_avx2_fma;
use crate::nn::scalar::{Dual, Scalar};

#[derive(Clone, Copy, Debug)]
pub enum Transform {
    Affine(AffineTransform),
    Spline(SplineTransform),
}

impl Transform {
    pub fn new(kind: &CouplingKind) -> Self {
        match *kind {
            CouplingKind::Affine { scale_bound, .. } => {
                Self::Affine(AffineTransform::new(scale_bound))
            }
            CouplingKind::Spline { bins, tail_bound } => {
                Self::Spline(SplineTransform::new(bins, tail_bound))
            }
        }
    }

    /// `x_i ← h(x_i; θ_i)` (or `h⁻¹` when `inverse`) for every transformed coordinate
    /// (at least one), `θ_i` the `i`-th of as many equal chunks of `params`; returns
    /// `Σ log|h'|`, which may be left zero unless `log_det`. The transform's primal values
    /// ([`AffineTransform::primal_scales`], [`SplineTransform::primal_knots`]) are
    /// computed into `primal`, or read from the record of a pass through the same point
    /// (forward passes only).
    #[inline(always)]
    fn apply_all<S: Scalar, const FUSED: bool>(
        &self,
        xs: &mut [S],
        params: &[S],
        primal: Primal,
        inverse: bool,
        log_det: bool,
    ) -> S {
        let primal = match primal {
            Primal::Compute(buffer) => {
                match self {
                    Self::Affine(t) => t.primal_scales::<S, FUSED>(params, inverse, buffer),
                    Self::Spline(t) => t.primal_knots::<S, FUSED>(xs, params, inverse, buffer),
                }
                &*buffer
            }
            Primal::Recorded(recorded) => {
                debug_assert!(
                    !inverse,
                    "recorded primal values are the forward direction's"
                );
                recorded
            }
        };
        match self {
            Self::Affine(t) => t.apply_all(xs, params, inverse, primal),
            Self::Spline(t) => t.apply_all(xs, params, inverse, primal, log_det),
        }
    }

    /// Length of the primal values of `transformed` coordinates.
    fn primal_len(&self, transformed: usize) -> usize {
        match self {
            Self::Affine(_) => 2 * transformed,
            Self::Spline(t) => t.primal_len() * transformed,
        }
    }

    /// Records the primal values `computed` by a pass in direction `inverse` as the
    /// forward direction's, for the forward passes through the same point.
    fn record_primal(&self, computed: &[f64], inverse: bool, record: &mut [f64]) {
        match self {
            Self::Affine(_) => {
                // `[tanh…, e^{±s}…]`: the forward passes need `e^{+s}`.
                let (tanh, exp) = computed.split_at(computed.len() / 2);
                let (recorded_tanh, recorded_exp) = record.split_at_mut(tanh.len());
                recorded_tanh.copy_from_slice(tanh);
                for (r, e) in recorded_exp.iter_mut().zip(exp) {
                    *r = if inverse { 1.0 / e } else { *e };
                }
            }
            // A bin found in `y` holds the `x` the inverse returns.
            Self::Spline(_) => record.copy_from_slice(computed),
        }
    }
}

/// Where [`Transform::apply_all`] takes the transform's primal values from.
enum Primal<'a> {
    /// Computed into this buffer.
    Compute(&'a mut [f64]),
    /// Recorded by a pass through the same point, forward direction.
    Recorded(&'a [f64]),
}

#[derive(Clone, Debug)]
pub struct Coupling {
    transform: Transform,
    conditioner: Conditioner,
    taper: Option<Taper>,
    kept: Range<usize>,
    transformed: Range<usize>,
}

/// Buffers of one coupling evaluation.
#[derive(Clone, Debug)]
pub struct CouplingScratch<S> {
    /// A state-sized buffer for the layers around the coupling (the mixing).
    pub(crate) state: Vec<S>,
    params: Vec<S>,
    primal: Vec<f64>,
    conditioner: ConditionerScratch<S>,
}

impl<S: Scalar> CouplingScratch<S> {
    pub fn new(coupling: &Coupling) -> Self {
        Self {
            state: vec![S::constant(0.0); coupling.state_dim()],
            params: vec![S::constant(0.0); coupling.conditioner.output_dim()],
            primal: vec![0.0; coupling.primal_len()],
            conditioner: ConditionerScratch::new(&coupling.conditioner),
        }
    }
}

/// Values of one recorded coupling evaluation that its forward tangents reuse, for a
/// scalar type of `lanes` components: `f64` for [`Coupling::tangent`], `Dual<f64>`
/// for [`Coupling::forward_second`].
#[derive(Clone, Debug)]
pub struct CouplingRecord {
    /// Hidden activations of the conditioner, every component.
    activations: Vec<f64>,
    /// `θ̂`, the conditioner's outputs before the taper, component after component.
    params: Vec<f64>,
    /// The kept coordinates (primal component), from which the taper is taken; filled
    /// only when the coupling has one.
    kept: Vec<f64>,
    /// The transformed coordinates on the input side of the forward transform `h`
    /// (primal component).
    input: Vec<f64>,
    /// The transform's primal values, forward direction.
    primal: Vec<f64>,
}

impl CouplingRecord {
    pub fn new(coupling: &Coupling, lanes: usize) -> Self {
        Self {
            activations: vec![0.0; lanes * coupling.conditioner.record_len()],
            params: vec![0.0; lanes * coupling.conditioner.output_dim()],
            kept: vec![0.0; coupling.kept.len()],
            input: vec![0.0; coupling.transformed.len()],
            primal: vec![0.0; coupling.primal_len()],
        }
    }
}

/// Buffers of [`Coupling::tangent`], [`Coupling::forward_with_tangent`] and
/// [`Coupling::forward_second`].
#[derive(Clone, Debug)]
pub struct TangentScratch {
    /// Two state-sized buffers for the layers around the coupling (the mixing).
    pub(crate) state: Vec<f64>,
    /// A state-sized buffer for the mixing in nested dual numbers.
    pub(crate) state_second: Vec<Dual<Dual<f64>>>,
    params: Vec<f64>,
    params_tangent: Vec<f64>,
    dual_params: Vec<Dual<f64>>,
    /// The transformed coordinates in dual numbers, and the primal pass's primal values.
    dual_state: Vec<Dual<f64>>,
    /// The kept coordinates in dual numbers, for the taper.
    dual_kept: Vec<Dual<f64>>,
    primal: Vec<f64>,
    /// The kept coordinates' second-order tangent `(dx, dẋ)`.
    kept_second: [Vec<f64>; 2],
    nested_params: Vec<Dual<Dual<f64>>>,
    conditioner: ConditionerTangentScratch,
}

impl TangentScratch {
    pub fn new(coupling: &Coupling) -> Self {
        let zero = Dual::new(0.0, 0.0);
        let nested_zero = Dual::new(zero, zero);
        let outputs = coupling.conditioner.output_dim();
        Self {
            state: vec![0.0; 2 * coupling.state_dim()],
            state_second: vec![nested_zero; coupling.state_dim()],
            params: vec![0.0; outputs],
            params_tangent: vec![0.0; outputs],
            dual_params: vec![zero; outputs],
            dual_state: vec![zero; coupling.transformed.len()],
            dual_kept: vec![zero; coupling.kept.len()],
            primal: vec![0.0; coupling.primal_len()],
            kept_second: std::array::from_fn(|_| vec![0.0; coupling.kept.len()]),
            nested_params: vec![nested_zero; outputs],
            conditioner: ConditionerTangentScratch::new(&coupling.conditioner),
        }
    }
}

impl Coupling {
    /// Coupling layer `index` of `config`, parameters under `{prefix}.conditioner` (and
    /// `{prefix}.local`).
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
        let taper = match config.coupling {
            CouplingKind::Affine {
                taper_radius: Some(radius),
                ..
            } => Some(Taper::new(radius)),
            _ => None,
        };
        Ok(Self {
            transform: Transform::new(&config.coupling),
            taper,
            conditioner: Conditioner::from_weights(
                weights,
                prefix,
                &config.conditioner_sizes(),
                kept_dim,
                &config.context_sets,
                config.local(),
                config.conditioning_dim(),
            )?,
            kept,
            transformed,
        })
    }

    fn primal_len(&self) -> usize {
        self.transform.primal_len(self.transformed.len())
    }

    /// `d`, the dimension of the state the coupling acts on.
    pub fn state_dim(&self) -> usize {
        self.kept.len() + self.transformed.len()
    }

    /// Length of the context bias [`fold_context`](Self::fold_context) writes.
    pub fn context_bias_len(&self) -> usize {
        self.conditioner.context_bias_len()
    }

    /// The conditioner's first-layer biases with the context (the conditioning vector
    /// `encoded` and the normalised context) folded in, the form every evaluation takes
    /// its context in: the context is the same for all the points of a step, so its
    /// columns of the first layers are read once per context.
    pub fn fold_context(&self, encoded: &[f64], normalised: &[f64], context_bias: &mut [f64]) {
        self.conditioner
            .fold_context(encoded, normalised, context_bias);
    }

    fn condition<S: Scalar>(
        &self,
        x: &[S],
        context_bias: &[f64],
        scratch: &mut CouplingScratch<S>,
        record: Option<&mut CouplingRecord>,
    ) {
        let CouplingScratch {
            params,
            conditioner,
            ..
        } = scratch;
        let activations = record.map(|r| &mut r.activations[..]);
        self.conditioner.eval(
            &x[self.kept.clone()],
            context_bias,
            conditioner,
            params,
            activations,
        );
    }

    /// Applies `h` (or `h⁻¹` when `inverse`) in place; returns the log-determinant, or
    /// zero when recording (a recorded pass serves Jacobian-vector products, not densities).
    ///
    /// On x86-64 CPUs with AVX2 and FMA it runs compiled for them, so the transforms'
    /// loops (the spline's softmax) use 4-wide vectors.
    fn apply<S: Scalar>(
        &self,
        x: &mut [S],
        context_bias: &[f64],
        scratch: &mut CouplingScratch<S>,
        inverse: bool,
        record: Option<&mut CouplingRecord>,
    ) -> S {
        #[cfg(target_arch = "x86_64")]
        if has_avx2_fma() {
            // SAFETY: AVX2 and FMA support were detected.
            return unsafe { self.apply_avx2(x, context_bias, scratch, inverse, record) };
        }
        self.apply_with::<S, false>(x, context_bias, scratch, inverse, record)
    }

    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2,fma")]
    fn apply_avx2<S: Scalar>(
        &self,
        x: &mut [S],
        context_bias: &[f64],
        scratch: &mut CouplingScratch<S>,
        inverse: bool,
        record: Option<&mut CouplingRecord>,
    ) -> S {
        self.apply_with::<S, true>(x, context_bias, scratch, inverse, record)
    }

    /// `FUSED`: compiled for FMA instructions ([`AffineTransform::primal_scales`]).
    #[inline(always)]
    fn apply_with<S: Scalar, const FUSED: bool>(
        &self,
        x: &mut [S],
        context_bias: &[f64],
        scratch: &mut CouplingScratch<S>,
        inverse: bool,
        mut record: Option<&mut CouplingRecord>,
    ) -> S {
        let want_log_det = record.is_none();
        self.condition(x, context_bias, scratch, record.as_deref_mut());
        if let Some(record) = record.as_deref_mut() {
            let planes = record.params.chunks_exact_mut(scratch.params.len());
            for (l, plane) in planes.enumerate() {
                for (r, p) in plane.iter_mut().zip(&scratch.params) {
                    *r = p.lane(l);
                }
            }
            if self.taper.is_some() {
                for (r, xi) in record.kept.iter_mut().zip(&x[self.kept.clone()]) {
                    *r = xi.value();
                }
            }
        }
        if let Some(taper) = &self.taper {
            taper.apply(&x[self.kept.clone()], &mut scratch.params);
        }
        let xs = &mut x[self.transformed.clone()];
        let record_input = |record: &mut CouplingRecord, xs: &[S]| {
            for (r, xi) in record.input.iter_mut().zip(xs) {
                *r = xi.value();
            }
        };
        if let Some(record) = record.as_deref_mut()
            && !inverse
        {
            record_input(record, xs);
        }
        let log_det = self.transform.apply_all::<S, FUSED>(
            xs,
            &scratch.params,
            Primal::Compute(&mut scratch.primal),
            inverse,
            want_log_det,
        );
        if let Some(record) = record {
            if inverse {
                record_input(record, xs);
            }
            self.transform
                .record_primal(&scratch.primal, inverse, &mut record.primal);
        }
        log_det
    }

    /// `x ← coupling(x)`; returns `log|det ∂y/∂x|`.
    pub fn forward<S: Scalar>(
        &self,
        x: &mut [S],
        context_bias: &[f64],
        scratch: &mut CouplingScratch<S>,
    ) -> S {
        self.apply(x, context_bias, scratch, false, None)
    }

    /// `x ← coupling⁻¹(x)`; returns `log|det ∂x/∂y|`.
    pub fn inverse<S: Scalar>(
        &self,
        x: &mut [S],
        context_bias: &[f64],
        scratch: &mut CouplingScratch<S>,
    ) -> S {
        self.apply(x, context_bias, scratch, true, None)
    }

    /// `x ← coupling⁻¹(x)`, keeping in `record` what [`tangent`](Self::tangent) needs at
    /// the point it returns (no log-determinant).
    pub fn inverse_recorded<S: Scalar>(
        &self,
        x: &mut [S],
        context_bias: &[f64],
        scratch: &mut CouplingScratch<S>,
        record: &mut CouplingRecord,
    ) {
        self.apply(x, context_bias, scratch, true, Some(record));
    }

    /// `dx ← ∂coupling/∂x · dx` at the point `record` was taken (the context is fixed):
    /// the conditioner's tangent `dθ` from its recorded activations, then `h` in dual
    /// numbers on `(x + dx ε, θ + dθ ε)`.
    pub fn tangent(&self, record: &CouplingRecord, dx: &mut [f64], scratch: &mut TangentScratch) {
        self.sweep(record, dx, None, scratch);
    }

    /// `x ← coupling(x)` and the [`tangent`](Self::tangent) `dx` at the recorded point, in
    /// one sweep over the conditioner's weights.
    pub fn forward_with_tangent(
        &self,
        x: &mut [f64],
        context_bias: &[f64],
        record: &CouplingRecord,
        dx: &mut [f64],
        scratch: &mut TangentScratch,
    ) {
        self.sweep(record, dx, Some((x, context_bias)), scratch);
    }

    /// `x ← coupling(x)` in nested dual numbers `(x + ẋ ε₂) + (dx + dẋ ε₂) ε₁` at the
    /// point whose `Dual<f64>` inverse pass (`x + ẋ ε₂`) filled `record`: the forward
    /// pass meets the coupling input the inverse pass returned, so `θ + θ̇ ε₂` is read
    /// from the record and only the conditioner's second-order tangent is computed
    /// ([`Conditioner::second_tangent`]).
    pub fn forward_second(
        &self,
        x: &mut [Dual<Dual<f64>>],
        record: &CouplingRecord,
        scratch: &mut TangentScratch,
    ) {
        #[cfg(target_arch = "x86_64")]
        if has_avx2_fma() {
            // SAFETY: AVX2 and FMA support were detected.
            return unsafe { self.forward_second_avx2(x, record, scratch) };
        }
        self.forward_second_with::<false>(x, record, scratch)
    }

    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2,fma")]
    fn forward_second_avx2(
        &self,
        x: &mut [Dual<Dual<f64>>],
        record: &CouplingRecord,
        scratch: &mut TangentScratch,
    ) {
        self.forward_second_with::<true>(x, record, scratch)
    }

    #[inline(always)]
    fn forward_second_with<const FUSED: bool>(
        &self,
        x: &mut [Dual<Dual<f64>>],
        record: &CouplingRecord,
        scratch: &mut TangentScratch,
    ) {
        let [dx, dx_dot] = &mut scratch.kept_second;
        for ((d, d_dot), xi) in dx
            .iter_mut()
            .zip(dx_dot.iter_mut())
            .zip(&x[self.kept.clone()])
        {
            (*d, *d_dot) = (xi.du.re, xi.du.du);
        }
        let [dtheta, dtheta_dot] = self.conditioner.second_tangent(
            &record.activations,
            [dx, dx_dot],
            &mut scratch.conditioner,
        );
        let (theta, theta_dot) = record.params.split_at(dtheta.len());
        let nested = theta
            .iter()
            .zip(theta_dot)
            .zip(dtheta.iter().zip(dtheta_dot));
        for (t, ((p, p_dot), (dp, dp_dot))) in scratch.nested_params.iter_mut().zip(nested) {
            *t = Dual::new(Dual::new(*p, *p_dot), Dual::new(*dp, *dp_dot));
        }
        if let Some(taper) = &self.taper {
            taper.apply(&x[self.kept.clone()], &mut scratch.nested_params);
        }
        self.transform.apply_all::<_, FUSED>(
            &mut x[self.transformed.clone()],
            &scratch.nested_params,
            Primal::Recorded(&record.primal),
            false,
            false,
        );
    }

    /// Tangent, and primal when given, in place; dispatched like [`apply`](Self::apply).
    fn sweep(
        &self,
        record: &CouplingRecord,
        dx: &mut [f64],
        primal: Option<(&mut [f64], &[f64])>,
        scratch: &mut TangentScratch,
    ) {
        #[cfg(target_arch = "x86_64")]
        if has_avx2_fma() {
            // SAFETY: AVX2 and FMA support were detected.
            return unsafe { self.sweep_avx2(record, dx, primal, scratch) };
        }
        self.sweep_with::<false>(record, dx, primal, scratch)
    }

    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2,fma")]
    fn sweep_avx2(
        &self,
        record: &CouplingRecord,
        dx: &mut [f64],
        primal: Option<(&mut [f64], &[f64])>,
        scratch: &mut TangentScratch,
    ) {
        self.sweep_with::<true>(record, dx, primal, scratch)
    }

    #[inline(always)]
    fn sweep_with<const FUSED: bool>(
        &self,
        record: &CouplingRecord,
        dx: &mut [f64],
        primal: Option<(&mut [f64], &[f64])>,
        scratch: &mut TangentScratch,
    ) {
        let TangentScratch {
            params,
            params_tangent,
            conditioner,
            ..
        } = scratch;
        let dx_kept = &dx[self.kept.clone()];
        match &primal {
            Some((x, context_bias)) => self.conditioner.eval_and_tangent(
                &x[self.kept.clone()],
                context_bias,
                params,
                &record.activations,
                dx_kept,
                params_tangent,
                conditioner,
            ),
            None => {
                self.conditioner
                    .tangent(&record.activations, dx_kept, conditioner, params_tangent)
            }
        }
        for ((d, p), dp) in scratch
            .dual_params
            .iter_mut()
            .zip(&record.params)
            .zip(&scratch.params_tangent)
        {
            *d = Dual::new(*p, *dp);
        }
        if let Some(taper) = &self.taper {
            let kept = &mut scratch.dual_kept;
            for ((k, xi), dxi) in kept.iter_mut().zip(&record.kept).zip(dx_kept) {
                *k = Dual::new(*xi, *dxi);
            }
            taper.apply(kept, &mut scratch.dual_params);
            if let Some((x, _)) = &primal {
                taper.apply(&x[self.kept.clone()], &mut scratch.params);
            }
        }
        let dx = &mut dx[self.transformed.clone()];
        for ((d, xi), dxi) in scratch.dual_state.iter_mut().zip(&record.input).zip(&*dx) {
            *d = Dual::new(*xi, *dxi);
        }
        self.transform.apply_all::<_, FUSED>(
            &mut scratch.dual_state,
            &scratch.dual_params,
            Primal::Recorded(&record.primal),
            false,
            false,
        );
        for (dxi, d) in dx.iter_mut().zip(&scratch.dual_state) {
            *dxi = d.du;
        }
        if let Some((x, _)) = primal {
            self.transform.apply_all::<_, FUSED>(
                &mut x[self.transformed.clone()],
                &scratch.params,
                Primal::Compute(&mut scratch.primal),
                false,
                false,
            );
        }
    }
}
