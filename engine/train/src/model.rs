//! The conditioned ImitationFlow in tch: `y = μ_y + σ_y ⊙ (g(z, c̃) + o(c))`,
//! `c̃ = (κ(c) - μ_c) ⊘ σ_c`, with the
//! latent dynamics of [`LatentModel`], mirroring `ciflow_engine::flow` parameter for
//! parameter, so `VarStore::save("weights.safetensors")` loads in the pure-Rust policy.

use ciflow_engine::flow::FlowConfig;
use tch::nn;
use tch::{Device, Kind, Tensor};

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

    /// `(c̃, o(c))` for raw contexts `[B, m]`.
    fn condition(&self, context: &Tensor) -> (Tensor, Tensor) {
        let normalised = (self.canonicalise(context) - &self.context_mean) / &self.context_std;
        let rows = context.size()[0];
        let d = self.config.state_dim as i64;
        let offset = match &self.goal_index {
            Some(index) => {
                let target = (context.index_select(1, index) - &self.state_mean) / &self.state_std;
                let origin = Tensor::zeros([rows, d], (Kind::Double, context.device()));
                target - self.g_forward(&origin, &normalised).0
            }
            None => Tensor::zeros([rows, d], (Kind::Double, context.device())),
        };
        (normalised, offset)
    }

    /// `y = f(z, c)` and `log|det ∂f/∂z|` per row.
    pub fn forward(&self, z: &Tensor, context: &Tensor) -> (Tensor, Tensor) {
        let (normalised, offset) = self.condition(context);
        let (y, log_det) = self.g_forward(z, &normalised);
        (
            (y + offset) * &self.state_std + &self.state_mean,
            log_det + self.log_state_scale(),
        )
    }

    /// `z = f⁻¹(y, c)` and `log|det ∂f⁻¹/∂y|` per row.
    pub fn inverse(&self, y: &Tensor, context: &Tensor) -> (Tensor, Tensor) {
        self.inverse_conditioned(y, &self.condition(context))
    }

    /// [`inverse`](Self::inverse) with the conditioning `(c̃, o(c))` already computed.
    fn inverse_conditioned(
        &self,
        y: &Tensor,
        (normalised, offset): &(Tensor, Tensor),
    ) -> (Tensor, Tensor) {
        let x = (y - &self.state_mean) / &self.state_std - offset;
        let (z, log_det) = self.g_inverse(&x, normalised);
        (z, log_det - self.log_state_scale())
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
        let (normalised, offset) = self.condition(context);
        let both = Tensor::cat(&[y_prev, y_next], 0);
        let conditioning = (
            Tensor::cat(&[&normalised, &normalised], 0),
            Tensor::cat(&[&offset, &offset], 0),
        );
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
