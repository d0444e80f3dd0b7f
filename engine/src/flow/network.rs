//! The conditioned invertible network `y = f(z, c)` in observation units:
//!
//! `f(z, c) = R(P_c⁻¹(μ_y + σ_y ⊙ g(z + a(c), ĉ)))`, `ĉ = E((c - μ_c) ⊘ σ_c)`,
//!
//! where `E` encodes the context's unordered sets into permutation-invariant summaries
//! ([`crate::flow::layers::context_set`]; the identity when there are none), `g` is the stack of
//! (LU mixing, coupling) blocks,
//! `P_c` the radial contractions about context points ([`crate::flow::layers::radial`]; the identity
//! when there are none), `R` the map onto a robot's joint ranges
//! ([`crate::flow::layers::joint_range`]; the identity without one) and the anchor is
//! `a(c) = g⁻¹((P_c(R⁻¹(target(c))) - μ_y) ⊘ σ_y, ĉ)` for go-to tasks whose target is part
//! of the context (so `f(0, c) = target(c)` exactly, for every `c`) and `a = 0` otherwise.
//! The anchor shifts the latent rather than the output so that a trainer finds it by
//! inverting the target in the same batch (and direction) as the demonstrations.
//! For each `c`, `f(·, c)` is a bijection with
//! `log|det ∂f/∂z| = Σ log σ_y + log|det ∂g/∂z| + log|det ∂P_c⁻¹/∂u| + log|det ∂R/∂w|`.

use crate::flow::checkpoint::config::FlowConfig;
use crate::flow::checkpoint::names::{self, LAYERS, MIXING};
use crate::flow::checkpoint::weights::Weights;
use crate::flow::error::{FlowResult, check_input};
use crate::flow::layers::context_set::{ContextEncoder, EncoderScratch};
use crate::flow::layers::coupling::{Coupling, CouplingRecord, CouplingScratch, TangentScratch};
use crate::flow::layers::mixing::LuMixing;
use crate::flow::layers::radial::{ContractionTape, RadialContractions};
use crate::nn::scalar::{Dual, Scalar};

#[derive(Clone, Debug)]
pub struct ConditionalFlow {
    config: FlowConfig,
    encoder: ContextEncoder,
    blocks: Vec<(LuMixing, Coupling)>,
    contractions: Option<RadialContractions>,
    log_state_scale: f64,
}

/// A context prepared for the network: normalised, encoded into the conditioning vector
/// `ĉ` ([`crate::flow::layers::context_set`]), folded into each conditioner's first-layer bias
/// ([`Coupling::fold_context`]), with its anchor `a(c)`. Recomputed only when the raw
/// context changes (the anchor costs one network pass).
#[derive(Clone, Debug)]
pub struct Conditioning {
    raw: Vec<f64>,
    normalised: Vec<f64>,
    encoded: Vec<f64>,
    encoder_scratch: EncoderScratch,
    /// One context bias per coupling, back to back.
    context_biases: Vec<f64>,
    anchor: Vec<f64>,
    /// The contraction centres as given, raw units.
    centres: Vec<f64>,
    valid: bool,
}

impl Conditioning {
    /// The context bias of each coupling.
    fn context_biases(&self, couplings: usize) -> std::slice::ChunksExact<'_, f64> {
        self.context_biases
            .chunks_exact(self.context_biases.len() / couplings)
    }

    /// `ĉ`, the conditioning vector.
    pub fn encoded(&self) -> &[f64] {
        &self.encoded
    }
}

/// Primal values of an inverse pass `z = f⁻¹(y, c)`, kept so Jacobian-vector products
/// at `z` ([`ConditionalFlow::tangent`]) need no second pass through the conditioners:
/// the forward pass at `z` meets the same coupling inputs the inverse pass saw.
#[derive(Clone, Debug)]
pub struct FlowTape {
    couplings: Vec<CouplingRecord>,
    contraction: ContractionTape,
    /// `tanh w` of the joint range's input, one per state dimension.
    joint_range: Vec<f64>,
}

impl ConditionalFlow {
    pub fn from_weights(config: &FlowConfig, weights: &mut Weights) -> FlowResult<Self> {
        config.validate()?;
        let encoder = ContextEncoder::from_weights(
            &config.context_sets,
            config.context_dim,
            config.set_encoder.as_ref(),
            weights,
        )?;
        let blocks = (0..config.layers)
            .map(|i| {
                let prefix = names::name(&[&LAYERS, &i]);
                Ok((
                    LuMixing::from_weights(
                        weights,
                        &names::name(&[&prefix, &MIXING]),
                        config.state_dim,
                    )?,
                    Coupling::from_weights(weights, &prefix, i, config)?,
                ))
            })
            .collect::<FlowResult<Vec<_>>>()?;
        let contractions = config
            .contractions
            .as_ref()
            .map(|c| RadialContractions::from_weights(c, weights))
            .transpose()?;
        Ok(Self {
            config: config.clone(),
            encoder,
            blocks,
            contractions,
            log_state_scale: config.normalisation.state_std.iter().map(|s| s.ln()).sum(),
        })
    }

    pub fn config(&self) -> &FlowConfig {
        &self.config
    }

    /// Buffers for [`condition`](Self::condition), holding no context yet.
    pub fn conditioning(&self) -> Conditioning {
        let config = &self.config;
        let bias_len = self.blocks[0].1.context_bias_len();
        Conditioning {
            raw: vec![0.0; config.context_dim],
            normalised: vec![0.0; config.context_dim],
            encoded: vec![0.0; self.encoder.output_dim()],
            encoder_scratch: self.encoder.scratch(),
            context_biases: vec![0.0; config.layers * bias_len],
            anchor: vec![0.0; config.state_dim],
            centres: vec![
                0.0;
                config
                    .contractions
                    .map_or(0, |c| c.centres.count * c.centres.size)
            ],
            valid: false,
        }
    }

    /// Scratch for evaluations in scalar type `S`.
    pub fn scratch<S: Scalar>(&self) -> CouplingScratch<S> {
        CouplingScratch::new(&self.blocks[0].1)
    }

    /// `x ← g(x, c̃)`; returns `log|det ∂g/∂x|`.
    fn g_forward<S: Scalar>(
        &self,
        x: &mut [S],
        conditioning: &Conditioning,
        scratch: &mut CouplingScratch<S>,
    ) -> S {
        let mut log_det = S::constant(0.0);
        let biases = conditioning.context_biases(self.blocks.len());
        for ((mixing, coupling), bias) in self.blocks.iter().zip(biases) {
            log_det = log_det + mixing.forward(x, &mut scratch.state);
            log_det += coupling.forward(x, bias, scratch);
        }
        log_det
    }

    /// A tape for [`inverse_recorded`](Self::inverse_recorded).
    pub fn tape(&self) -> FlowTape {
        self.tape_of(1)
    }

    /// A tape for [`inverse_recorded_dual`](Self::inverse_recorded_dual).
    pub fn dual_tape(&self) -> FlowTape {
        self.tape_of(2)
    }

    /// A tape for a recorded inverse in a scalar type of `lanes` components.
    fn tape_of(&self, lanes: usize) -> FlowTape {
        FlowTape {
            couplings: self
                .blocks
                .iter()
                .map(|(_, c)| CouplingRecord::new(c, lanes))
                .collect(),
            contraction: ContractionTape::default(),
            joint_range: vec![0.0; self.config.state_dim],
        }
    }

    /// Scratch for [`tangent`](Self::tangent).
    pub fn tangent_scratch(&self) -> TangentScratch {
        TangentScratch::new(&self.blocks[0].1)
    }

    /// `x ← g⁻¹(x, c̃)`; returns `log|det ∂g⁻¹/∂x|`.
    fn g_inverse<S: Scalar>(
        &self,
        x: &mut [S],
        conditioning: &Conditioning,
        scratch: &mut CouplingScratch<S>,
    ) -> S {
        let mut log_det = S::constant(0.0);
        let biases = conditioning.context_biases(self.blocks.len());
        for ((mixing, coupling), bias) in self.blocks.iter().zip(biases).rev() {
            log_det += coupling.inverse(x, bias, scratch);
            log_det = log_det + mixing.inverse(x, &mut scratch.state);
        }
        log_det
    }

    /// `x ← g⁻¹(x, c̃)`, recording the couplings into `tape` (no log-determinant).
    fn g_inverse_recorded<S: Scalar>(
        &self,
        x: &mut [S],
        conditioning: &Conditioning,
        scratch: &mut CouplingScratch<S>,
        tape: &mut FlowTape,
    ) {
        let biases = conditioning.context_biases(self.blocks.len());
        let layers = self.blocks.iter().zip(biases).zip(&mut tape.couplings);
        for (((mixing, coupling), bias), record) in layers.rev() {
            coupling.inverse_recorded(x, bias, scratch, record);
            mixing.inverse(x, &mut scratch.state);
        }
    }

    /// Validates the raw context `c` and prepares `conditioning` for it.
    pub fn condition(
        &self,
        context: &[f64],
        conditioning: &mut Conditioning,
        scratch: &mut CouplingScratch<f64>,
    ) -> FlowResult<()> {
        if conditioning.valid && conditioning.raw == context {
            return Ok(());
        }
        check_input("context", self.config.context_dim, context)?;
        let norm = &self.config.normalisation;
        conditioning.raw.copy_from_slice(context);
        if let Some(contractions) = &self.contractions {
            let set = contractions.config().centres;
            conditioning
                .centres
                .copy_from_slice(&context[set.start..set.end()]);
        }
        for ((n, c), (m, s)) in conditioning
            .normalised
            .iter_mut()
            .zip(context)
            .zip(norm.context_mean.iter().zip(&norm.context_std))
        {
            *n = (c - m) / s;
        }
        self.encoder.encode(
            &conditioning.normalised,
            &mut conditioning.encoder_scratch,
            &mut conditioning.encoded,
        );
        let bias_len = conditioning.context_biases.len() / self.blocks.len();
        let biases = conditioning.context_biases.chunks_exact_mut(bias_len);
        for ((_, coupling), bias) in self.blocks.iter().zip(biases) {
            coupling.fold_context(&conditioning.encoded, &conditioning.normalised, bias);
        }
        conditioning.anchor.fill(0.0);
        if let Some(indices) = &self.config.goal_context_indices {
            let mut anchor = std::mem::take(&mut conditioning.anchor);
            for (a, &i) in anchor.iter_mut().zip(indices) {
                *a = context[i];
            }
            self.enter(&mut anchor, conditioning);
            self.g_inverse(&mut anchor, conditioning, scratch);
            conditioning.anchor = anchor;
        }
        conditioning.valid = true;
        Ok(())
    }

    /// `y = f(z, c)`; returns `log|det ∂f/∂z|`.
    pub fn forward<S: Scalar>(
        &self,
        z: &[S],
        conditioning: &Conditioning,
        scratch: &mut CouplingScratch<S>,
        y: &mut [S],
    ) -> S {
        for ((yi, &zi), a) in y.iter_mut().zip(z).zip(&conditioning.anchor) {
            *yi = zi + *a;
        }
        let log_det = self.g_forward(y, conditioning, scratch);
        self.leave(y, conditioning) + log_det + self.log_state_scale
    }

    /// `y ← R(P_c⁻¹(μ_y + σ_y ⊙ x))`, the output of `g` to the observation; returns
    /// `log|det ∂(R ∘ P_c⁻¹)/∂u|`.
    fn leave<S: Scalar>(&self, x: &mut [S], conditioning: &Conditioning) -> S {
        self.unnormalise_state(x);
        let log_det = match &self.contractions {
            Some(contractions) => contractions.invert(&conditioning.centres, x),
            None => S::constant(0.0),
        };
        match &self.config.joint_range {
            Some(range) => log_det + range.apply(x),
            None => log_det,
        }
    }

    /// [`leave`](Self::leave) without the log-determinant, for the tangent and
    /// second-order passes, which have no use for it (the contractions' would cost another
    /// `P` and `J` per layer). `near`: the recorded pass that `x` is close to, whose points
    /// start the contractions' root searches.
    fn leave_point<S: Scalar>(
        &self,
        x: &mut [S],
        conditioning: &Conditioning,
        near: Option<&FlowTape>,
    ) {
        self.unnormalise_state(x);
        if let Some(contractions) = &self.contractions {
            let near = near.map(|tape| &tape.contraction);
            contractions.invert_point(&conditioning.centres, x, near);
        }
        if let Some(range) = &self.config.joint_range {
            range.apply(x);
        }
    }

    /// `x ← μ_y + σ_y ⊙ x`.
    fn unnormalise_state<S: Scalar>(&self, x: &mut [S]) {
        let norm = &self.config.normalisation;
        for (i, xi) in x.iter_mut().enumerate() {
            *xi = *xi * norm.state_std[i] + norm.state_mean[i];
        }
    }

    /// `z = f⁻¹(y, c)`; returns `log|det ∂f⁻¹/∂y|`.
    pub fn inverse<S: Scalar>(
        &self,
        y: &[S],
        conditioning: &Conditioning,
        scratch: &mut CouplingScratch<S>,
        z: &mut [S],
    ) -> S {
        z.copy_from_slice(y);
        let log_det = self.enter(z, conditioning);
        let log_det = log_det + self.g_inverse(z, conditioning, scratch);
        self.unanchor(z, conditioning);
        log_det + (-self.log_state_scale)
    }

    /// `z = f⁻¹(y, c)`, recording in `tape` what [`tangent`](Self::tangent) needs at that
    /// `z` (no log-determinant).
    pub fn inverse_recorded(
        &self,
        y: &[f64],
        conditioning: &Conditioning,
        scratch: &mut CouplingScratch<f64>,
        z: &mut [f64],
        tape: &mut FlowTape,
    ) {
        z.copy_from_slice(y);
        self.enter_recorded(z, conditioning, tape);
        self.g_inverse_recorded(z, conditioning, scratch, tape);
        self.unanchor(z, conditioning);
    }

    /// `z + ż ε = f⁻¹(y + ẏ ε, c)`, recording in `tape` (a [`dual_tape`](Self::dual_tape))
    /// what [`forward_second`](Self::forward_second) needs at that point.
    pub fn inverse_recorded_dual(
        &self,
        y: &[Dual<f64>],
        conditioning: &Conditioning,
        scratch: &mut CouplingScratch<Dual<f64>>,
        z: &mut [Dual<f64>],
        tape: &mut FlowTape,
    ) {
        z.copy_from_slice(y);
        self.enter_recorded(z, conditioning, tape);
        self.g_inverse_recorded(z, conditioning, scratch, tape);
        self.unanchor(z, conditioning);
    }

    /// `y = f(z, c)` in nested dual numbers, at the `z + ż ε₂` whose
    /// [`inverse_recorded_dual`](Self::inverse_recorded_dual) filled `tape`: `z` is
    /// `(z + ż ε₂) + (dz + dż ε₂) ε₁`, and `y` comes out the same as from
    /// [`forward`](Self::forward), with the couplings' conditioners evaluated only along
    /// `ε₁` (their value and `ε₂` part are the recorded ones).
    pub fn forward_second(
        &self,
        z: &[Dual<Dual<f64>>],
        conditioning: &Conditioning,
        tape: &FlowTape,
        scratch: &mut TangentScratch,
        y: &mut [Dual<Dual<f64>>],
    ) {
        for ((yi, &zi), a) in y.iter_mut().zip(z).zip(&conditioning.anchor) {
            *yi = zi + *a;
        }
        for ((mixing, coupling), record) in self.blocks.iter().zip(&tape.couplings) {
            mixing.forward(y, &mut scratch.state_second);
            coupling.forward_second(y, record, scratch);
        }
        // `z` is the recorded pass's own latent point, so its roots are the recorded ones.
        self.leave_point(y, conditioning, Some(tape));
    }

    /// `x ← (P_c(R⁻¹(x)) - μ_y) ⊘ σ_y`, an observation to the input of `g⁻¹`; returns
    /// `log|det ∂(P_c ∘ R⁻¹)/∂y|`.
    fn enter<S: Scalar>(&self, x: &mut [S], conditioning: &Conditioning) -> S {
        let log_det = match &self.config.joint_range {
            Some(range) => range.invert(x, None),
            None => S::constant(0.0),
        };
        let log_det = match &self.contractions {
            Some(contractions) => log_det + contractions.apply(&conditioning.centres, x),
            None => log_det,
        };
        self.normalise_state(x);
        log_det
    }

    /// [`enter`](Self::enter) without the log-determinant, recording what the passes back
    /// through the same point need: the joint range's coordinates and the contractions'
    /// points.
    fn enter_recorded<S: Scalar>(
        &self,
        x: &mut [S],
        conditioning: &Conditioning,
        tape: &mut FlowTape,
    ) {
        if let Some(range) = &self.config.joint_range {
            range.invert(x, Some(&mut tape.joint_range));
        }
        if let Some(contractions) = &self.contractions {
            contractions.apply_recorded(&conditioning.centres, x, &mut tape.contraction);
        }
        self.normalise_state(x);
    }

    /// `x ← (x - μ_y) ⊘ σ_y`.
    fn normalise_state<S: Scalar>(&self, x: &mut [S]) {
        let norm = &self.config.normalisation;
        for (i, xi) in x.iter_mut().enumerate() {
            *xi = (*xi + (-norm.state_mean[i])) * (1.0 / norm.state_std[i]);
        }
    }

    /// `z ← z - a(c)`, the output of `g⁻¹` to the latent.
    fn unanchor<S: Scalar>(&self, z: &mut [S], conditioning: &Conditioning) {
        for (zi, a) in z.iter_mut().zip(&conditioning.anchor) {
            *zi = *zi + (-*a);
        }
    }

    /// The Jacobian-vector product `dy = ∂f(z, c)/∂z · dz` at the `z` of the
    /// [`inverse_recorded`](Self::inverse_recorded) call that filled `tape`:
    /// `dy = J_R J_{P⁻¹} (σ_y ⊙ J_g dz)`, one tangent sweep through the blocks in forward
    /// order.
    pub fn tangent(
        &self,
        tape: &FlowTape,
        dz: &[f64],
        scratch: &mut TangentScratch,
        dy: &mut [f64],
    ) {
        self.sweep(tape, dz, scratch, dy, None);
    }

    /// `y' = f(z', c)` and the [`tangent`](Self::tangent) `dy` at the recorded `z`, in
    /// one sweep over the weights (each conditioner multiplies both vectors at once);
    /// `c` is the context of the recorded pass.
    #[allow(clippy::too_many_arguments)]
    pub fn forward_with_tangent(
        &self,
        tape: &FlowTape,
        z_other: &[f64],
        conditioning: &Conditioning,
        dz: &[f64],
        scratch: &mut TangentScratch,
        y_other: &mut [f64],
        dy: &mut [f64],
    ) {
        for ((y, &z), a) in y_other.iter_mut().zip(z_other).zip(&conditioning.anchor) {
            *y = z + a;
        }
        self.sweep(tape, dz, scratch, dy, Some((y_other, conditioning)));
        self.leave_point(y_other, conditioning, None);
    }

    /// `dy ← J_R J_{P⁻¹} (σ_y ⊙ J_g dz)` and, when given, `x ← g(x, c̃)`.
    fn sweep(
        &self,
        tape: &FlowTape,
        dz: &[f64],
        scratch: &mut TangentScratch,
        dy: &mut [f64],
        mut primal: Option<(&mut [f64], &Conditioning)>,
    ) {
        dy.copy_from_slice(dz);
        for (b, ((mixing, coupling), record)) in self.blocks.iter().zip(&tape.couplings).enumerate()
        {
            match primal.as_mut() {
                Some((x, conditioning)) => {
                    let bias = conditioning.context_biases(self.blocks.len()).nth(b);
                    let bias = bias.expect("one context bias per coupling");
                    mixing.forward_with_tangent(x, dy, &mut scratch.state);
                    coupling.forward_with_tangent(x, bias, record, dy, scratch);
                }
                None => {
                    mixing.tangent(dy, &mut scratch.state);
                    coupling.tangent(record, dy, scratch);
                }
            }
        }
        for (d, s) in dy.iter_mut().zip(&self.config.normalisation.state_std) {
            *d *= s;
        }
        if let Some(contractions) = &self.contractions {
            contractions.tangent(&tape.contraction, dy);
        }
        if let Some(range) = &self.config.joint_range {
            range.tangent(&tape.joint_range, dy);
        }
    }
}
