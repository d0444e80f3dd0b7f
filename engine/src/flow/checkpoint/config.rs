//! The JSON half of a checkpoint: architecture, dimensions, normalisation, latent type,
//! task name. The other half, `weights.safetensors`, holds the parameters named by
//! [`FlowConfig::parameter_shapes`] / [`BaselineConfig::parameter_shapes`].

use std::collections::BTreeMap;

use serde::{Deserialize, Serialize};

use crate::math::distance;

use crate::flow::checkpoint::names::{
    self, BIAS, CONDITIONER, FACTOR, LATENT, LAYERS, LOG_DIAG, LOG_RADIUS, LOG_RATE, LOG_SIGMA,
    LOG_SIGMA0, LOG_SPEED, LOWER, MIXING, NET, OMEGA, SKEW, UPPER,
};
use crate::flow::error::{FlowResult, invalid};
use crate::flow::layers::context_set::{
    ContextSet, LocalConfig, SetEncoderConfig, encoder_parameter_shapes, local_prefix, local_sizes,
    rest_indices,
};
use crate::flow::layers::joint_range::JointRange;
use crate::flow::layers::radial::ContractionConfig;
use crate::nn::mlp::mlp_parameter_shapes;

/// Minimum bin width / height and knot derivative of the rational-quadratic spline
/// (the defaults of Durkan et al. 2019).
pub const SPLINE_MIN_BIN: f64 = 1e-3;
pub const SPLINE_MIN_DERIVATIVE: f64 = 1e-3;

/// The bound `B` of [`CouplingKind::AFFINE`]'s log-scales.
pub const AFFINE_SCALE_BOUND: f64 = 2.0;

/// The element-wise transform of a coupling layer.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(tag = "type", rename_all = "snake_case")]
pub enum CouplingKind {
    /// `y = x·e^s + t` with `s = B·tanh(ŝ/B)`, so `|log-scale| < B` everywhere.
    Affine {
        scale_bound: f64,
        /// `R`: the conditioner's outputs fade with the kept coordinates' distance from
        /// the origin, so the layer tends to the identity beyond `R` (normalised units;
        /// [`crate::flow::layers::taper`]). Checkpoints without the key do not fade.
        #[serde(default, skip_serializing_if = "Option::is_none")]
        taper_radius: Option<f64>,
    },
    /// Monotone rational-quadratic spline on `[-B, B]` with `bins` bins, identity outside.
    Spline { bins: usize, tail_bound: f64 },
}

impl CouplingKind {
    /// The affine coupling the recipes and `--coupling affine` use: log-scales bounded
    /// by 2 (a factor of e² per layer at most), no taper.
    pub const AFFINE: Self = Self::Affine {
        scale_bound: AFFINE_SCALE_BOUND,
        taper_radius: None,
    };

    /// Conditioner outputs per transformed dimension.
    pub fn params_per_dim(&self) -> usize {
        match self {
            Self::Affine { .. } => 2,
            Self::Spline { bins, .. } => 3 * bins - 1,
        }
    }
}

/// The latent attractor.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum LatentKind {
    /// A fixed point at the origin: `z_{k+1} = exp(A·dt) z_k + ε`.
    GoTo,
    /// A fixed point at the origin approached at bounded speed while turning about it:
    /// `ż = -v tanh(λρ/v) z/ρ + Ω z` for `ρ = ‖z‖`, `Ω` skew (constant radial speed `v`
    /// far away, rate `λ` near).
    SaturatedGoTo,
    /// A circle of radius `ρ*` in the first two latent dimensions, a fixed point in the rest.
    LimitCycle,
}

impl LatentKind {
    /// Whether the motion ends at a point (the origin), so `f(0, c)` is the attractor.
    pub fn is_go_to(self) -> bool {
        matches!(self, Self::GoTo | Self::SaturatedGoTo)
    }
}

/// Affine normalisation `x = mean + std ⊙ x̃` of states and contexts; part of the model.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Normalisation {
    pub state_mean: Vec<f64>,
    pub state_std: Vec<f64>,
    pub context_mean: Vec<f64>,
    pub context_std: Vec<f64>,
}

impl Normalisation {
    pub fn identity(state_dim: usize, context_dim: usize) -> Self {
        Self {
            state_mean: vec![0.0; state_dim],
            state_std: vec![1.0; state_dim],
            context_mean: vec![0.0; context_dim],
            context_std: vec![1.0; context_dim],
        }
    }

    fn validate(&self, state_dim: usize, context_dim: usize) -> FlowResult<()> {
        for (name, v, n, positive) in [
            ("state_mean", &self.state_mean, state_dim, false),
            ("state_std", &self.state_std, state_dim, true),
            ("context_mean", &self.context_mean, context_dim, false),
            ("context_std", &self.context_std, context_dim, true),
        ] {
            if v.len() != n {
                return Err(invalid(format!(
                    "normalisation.{name} has {} entries, expected {n}",
                    v.len()
                )));
            }
            if v.iter().any(|x| !x.is_finite() || (positive && *x <= 0.0)) {
                return Err(invalid(format!(
                    "normalisation.{name} must be finite{}",
                    if positive { " and > 0" } else { "" }
                )));
            }
        }
        Ok(())
    }
}

/// The demonstrations' bounding box; the stability check samples starts around it.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Bounds {
    pub state_min: Vec<f64>,
    pub state_max: Vec<f64>,
    pub context_min: Vec<f64>,
    pub context_max: Vec<f64>,
}

impl Bounds {
    fn validate(&self, state_dim: usize, context_dim: usize) -> FlowResult<()> {
        for (name, lo, hi, n) in [
            ("state", &self.state_min, &self.state_max, state_dim),
            ("context", &self.context_min, &self.context_max, context_dim),
        ] {
            if lo.len() != n || hi.len() != n {
                return Err(invalid(format!("bounds.{name}_min/max need {n} entries")));
            }
            if lo
                .iter()
                .zip(hi)
                .any(|(a, b)| !a.is_finite() || !b.is_finite() || a > b)
            {
                return Err(invalid(format!(
                    "bounds.{name}_min must be finite and <= {name}_max"
                )));
            }
        }
        Ok(())
    }

    /// Length of the state box's diagonal: the unit of the stability tolerances.
    pub fn state_diagonal(&self) -> f64 {
        distance(&self.state_min, &self.state_max)
    }
}

/// The checkpoint format this build reads and writes. Format 2 anchors a go-to target by
/// shifting the latent ([`crate::flow::network`]); format 1 shifted the network's output, so
/// the same weights meant another map.
pub const FORMAT: u32 = 2;

fn first_format() -> u32 {
    1
}

/// Architecture and data description of a conditioned ImitationFlow
/// `y = f(z, c)`, `z_{k+1} ~ p(z_{k+1} | z_k)`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct FlowConfig {
    /// Checkpoint format ([`FORMAT`]); configurations without the key are format 1.
    #[serde(default = "first_format")]
    pub format: u32,
    /// Name of the task the policy was trained for; loading checks it.
    pub task: String,
    /// The task's construction arguments (numbers, or texts such as the reach task's URDF
    /// document): what builds the same task and robot to act in and to check it on.
    /// Checkpoints without the key were trained on the task's defaults.
    #[serde(default, skip_serializing_if = "BTreeMap::is_empty")]
    pub task_kwargs: BTreeMap<String, serde_json::Value>,
    /// `d`, the dimension of `y` and `z`.
    pub state_dim: usize,
    /// `m`, the dimension of `c` (0: the unconditioned ImitationFlow).
    pub context_dim: usize,
    /// Sampling period of the transitions, in seconds.
    pub dt: f64,
    pub latent: LatentKind,
    /// `ε` in `A = -(L Lᵀ + ε I) + (W - Wᵀ)`: the guaranteed latent contraction rate (1/s).
    pub min_rate: f64,
    pub coupling: CouplingKind,
    /// Number of (mixing, coupling) blocks.
    pub layers: usize,
    /// Hidden widths of each conditioner MLP.
    pub hidden: Vec<usize>,
    /// For go-to tasks whose target is part of the context: `target(c) = c[indices]`
    /// (raw units, one index per state dimension); the attractor then sits on it.
    #[serde(default)]
    pub goal_context_indices: Option<Vec<usize>>,
    /// Unordered sets in the context, which the conditioners see through permutation-
    /// invariant encoders ([`crate::flow::layers::context_set`]); the goal is read from the raw
    /// context. Checkpoints without the key have none.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub context_sets: Vec<ContextSet>,
    /// The set encoders' architecture: present exactly when there are sets.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub set_encoder: Option<SetEncoderConfig>,
    /// Radial contractions about context points in front of the network
    /// ([`crate::flow::layers::radial`]); checkpoints without the key have none.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub contractions: Option<ContractionConfig>,
    /// A robot's joint limits, as the last layer of `f` and bounds of the commands
    /// ([`crate::flow::layers::joint_range`]); checkpoints without the key have none.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub joint_range: Option<JointRange>,
    /// Statistics of the states and of the contexts (a set's slots share theirs).
    pub normalisation: Normalisation,
    /// Box of the states and of the raw contexts.
    pub bounds: Bounds,
}

impl FlowConfig {
    /// A configuration with identity normalisation and unit bounds, for tests and benches.
    pub fn new(
        task: &str,
        state_dim: usize,
        context_dim: usize,
        latent: LatentKind,
        coupling: CouplingKind,
        layers: usize,
        hidden: Vec<usize>,
    ) -> Self {
        Self {
            format: FORMAT,
            task: task.to_owned(),
            task_kwargs: BTreeMap::new(),
            state_dim,
            context_dim,
            dt: 0.01,
            latent,
            min_rate: 0.1,
            coupling,
            layers,
            hidden,
            goal_context_indices: None,
            context_sets: Vec::new(),
            set_encoder: None,
            contractions: None,
            joint_range: None,
            normalisation: Normalisation::identity(state_dim, context_dim),
            bounds: Bounds {
                state_min: vec![-1.0; state_dim],
                state_max: vec![1.0; state_dim],
                context_min: vec![-1.0; context_dim],
                context_max: vec![1.0; context_dim],
            },
        }
    }

    /// Dimensions left unchanged by each coupling layer (they feed the conditioner).
    pub fn kept_dim(&self) -> usize {
        self.state_dim / 2
    }

    /// Dimensions each coupling layer transforms.
    pub fn transformed_dim(&self) -> usize {
        self.state_dim - self.kept_dim()
    }

    /// `|ĉ|`, the dimension of the conditioning vector the conditioners see: the context
    /// itself without sets, else its entries outside them and one summary per set
    /// ([`crate::flow::layers::context_set`]).
    pub fn conditioning_dim(&self) -> usize {
        match &self.set_encoder {
            Some(encoder) => {
                rest_indices(&self.context_sets, self.context_dim).len()
                    + self.context_sets.len() * encoder.width
            }
            None => self.context_dim,
        }
    }

    /// The couplings' local element networks ([`crate::flow::layers::conditioner`]), if any.
    pub fn local(&self) -> Option<&LocalConfig> {
        self.set_encoder.as_ref().and_then(|e| e.local.as_ref())
    }

    /// `K W_ψ`, the width of the local features pooled in each coupling.
    pub fn local_features_dim(&self) -> usize {
        self.local()
            .map_or(0, |l| self.context_sets.len() * l.width)
    }

    /// Layer sizes of the conditioner MLP:
    /// `[kept + K W_ψ + |ĉ|, hidden.., transformed · P]`.
    pub fn conditioner_sizes(&self) -> Vec<usize> {
        let mut sizes = vec![self.kept_dim() + self.local_features_dim() + self.conditioning_dim()];
        sizes.extend(&self.hidden);
        sizes.push(self.transformed_dim() * self.coupling.params_per_dim());
        sizes
    }

    /// Dimension of the linear latent attractor (all of `z` for go-to, `z[2..]` for cycles).
    pub fn linear_latent_dim(&self) -> usize {
        match self.latent {
            LatentKind::GoTo => self.state_dim,
            LatentKind::SaturatedGoTo => 0,
            LatentKind::LimitCycle => self.state_dim - 2,
        }
    }

    /// Every parameter's name and shape, as the trainer's `VarStore` names them.
    pub fn parameter_shapes(&self) -> Vec<(String, Vec<usize>)> {
        let d = self.state_dim;
        let mut shapes = Vec::new();
        for i in 0..self.layers {
            let prefix = names::name(&[&LAYERS, &i]);
            let mixing = |p: &str| names::name(&[&prefix, &MIXING, &p]);
            shapes.push((mixing(LOWER), vec![d, d]));
            shapes.push((mixing(UPPER), vec![d, d]));
            shapes.push((mixing(LOG_DIAG), vec![d]));
            shapes.push((mixing(BIAS), vec![d]));
            shapes.extend(mlp_parameter_shapes(
                &names::name(&[&prefix, &CONDITIONER]),
                &self.conditioner_sizes(),
            ));
            if let Some(local) = self.local() {
                for (k, set) in self.context_sets.iter().enumerate() {
                    let sizes = local_sizes(set, self.kept_dim(), self.conditioning_dim(), local);
                    shapes.extend(mlp_parameter_shapes(&local_prefix(&prefix, k), &sizes));
                }
            }
        }
        let latent = |p: &str| names::name(&[&LATENT, &p]);
        shapes.push((latent(LOG_SIGMA), vec![d]));
        shapes.push((latent(LOG_SIGMA0), vec![d]));
        let r = self.linear_latent_dim();
        if r > 0 {
            shapes.push((latent(FACTOR), vec![r, r]));
            shapes.push((latent(SKEW), vec![r, r]));
        }
        if self.latent == LatentKind::SaturatedGoTo {
            shapes.push((latent(SKEW), vec![d, d]));
        }
        let scalars: &[&str] = match self.latent {
            LatentKind::GoTo => &[],
            LatentKind::SaturatedGoTo => &[LOG_RATE, LOG_SPEED],
            LatentKind::LimitCycle => &[LOG_RADIUS, LOG_RATE, OMEGA],
        };
        for name in scalars {
            shapes.push((latent(name), vec![1]));
        }
        if let Some(encoder) = &self.set_encoder {
            shapes.extend(encoder_parameter_shapes(
                &self.context_sets,
                self.context_dim,
                encoder,
            ));
        }
        if let Some(contractions) = &self.contractions {
            for l in 0..contractions.layers {
                shapes.extend(ContractionConfig::parameter_names(l).map(|name| (name, vec![1])));
            }
        }
        shapes
    }

    pub fn validate(&self) -> FlowResult<()> {
        if self.format != FORMAT {
            return Err(invalid(format!(
                "checkpoint format {} is not this build's {FORMAT}: retrain the policy",
                self.format
            )));
        }
        let (d, m) = (self.state_dim, self.context_dim);
        if d < 2 {
            // The couplings transform one part of the state conditioned on the other, and
            // the latent turns and contracts in the plane of its first two coordinates.
            return Err(invalid(format!(
                "the state has {d} dimension(s); a flow needs at least 2 (its couplings \
                 split the state in two, its latent acts in a plane)"
            )));
        }
        if !(self.dt.is_finite() && self.dt > 0.0) {
            return Err(invalid("dt must be finite and > 0".into()));
        }
        if !(self.min_rate.is_finite() && self.min_rate > 0.0) {
            return Err(invalid("min_rate must be finite and > 0".into()));
        }
        if self.layers == 0 || self.hidden.is_empty() || self.hidden.contains(&0) {
            return Err(invalid("layers and hidden widths must be >= 1".into()));
        }
        match self.coupling {
            CouplingKind::Affine { scale_bound, .. }
                if !(scale_bound.is_finite() && scale_bound > 0.0) =>
            {
                return Err(invalid("affine scale_bound must be finite and > 0".into()));
            }
            CouplingKind::Affine {
                taper_radius: Some(radius),
                ..
            } if !(radius.is_finite() && radius > 0.0) => {
                return Err(invalid("affine taper_radius must be finite and > 0".into()));
            }
            CouplingKind::Spline { bins, tail_bound }
                if bins < 2
                    || !(tail_bound.is_finite() && tail_bound > 0.0)
                    || (bins as f64) * SPLINE_MIN_BIN >= 1.0 =>
            {
                return Err(invalid(
                    "spline needs bins in [2, 999] and a finite tail_bound > 0".into(),
                ));
            }
            _ => {}
        }
        if let Some(indices) = &self.goal_context_indices {
            if !self.latent.is_go_to() {
                return Err(invalid("goal_context_indices needs a go-to latent".into()));
            }
            if indices.len() != d || indices.iter().any(|&i| i >= m) {
                return Err(invalid(format!(
                    "goal_context_indices needs {d} indices into a context of dimension {m}"
                )));
            }
        }
        validate_context_sets(&self.context_sets, m)?;
        for set in &self.context_sets {
            let norm = &self.normalisation;
            let shared = |stats: &[f64]| {
                let slots = stats[set.start..set.end()].chunks_exact(set.size);
                slots
                    .clone()
                    .all(|slot| slot == &stats[set.start..set.start + set.size])
            };
            if !(shared(&norm.context_mean) && shared(&norm.context_std)) {
                return Err(invalid(format!(
                    "the slots of the context set ({set}) need the same normalisation"
                )));
            }
        }
        match &self.set_encoder {
            None if !self.context_sets.is_empty() => {
                return Err(invalid("context sets need a set_encoder".into()));
            }
            Some(_) if self.context_sets.is_empty() => {
                return Err(invalid("set_encoder without context sets".into()));
            }
            Some(e)
                if e.width == 0
                    || e.hidden.contains(&0)
                    || e.local
                        .as_ref()
                        .is_some_and(|l| l.width == 0 || l.hidden.contains(&0)) =>
            {
                return Err(invalid("set_encoder widths must be >= 1".into()));
            }
            _ => {}
        }
        if let Some(contractions) = &self.contractions {
            contractions.validate(d, m)?;
        }
        if let Some(range) = &self.joint_range {
            if self.contractions.is_some() {
                // The contractions' centres are raw positions, in front of the network.
                return Err(invalid(
                    "joint_range and contractions cannot be combined".into(),
                ));
            }
            range.validate(d)?;
        }
        self.normalisation.validate(d, m)?;
        self.bounds.validate(d, m)
    }
}

/// Sets need elements of at least one entry, must lie inside a context of dimension `m`
/// and must not overlap.
pub fn validate_context_sets(sets: &[ContextSet], m: usize) -> FlowResult<()> {
    let mut sorted = sets.to_vec();
    sorted.sort_by_key(|s| s.start);
    for (i, set) in sorted.iter().enumerate() {
        if set.count == 0 || set.size == 0 || set.end() > m {
            return Err(invalid(format!(
                "the context set ({set}) needs count and size >= 1 and must end within the \
                 {m}-D context"
            )));
        }
        if let Some(next) = sorted.get(i + 1)
            && next.start < set.end()
        {
            return Err(invalid(format!(
                "the context sets ({set}) and ({next}) overlap"
            )));
        }
    }
    Ok(())
}

/// The negative control for stability: unconstrained behaviour cloning
/// `ỹ_{k+1} = ỹ_k + dt · MLP(ỹ_k, c̃)` in normalised coordinates.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct BaselineConfig {
    pub task: String,
    /// The task's construction arguments, as [`FlowConfig::task_kwargs`]: the arm a reach
    /// baseline acts on. Checkpoints without the key were trained on the task's defaults.
    #[serde(default, skip_serializing_if = "BTreeMap::is_empty")]
    pub task_kwargs: BTreeMap<String, serde_json::Value>,
    pub state_dim: usize,
    pub context_dim: usize,
    pub dt: f64,
    pub hidden: Vec<usize>,
    /// The attractor the demonstrations go to: `c[indices]` or a fixed state (raw units).
    pub goal: Goal,
    pub normalisation: Normalisation,
    pub bounds: Bounds,
}

/// Where a go-to task's attractor is, for models that have none built in.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(tag = "type", rename_all = "snake_case")]
pub enum Goal {
    ContextIndices { indices: Vec<usize> },
    State { value: Vec<f64> },
}

impl BaselineConfig {
    pub fn mlp_sizes(&self) -> Vec<usize> {
        let mut sizes = vec![self.state_dim + self.context_dim];
        sizes.extend(&self.hidden);
        sizes.push(self.state_dim);
        sizes
    }

    pub fn parameter_shapes(&self) -> Vec<(String, Vec<usize>)> {
        mlp_parameter_shapes(NET, &self.mlp_sizes())
    }

    pub fn validate(&self) -> FlowResult<()> {
        let (d, m) = (self.state_dim, self.context_dim);
        if d == 0 || !(self.dt.is_finite() && self.dt > 0.0) {
            return Err(invalid(
                "state_dim must be >= 1 and dt finite and > 0".into(),
            ));
        }
        if self.hidden.is_empty() || self.hidden.contains(&0) {
            return Err(invalid("hidden widths must be >= 1".into()));
        }
        match &self.goal {
            Goal::ContextIndices { indices }
                if indices.len() != d || indices.iter().any(|&i| i >= m) =>
            {
                return Err(invalid(format!(
                    "goal needs {d} indices into a context of dimension {m}"
                )));
            }
            Goal::State { value } if value.len() != d || value.iter().any(|v| !v.is_finite()) => {
                return Err(invalid(format!("goal state needs {d} finite entries")));
            }
            _ => {}
        }
        self.normalisation.validate(d, m)?;
        self.bounds.validate(d, m)
    }
}

/// What `config.json` holds: one of the two model families.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(tag = "model", rename_all = "snake_case")]
// Read once per checkpoint load and never stored in bulk: boxing the larger variant would
// save nothing that matters.
#[allow(clippy::large_enum_variant)]
pub enum CheckpointConfig {
    Flow(FlowConfig),
    MlpBaseline(BaselineConfig),
}

impl CheckpointConfig {
    pub fn task(&self) -> &str {
        match self {
            Self::Flow(c) => &c.task,
            Self::MlpBaseline(c) => &c.task,
        }
    }

    pub fn model_name(&self) -> &'static str {
        match self {
            Self::Flow(_) => "flow",
            Self::MlpBaseline(_) => "mlp_baseline",
        }
    }
}
