//! The conditioned ImitationFlow in tch: `y = R(P_c⁻¹(μ_y + σ_y ⊙ g(z + a(c), ĉ)))`,
//! `ĉ = E((c - μ_c) ⊘ σ_c)`, with the
//! latent dynamics of [`LatentModel`], mirroring `ciflow_engine::flow` parameter for
//! parameter, so `VarStore::save("weights.safetensors")` loads in the pure-Rust policy.

use ciflow_engine::flow::layers::context_set::{encoder_prefix, encoder_sizes, rest_indices};
use ciflow_engine::flow::{ContextSet, FlowConfig};
use tch::nn;
use tch::{Device, Kind, Tensor};

use crate::data::Pairs;
use crate::latent::{LatentInit, LatentModel};
use crate::layers::coupling::{Coupling, CouplingContext};
use crate::layers::joint_range::JointRangeMap;
use crate::layers::mixing::LuMixing;
use crate::layers::radial::Contractions;
use crate::nn::mlp::Mlp;
use crate::nn::row;
use ciflow_engine::flow::checkpoint::names::{LATENT, LAYERS, MIXING};

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
    /// The context indices outside every set, when there are sets, and each set's encoder.
    rest: Option<Tensor>,
    set_encoders: Vec<(ContextSet, Mlp)>,
    contractions: Option<Contractions>,
    joint_range: Option<JointRangeMap>,
}

/// A batch of contexts prepared for the network: what the couplings see and the
/// contraction centres (`[B, count, d]`, raw units).
struct Conditioned {
    couplings: CouplingContext,
    centres: Option<Tensor>,
}

impl FlowModel {
    /// Creates the variables under `path` (names as in the engine) — in a `VarStore`
    /// whose kind is f64 ([`crate::trainer::double_var_store`]).
    pub fn new(path: &nn::Path, config: &FlowConfig, init: LatentInit) -> Self {
        let rest = rest_indices(&config.context_sets, config.context_dim);
        let blocks = (0..config.layers)
            .map(|i| {
                let p = path / LAYERS / i;
                (
                    LuMixing::new(&(&p / MIXING), config.state_dim),
                    Coupling::new(&p, i, config),
                )
            })
            .collect();
        let norm = &config.normalisation;
        Self {
            config: config.clone(),
            blocks,
            latent: LatentModel::new(&(path / LATENT), config, init),
            state_mean: row(&norm.state_mean),
            state_std: row(&norm.state_std),
            context_mean: row(&norm.context_mean),
            context_std: row(&norm.context_std),
            goal_index: config.goal_context_indices.as_deref().map(index_tensor),
            rest: config.set_encoder.as_ref().map(|_| index_tensor(&rest)),
            set_encoders: match &config.set_encoder {
                Some(encoder) => {
                    let rest = rest.len();
                    config
                        .context_sets
                        .iter()
                        .enumerate()
                        .map(|(k, set)| {
                            let sizes = encoder_sizes(set, rest, encoder);
                            let prefix = encoder_prefix(k);
                            let at = prefix.split('.').fold(path.clone(), |p, part| &p / part);
                            (*set, Mlp::new(&at, &sizes, false))
                        })
                        .collect()
                }
                None => Vec::new(),
            },
            contractions: config
                .contractions
                .as_ref()
                .map(|c| Contractions::new(path, c)),
            joint_range: config.joint_range.as_ref().map(JointRangeMap::new),
        }
    }

    /// Per-coordinate standard deviation of the states, `σ_y` as a `[1, d]` row (in the
    /// network's coordinates `R⁻¹(y)` under a joint range).
    pub fn state_std(&self) -> &Tensor {
        &self.state_std
    }

    /// `noise` (in the network's coordinates) as a step in observation units at `y`: the
    /// joint range's slope times it, or itself without one.
    pub fn to_observation_step(&self, y: &Tensor, noise: Tensor) -> Tensor {
        match &self.joint_range {
            Some(range) => noise * range.slope(y),
            None => noise,
        }
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

    fn g_forward(&self, z: &Tensor, context: &CouplingContext) -> (Tensor, Tensor) {
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

    fn g_inverse(&self, y: &Tensor, context: &CouplingContext) -> (Tensor, Tensor) {
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

    /// What the couplings see for normalised contexts `[B, m]`: `ĉ` (the entries outside
    /// the sets, then each set's mean-pooled encoding, `ciflow_engine::flow::layers::context_set`)
    /// and each set's elements.
    fn encode(&self, normalised: &Tensor) -> CouplingContext {
        let Some(rest) = &self.rest else {
            return CouplingContext {
                encoded: normalised.shallow_clone(),
                elements: Vec::new(),
            };
        };
        let rest = normalised.index_select(1, rest);
        let rows = normalised.size()[0];
        let mut parts = vec![rest.shallow_clone()];
        let mut elements = Vec::new();
        for (set, encoder) in &self.set_encoders {
            let (count, size) = (set.count as i64, set.size as i64);
            let set_elements = normalised
                .narrow(1, set.start as i64, count * size)
                .reshape([rows, count, size]);
            let others = rest.unsqueeze(1).expand([rows, count, -1], false);
            let input = Tensor::cat(&[&set_elements, &others], 2);
            parts.push(encoder.forward(&input).mean_dim(1, false, Kind::Double));
            elements.push(set_elements);
        }
        CouplingContext {
            encoded: Tensor::cat(&parts, 1),
            elements,
        }
    }

    /// `(ĉ, centres)` for raw contexts `[B, m]`.
    fn condition(&self, context: &Tensor) -> Conditioned {
        let normalised = (context - &self.context_mean) / &self.context_std;
        let centres = self.contractions.as_ref().map(|p| p.centres(context));
        Conditioned {
            couplings: self.encode(&normalised),
            centres,
        }
    }

    /// `x̃ = (P_c(R⁻¹(y)) - μ_y) ⊘ σ_y` and `log|det ∂(P_c ∘ R⁻¹)/∂y|` per row.
    fn enter(&self, y: &Tensor, conditioned: &Conditioned) -> (Tensor, Tensor) {
        let (w, range_log_det) = match &self.joint_range {
            Some(range) => {
                let (w, log_det) = range.invert(y);
                (w, Some(log_det))
            }
            None => (y.shallow_clone(), None),
        };
        let (u, log_det) = self.contract(&w, &conditioned.centres);
        let log_det = match range_log_det {
            Some(range_log_det) => log_det + range_log_det,
            None => log_det,
        };
        ((u - &self.state_mean) / &self.state_std, log_det)
    }

    /// `y = f(z, c)` and `log|det ∂f/∂z|` per row; through the contractions without
    /// gradient (their inverse is iterative: only inference needs it).
    pub fn forward(&self, z: &Tensor, context: &Tensor) -> (Tensor, Tensor) {
        let conditioned = self.condition(context);
        let shifted = match self.anchors(context, &conditioned) {
            Some(anchor) => z + anchor,
            None => z.shallow_clone(),
        };
        let (x, log_det) = self.g_forward(&shifted, &conditioned.couplings);
        let u = x * &self.state_std + &self.state_mean;
        let log_det = log_det + self.log_state_scale();
        let (w, log_det) = match (&self.contractions, &conditioned.centres) {
            (Some(p), Some(centres)) => {
                let w = p.invert(&u, centres);
                let contraction_log_det = p.apply(&w, centres).1;
                (w, log_det - contraction_log_det)
            }
            _ => (u, log_det),
        };
        match &self.joint_range {
            Some(range) => {
                let (y, range_log_det) = range.apply(&w);
                (y, log_det + range_log_det)
            }
            None => (w, log_det),
        }
    }

    /// The anchors `a(c) = g⁻¹(x̃_target(c), c̃)` per row, when the target is in the context.
    fn anchors(&self, context: &Tensor, conditioned: &Conditioned) -> Option<Tensor> {
        let index = self.goal_index.as_ref()?;
        let target = self.enter(&context.index_select(1, index), conditioned).0;
        Some(self.g_inverse(&target, &conditioned.couplings).0)
    }

    /// `z = f⁻¹(y, c)` and `log|det ∂f⁻¹/∂y|` per row. With the target in the context, its
    /// anchor `a(c)` is inverted in the same batch as `y`, once per distinct context (a
    /// batch of transitions holds few: one per episode), so the anchoring costs a few
    /// rows rather than a second pass through the network.
    pub fn inverse(&self, y: &Tensor, context: &Tensor) -> (Tensor, Tensor) {
        let conditioned = self.condition(context);
        let (x, contraction_log_det) = self.enter(y, &conditioned);
        let log_det = contraction_log_det - self.log_state_scale();
        let Some(index) = &self.goal_index else {
            let (z, g_log_det) = self.g_inverse(&x, &conditioned.couplings);
            return (z, log_det + g_log_det);
        };
        let rows = y.size()[0];
        let (distinct_raw, row_of, _) = context.unique_dim(0, false, true, false);
        let distinct = self.condition(&distinct_raw);
        let targets = self
            .enter(&distinct_raw.index_select(1, index), &distinct)
            .0;
        let (z, g_log_det) = self.g_inverse(
            &Tensor::cat(&[&x, &targets], 0),
            &conditioned.couplings.cat(&distinct.couplings),
        );
        let anchor = z
            .narrow(0, rows, targets.size()[0])
            .index_select(0, &row_of);
        (
            z.narrow(0, 0, rows) - anchor,
            log_det + g_log_det.narrow(0, 0, rows),
        )
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

    /// `log p(y_next | y_prev, c)` per row, with `c` the context at `y_prev`; row `i` spans
    /// `steps[i]` steps of `dt` ([`LatentModel::log_transition`]).
    pub fn log_transition(
        &self,
        y_prev: &Tensor,
        y_next: &Tensor,
        context: &Tensor,
        steps: &Tensor,
        max_steps: usize,
    ) -> Tensor {
        let pairs = Pairs {
            prev: y_prev.shallow_clone(),
            next: y_next.shallow_clone(),
            context: context.shallow_clone(),
            steps: steps.shallow_clone(),
        };
        let none = |t: &Tensor| t.narrow(0, 0, 0);
        self.log_densities(&pairs, max_steps, &none(y_prev), &none(context))
            .0
    }

    /// `(log p(y_next | y_prev, c), log p(y₀ | c₀))` per row of `pairs` (spans of at most
    /// `max_steps`) and of the starts, in one pass through the network: every end, and
    /// the anchor of each distinct context among them, is inverted in a single batch.
    pub fn log_densities(
        &self,
        pairs: &Pairs,
        max_steps: usize,
        starts: &Tensor,
        start_contexts: &Tensor,
    ) -> (Tensor, Tensor) {
        let rows = pairs.prev.size()[0];
        let ends = Tensor::cat(&[&pairs.prev, &pairs.next, starts], 0);
        let contexts = Tensor::cat(&[&pairs.context, &pairs.context, start_contexts], 0);
        let (z, log_det) = self.inverse(&ends, &contexts);
        let (z_prev, z_next) = (z.narrow(0, 0, rows), z.narrow(0, rows, rows));
        let log_transition = self
            .latent
            .log_transition(&z_prev, &z_next, &pairs.steps, max_steps)
            + log_det.narrow(0, rows, rows);
        let first = 2 * rows;
        let count = starts.size()[0];
        let log_initial =
            self.latent.log_initial(&z.narrow(0, first, count)) + log_det.narrow(0, first, count);
        (log_transition, log_initial)
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

/// Context indices as an `i64` tensor for `index_select`.
fn index_tensor(indices: &[usize]) -> Tensor {
    Tensor::from_slice(&indices.iter().map(|&i| i as i64).collect::<Vec<_>>())
        .to_device(Device::Cpu)
}
