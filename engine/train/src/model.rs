//! The conditioned ImitationFlow in tch: `y = P_c⁻¹(μ_y + σ_y ⊙ (g(z, c̃) + o(c)))`,
//! `c̃ = (κ(c) - μ_c) ⊘ σ_c`, with the
//! latent dynamics of [`LatentModel`], mirroring `ciflow_engine::flow` parameter for
//! parameter, so `VarStore::save("weights.safetensors")` loads in the pure-Rust policy.

use ciflow_engine::flow::FlowConfig;
use tch::nn;
use tch::{Device, Kind, Tensor};

use crate::contraction::Contractions;
use crate::latent::{LatentInit, LatentModel};
use crate::nets::{Coupling, LuMixing};

#[derive(Debug)]
pub struct FlowModel {
    config: FlowConfig,
    blocks: Vec<(LuMixing, Coupling)>,
    latent: LatentModel,
    state_mean: Tensor,
    state_std: Tensor,
    context_mean: Tensor,
    context_std: Tensor,
    goal_index: Option<Tensor>,
    contractions: Option<Contractions>,
}

/// A batch of contexts prepared for the network: `c̃`, `o(c)` and the contraction
/// centres (`[B, count, d]`, canonical order, raw units).
struct Conditioned {
    normalised: Tensor,
    offset: Tensor,
    centres: Option<Tensor>,
}

impl Conditioned {
    /// Both batches, `self` first.
    fn twice(&self) -> Self {
        let doubled = |t: &Tensor| Tensor::cat(&[t, t], 0);
        Self {
            normalised: doubled(&self.normalised),
            offset: doubled(&self.offset),
            centres: self.centres.as_ref().map(doubled),
        }
    }
}

pub(crate) fn row(values: &[f64]) -> Tensor {
    Tensor::from_slice(values)
        .to_kind(Kind::Double)
        .reshape([1, -1])
}

impl FlowModel {
    /// Creates the variables under `path` (names as in the engine) — in a `VarStore`
    /// whose kind is f64 ([`crate::trainer::double_var_store`]).
    pub fn new(path: &nn::Path, config: &FlowConfig, init: LatentInit) -> Self {
        let blocks = (0..config.layers)
            .map(|i| {
                let p = path / "layers" / i;
                (
                    LuMixing::new(&(&p / "mixing"), config.state_dim),
                    Coupling::new(&p, i, config),
                )
            })
            .collect();
        let norm = &config.normalisation;
        Self {
            config: config.clone(),
            blocks,
            latent: LatentModel::new(&(path / "latent"), config, init),
            state_mean: row(&norm.state_mean),
            state_std: row(&norm.state_std),
            context_mean: row(&norm.context_mean),
            context_std: row(&norm.context_std),
            goal_index: config.goal_context_indices.as_ref().map(|indices| {
                Tensor::from_slice(&indices.iter().map(|&i| i as i64).collect::<Vec<_>>())
                    .to_device(Device::Cpu)
            }),
            contractions: config
                .contractions
                .as_ref()
                .map(|c| Contractions::new(path, c)),
        }
    }

    /// Per-coordinate standard deviation of the states, `σ_y` as a `[1, d]` row.
    pub fn state_std(&self) -> &Tensor {
        &self.state_std
    }

    pub fn config(&self) -> &FlowConfig {
        &self.config
    }

    pub fn latent(&self) -> &LatentModel {
        &self.latent
    }

    fn log_state_scale(&self) -> Tensor {
        self.state_std.log().sum(Kind::Double)
    }

    fn g_forward(&self, z: &Tensor, context: &Tensor) -> (Tensor, Tensor) {
        let mut x = z.shallow_clone();
        let mut log_det = Tensor::zeros([z.size()[0]], (Kind::Double, z.device()));
        for (mixing, coupling) in &self.blocks {
            let (y, ld) = mixing.forward(&x);
            let (y, lc) = coupling.apply(&y, context, false);
            x = y;
            log_det = log_det + ld + lc;
        }
        (x, log_det)
    }

    fn g_inverse(&self, y: &Tensor, context: &Tensor) -> (Tensor, Tensor) {
        let mut x = y.shallow_clone();
        let mut log_det = Tensor::zeros([y.size()[0]], (Kind::Double, y.device()));
        for (mixing, coupling) in self.blocks.iter().rev() {
            let (u, lc) = coupling.apply(&x, context, true);
            let (u, ld) = mixing.inverse(&u);
            x = u;
            log_det = log_det + ld + lc;
        }
        (x, log_det)
    }

    /// `κ(c)`: each context set's elements `[B, count, size]` sorted (stably) by their
    /// first entry, as `ciflow_engine::flow::context_set` does.
    fn canonicalise(&self, context: &Tensor) -> Tensor {
        let mut canonical = context.shallow_clone();
        for set in &self.config.context_sets {
            let (start, count, size) = (set.start as i64, set.count as i64, set.size as i64);
            let rows = context.size()[0];
            let elements = canonical
                .narrow(1, start, count * size)
                .reshape([rows, count, size]);
            let (_, order) = elements.select(2, 0).sort_stable(true, 1, false);
            let sorted = elements
                .gather(
                    1,
                    &order.unsqueeze(2).expand([rows, count, size], false),
                    false,
                )
                .reshape([rows, count * size]);
            let m = canonical.size()[1];
            canonical = Tensor::cat(
                &[
                    canonical.narrow(1, 0, start),
                    sorted,
                    canonical.narrow(1, start + count * size, m - start - count * size),
                ],
                1,
            );
        }
        canonical
    }

    /// `(c̃, o(c), centres)` for raw contexts `[B, m]`.
    fn condition(&self, context: &Tensor) -> Conditioned {
        let canonical = self.canonicalise(context);
        let normalised = (&canonical - &self.context_mean) / &self.context_std;
        let centres = self.contractions.as_ref().map(|p| p.centres(&canonical));
        let rows = context.size()[0];
        let d = self.config.state_dim as i64;
        let offset = match &self.goal_index {
            Some(index) => {
                let target = self.contract(&context.index_select(1, index), &centres).0;
                let origin = Tensor::zeros([rows, d], (Kind::Double, context.device()));
                (target - &self.state_mean) / &self.state_std
                    - self.g_forward(&origin, &normalised).0
            }
            None => Tensor::zeros([rows, d], (Kind::Double, context.device())),
        };
        Conditioned {
            normalised,
            offset,
            centres,
        }
    }

    /// `y = f(z, c)` and `log|det ∂f/∂z|` per row; through the contractions without
    /// gradient (their inverse is iterative: only inference needs it).
    pub fn forward(&self, z: &Tensor, context: &Tensor) -> (Tensor, Tensor) {
        let conditioned = self.condition(context);
        let (y, log_det) = self.g_forward(z, &conditioned.normalised);
        let u = (y + &conditioned.offset) * &self.state_std + &self.state_mean;
        let log_det = log_det + self.log_state_scale();
        match (&self.contractions, &conditioned.centres) {
            (Some(p), Some(centres)) => {
                let y = p.invert(&u, centres);
                let contraction_log_det = p.apply(&y, centres).1;
                (y, log_det - contraction_log_det)
            }
            _ => (u, log_det),
        }
    }

    /// `z = f⁻¹(y, c)` and `log|det ∂f⁻¹/∂y|` per row.
    pub fn inverse(&self, y: &Tensor, context: &Tensor) -> (Tensor, Tensor) {
        self.inverse_conditioned(y, &self.condition(context))
    }

    /// `(P_c(y), log|det ∂P_c/∂y|)` about `centres`; the identity without contractions.
    fn contract(&self, y: &Tensor, centres: &Option<Tensor>) -> (Tensor, Tensor) {
        match (&self.contractions, centres) {
            (Some(p), Some(centres)) => p.apply(y, centres),
            _ => (
                y.shallow_clone(),
                Tensor::zeros([y.size()[0]], (Kind::Double, y.device())),
            ),
        }
    }

    /// [`inverse`](Self::inverse) with the conditioning `(c̃, o(c), centres)` already
    /// computed.
    fn inverse_conditioned(&self, y: &Tensor, conditioned: &Conditioned) -> (Tensor, Tensor) {
        let (u, contraction_log_det) = self.contract(y, &conditioned.centres);
        let x = (u - &self.state_mean) / &self.state_std - &conditioned.offset;
        let (z, log_det) = self.g_inverse(&x, &conditioned.normalised);
        (z, log_det - self.log_state_scale() + contraction_log_det)
    }

    /// `log p(y_next | y_prev, c)` per row (the `horizon`-step model), with `c = c_{k-1}`.
    pub fn log_transition(
        &self,
        y_prev: &Tensor,
        y_next: &Tensor,
        context: &Tensor,
        horizon: usize,
    ) -> Tensor {
        // Both ends share `c`: condition once (the offset costs a network pass), then
        // invert both ends in one batch.
        let conditioning = self.condition(context).twice();
        let both = Tensor::cat(&[y_prev, y_next], 0);
        let (z, log_det) = self.inverse_conditioned(&both, &conditioning);
        let rows = y_prev.size()[0];
        let (z_prev, z_next) = (z.narrow(0, 0, rows), z.narrow(0, rows, rows));
        self.latent.log_transition(&z_prev, &z_next, horizon) + log_det.narrow(0, rows, rows)
    }

    /// `log p(y₀ | c₀)` per row.
    pub fn log_initial(&self, y0: &Tensor, context: &Tensor) -> Tensor {
        let (z, log_det) = self.inverse(y0, context);
        self.latent.log_initial(&z) + log_det
    }

    /// Noise-free next state `f(μ(f⁻¹(y, c)), c)`.
    pub fn mean_next(&self, y: &Tensor, context: &Tensor) -> Tensor {
        let (z, _) = self.inverse(y, context);
        self.forward(&self.latent.mean_step(&z), context).0
    }
}
