//! Settings that replace a task's training recipe (`TaskEntry::training_recipe`) where
//! they are given: what `ciflow train` and `ciflow lasa` accept on the command line. With
//! the `clap` feature both structs are `clap::Args`, documented once here for `--help`.
//!
//! [`RecipeOverrides`] covers the network, the latent and the optimisation, for any task;
//! [`ContextOverrides`] how the context is read (where the target sits, which entries form
//! unordered sets, the radial contractions about obstacle centres).

use ciflow_engine::flow::{
    AFFINE_SCALE_BOUND, ContextSet, ContractionConfig, CouplingKind, JointRange, LatentKind,
    LocalConfig, SetEncoderConfig,
};

use crate::{Keep, OptimConfig, TrainConfig};

/// Widest layer `--hidden` and `--local-features` may ask for. The recipes use 32 to 64;
/// each coupling's `ψ` has a hidden layer twice as wide as its local features, so 1024
/// already means a 2048 × 1024 f64 layer (16 MB, 48 MB with Adam's moments) per coupling
/// and set, while 100 000 would need 160 GB for one such layer.
pub const MAX_WIDTH: usize = 1024;

/// A setting given that does not fit the recipe it would replace.
#[derive(Debug, thiserror::Error)]
pub enum OverrideError {
    #[error(
        "--spline-bins and --tail-bound set a spline coupling, and this one is affine (add \
         --coupling spline)"
    )]
    SplineSettingsOnAffine,
    #[error(
        "--taper-radius fades an affine coupling, and this one is a spline (add --coupling affine)"
    )]
    TaperOnSpline,
    #[error("--taper-radius {0}: a radius is finite and > 0 (0 turns the taper off)")]
    TaperRadius(f64),
    #[error("--contraction-layers: task `{task}` has no centres to contract about")]
    NoCentres { task: String },
    #[error("--joint-range: task `{task}` drives no robot whose limits it could respect")]
    NoJointRange { task: String },
    #[error("{flag} {width}: at most {MAX_WIDTH} units per layer")]
    TooWide { flag: &'static str, width: usize },
}

/// The coupling layers, by name.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "clap", derive(clap::ValueEnum))]
pub enum CouplingChoice {
    /// Affine coupling with tanh-bounded log-scale.
    Affine,
    /// Rational-quadratic spline coupling with identity tails.
    Spline,
}

/// The latent attractor, by name.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "clap", derive(clap::ValueEnum))]
pub enum LatentChoice {
    /// Fixed-point attractor.
    GoTo,
    /// Fixed-point attractor approached at bounded speed.
    SaturatedGoTo,
    /// Limit cycle in the first two latent dimensions.
    LimitCycle,
}

impl From<LatentChoice> for LatentKind {
    fn from(latent: LatentChoice) -> Self {
        match latent {
            LatentChoice::GoTo => LatentKind::GoTo,
            LatentChoice::SaturatedGoTo => LatentKind::SaturatedGoTo,
            LatentChoice::LimitCycle => LatentKind::LimitCycle,
        }
    }
}

/// Which epoch's parameters to keep, by name.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "clap", derive(clap::ValueEnum))]
pub enum KeepChoice {
    /// The epoch with the best validation score (early stopping).
    BestValidation,
    /// The last epoch's.
    Last,
}

impl From<KeepChoice> for Keep {
    fn from(keep: KeepChoice) -> Self {
        match keep {
            KeepChoice::BestValidation => Keep::BestValidation,
            KeepChoice::Last => Keep::Last,
        }
    }
}

/// Architecture and optimisation settings; those not given keep the task's recipe.
#[derive(Clone, Debug, Default, PartialEq)]
#[cfg_attr(feature = "clap", derive(clap::Args))]
pub struct RecipeOverrides {
    /// Latent attractor [default: the task's: limit-cycle for limit-cycle, saturated-go-to
    /// for lasa, else go-to].
    #[cfg_attr(feature = "clap", arg(long, value_enum))]
    pub latent: Option<LatentChoice>,
    /// Coupling layers [default: the task's: affine for lasa, pouring and reach, else
    /// spline].
    #[cfg_attr(feature = "clap", arg(long, value_enum))]
    pub coupling: Option<CouplingChoice>,
    /// Bins of each spline coupling [default: the task's spline's, else 8].
    #[cfg_attr(feature = "clap", arg(long))]
    pub spline_bins: Option<usize>,
    /// Half-width `B` of the spline's interval `[-B, B]` (normalised units; identity
    /// outside) [default: the task's spline's, else 4].
    #[cfg_attr(feature = "clap", arg(long))]
    pub tail_bound: Option<f64>,
    /// Radius `R` beyond which each affine coupling fades to the identity (normalised
    /// units; README "LASA" has why); 0 turns it off [default: the task's: 8 for lasa and
    /// pouring, else off].
    #[cfg_attr(feature = "clap", arg(long))]
    pub taper_radius: Option<f64>,
    /// Number of (mixing, coupling) blocks [default: the task's: 10 for lasa, pouring and
    /// reach, else 6].
    #[cfg_attr(feature = "clap", arg(long))]
    pub layers: Option<usize>,
    /// Hidden widths of each conditioner MLP, comma-separated [default: the task's: 32,32
    /// for lasa and pouring, else 64,64].
    #[cfg_attr(feature = "clap", arg(long, value_delimiter = ','))]
    pub hidden: Option<Vec<usize>>,
    /// Guaranteed latent contraction rate (1/s) [default: the task's: 1 for go-to tasks,
    /// whose demonstrations arrive within 2–9 s; 0.2 for lasa, whose saturated latent
    /// keeps its constant pace only where it is faster than this rate; 0.1 for the limit
    /// cycle].
    #[cfg_attr(feature = "clap", arg(long))]
    pub min_rate: Option<f64>,
    /// Gaussian jitter added to training states, as a fraction of the demonstrations' RMS
    /// step; gives deterministic (expert) demonstrations a bounded likelihood; 0 trains
    /// on the states as recorded (exact maximum likelihood) [default: the task's: 0 for
    /// lasa and the limit cycle, else 0.1].
    #[cfg_attr(feature = "clap", arg(long))]
    pub state_noise: Option<f64>,
    /// Longest modelled transition: each training pair spans k ~ U{1..K} steps, scored
    /// with the exact k-step density (1: one-step transitions) [default: the task's: 40
    /// for lasa and the limit cycle, else 1].
    #[cfg_attr(feature = "clap", arg(long))]
    pub horizon: Option<usize>,
    /// Share of the training pairs whose span runs to the end of their demonstration
    /// (0: none) [default: the task's: 0.25 for lasa, else 0].
    #[cfg_attr(feature = "clap", arg(long))]
    pub arrival: Option<f64>,
    /// Fraction of the demonstrations held out for early stopping (0: fit all of them,
    /// the training loss stands in for the validation score) [default: the task's: 0 for
    /// lasa, pouring and the limit cycle, else 0.2].
    #[cfg_attr(feature = "clap", arg(long))]
    pub validation_fraction: Option<f64>,
    /// Epoch budget [default: the task's: 30 for lasa, 10 for pouring, 6 for reach, else
    /// 200].
    #[cfg_attr(feature = "clap", arg(long))]
    pub epochs: Option<usize>,
    /// Training pairs per step [default: the task's: 512 for pouring and reach, else 256].
    #[cfg_attr(feature = "clap", arg(long))]
    pub batch_size: Option<usize>,
    /// Initial learning rate [default: the recipe's, 2e-3].
    #[cfg_attr(feature = "clap", arg(long))]
    pub learning_rate: Option<f64>,
    /// Early-stopping patience in epochs [default: the recipe's, 30].
    #[cfg_attr(feature = "clap", arg(long))]
    pub patience: Option<usize>,
    /// Which epoch's parameters to keep [default: the task's: last for lasa, pouring and
    /// the limit cycle, else best-validation].
    #[cfg_attr(feature = "clap", arg(long, value_enum))]
    pub keep: Option<KeepChoice>,
    /// Seed of the initial weights, the hold-out and the batches [default: 0].
    #[cfg_attr(feature = "clap", arg(long))]
    pub seed: Option<u64>,
    /// libtorch threads [default: 1].
    #[cfg_attr(feature = "clap", arg(long))]
    pub threads: Option<i32>,
    /// Build the task's robot's joint limits into the policy: its last layer maps onto
    /// the position ranges, its velocity is time-scaled into the speed limits and
    /// braking distance, its acceleration scaled into bounds [default: false; README
    /// "Joint limits" has why].
    #[cfg_attr(feature = "clap", arg(long))]
    pub joint_range: Option<bool>,
}

impl RecipeOverrides {
    /// `recipe` with the settings given in its place. The spline settings apply to
    /// whichever spline the coupling is; with an affine one they are an error rather than
    /// silently ignored. `robot` is the range of the task's robot, if it drives one.
    pub fn apply(
        &self,
        recipe: TrainConfig,
        robot: Option<JointRange>,
    ) -> Result<TrainConfig, OverrideError> {
        let (bins, tail_bound) = match recipe.coupling {
            CouplingKind::Spline { bins, tail_bound } => (bins, tail_bound),
            CouplingKind::Affine { .. } => (8, 4.0),
        };
        let spline = CouplingKind::Spline {
            bins: self.spline_bins.unwrap_or(bins),
            tail_bound: self.tail_bound.unwrap_or(tail_bound),
        };
        let spline_settings = self.spline_bins.is_some() || self.tail_bound.is_some();
        let (scale_bound, recipe_taper) = match recipe.coupling {
            CouplingKind::Affine {
                scale_bound,
                taper_radius,
            } => (scale_bound, taper_radius),
            CouplingKind::Spline { .. } => (AFFINE_SCALE_BOUND, None),
        };
        let taper_radius = match self.taper_radius {
            Some(0.0) => None,
            Some(radius) if radius.is_finite() && radius > 0.0 => Some(radius),
            Some(radius) => return Err(OverrideError::TaperRadius(radius)),
            None => recipe_taper,
        };
        let coupling = match (self.coupling, recipe.coupling) {
            (Some(CouplingChoice::Spline), _) | (None, CouplingKind::Spline { .. }) => {
                if self.taper_radius.is_some_and(|radius| radius != 0.0) {
                    return Err(OverrideError::TaperOnSpline);
                }
                spline
            }
            _ if spline_settings => return Err(OverrideError::SplineSettingsOnAffine),
            (Some(CouplingChoice::Affine), _) | (None, CouplingKind::Affine { .. }) => {
                CouplingKind::Affine {
                    scale_bound,
                    taper_radius,
                }
            }
        };
        if let Some(width) = self
            .hidden
            .iter()
            .flatten()
            .copied()
            .find(|&w| w > MAX_WIDTH)
        {
            return Err(OverrideError::TooWide {
                flag: "--hidden",
                width,
            });
        }
        let joint_range = match (self.joint_range, robot) {
            (Some(false), _) => None,
            (Some(true), Some(range)) => Some(range),
            (Some(true), None) => return Err(OverrideError::NoJointRange { task: recipe.task }),
            (None, _) => recipe.joint_range,
        };
        Ok(TrainConfig {
            joint_range,
            latent: self.latent.map_or(recipe.latent, LatentKind::from),
            coupling,
            layers: self.layers.unwrap_or(recipe.layers),
            hidden: self.hidden.clone().unwrap_or(recipe.hidden),
            min_rate: self.min_rate.unwrap_or(recipe.min_rate),
            horizon: self.horizon.unwrap_or(recipe.horizon),
            arrival: self.arrival.unwrap_or(recipe.arrival),
            state_noise: self.state_noise.unwrap_or(recipe.state_noise),
            validation_fraction: self
                .validation_fraction
                .unwrap_or(recipe.validation_fraction),
            threads: self.threads.unwrap_or(recipe.threads),
            optim: OptimConfig {
                epochs: self.epochs.unwrap_or(recipe.optim.epochs),
                batch_size: self.batch_size.unwrap_or(recipe.optim.batch_size),
                learning_rate: self.learning_rate.unwrap_or(recipe.optim.learning_rate),
                patience: self.patience.unwrap_or(recipe.optim.patience),
                keep: self.keep.map_or(recipe.optim.keep, Keep::from),
                seed: self.seed.unwrap_or(recipe.optim.seed),
                ..recipe.optim
            },
            ..recipe
        })
    }
}

/// How the context is read; settings not given keep the task's recipe.
#[derive(Clone, Debug, Default, PartialEq)]
#[cfg_attr(feature = "clap", derive(clap::Args))]
pub struct ContextOverrides {
    /// Context indices holding the go-to target (one per state dimension),
    /// comma-separated [default: the task's: the target of obstacle-avoidance, the goal
    /// of lasa, none otherwise].
    #[cfg_attr(feature = "clap", arg(long, value_delimiter = ','))]
    pub goal_context_indices: Option<Vec<usize>>,
    /// Unordered sets in the context, which the conditioners see through a
    /// permutation-invariant set encoder: START:COUNT:SIZE (COUNT elements of SIZE entries
    /// from context index START), comma-separated, or `none` [default: the task's: the
    /// obstacle centres of obstacle-avoidance, none otherwise].
    #[cfg_attr(
        feature = "clap",
        arg(long, value_delimiter = ',', value_parser = parse_context_set)
    )]
    pub context_sets: Option<Vec<Option<ContextSet>>>,
    /// Radial contraction layers about the obstacle centres in front of the network (0:
    /// none) [default: the task's: 5 per obstacle for obstacle-avoidance; other tasks have
    /// no centres to contract about].
    #[cfg_attr(feature = "clap", arg(long))]
    pub contraction_layers: Option<usize>,
    /// Width `W_ψ` of the local features each coupling pools over every context set, from
    /// a network with one hidden layer of `2 W_ψ` (0: none; the set encoder's summary
    /// alone) [default: the set encoder's].
    #[cfg_attr(feature = "clap", arg(long))]
    pub local_features: Option<usize>,
}

impl ContextOverrides {
    /// `recipe` with the settings given in its place.
    pub fn apply(&self, recipe: TrainConfig) -> Result<TrainConfig, OverrideError> {
        let contractions = match (self.contraction_layers, recipe.contractions) {
            (Some(0), _) => None,
            (Some(layers), Some(contractions)) => Some(ContractionConfig {
                layers,
                ..contractions
            }),
            (Some(_), None) => return Err(OverrideError::NoCentres { task: recipe.task }),
            (None, contractions) => contractions,
        };
        let local = match self.local_features {
            Some(0) => None,
            Some(width) if width > MAX_WIDTH => {
                return Err(OverrideError::TooWide {
                    flag: "--local-features",
                    width,
                });
            }
            Some(width) => Some(LocalConfig {
                hidden: vec![2 * width],
                width,
            }),
            None => recipe.set_encoder.local.clone(),
        };
        Ok(TrainConfig {
            goal_context_indices: self
                .goal_context_indices
                .clone()
                .or(recipe.goal_context_indices),
            context_sets: match &self.context_sets {
                Some(sets) => sets.iter().flatten().copied().collect(),
                None => recipe.context_sets,
            },
            contractions,
            set_encoder: SetEncoderConfig {
                local,
                ..recipe.set_encoder
            },
            ..recipe
        })
    }
}

/// `START:COUNT:SIZE` as a [`ContextSet`], `none` as no set.
pub fn parse_context_set(text: &str) -> Result<Option<ContextSet>, String> {
    if text == "none" {
        return Ok(None);
    }
    let fields: Vec<usize> = text
        .split(':')
        .map(|f| f.parse().map_err(|e| format!("`{f}`: {e}")))
        .collect::<Result<_, _>>()?;
    match fields[..] {
        [start, count, size] => Ok(Some(ContextSet { start, count, size })),
        _ => Err(format!("`{text}` is not START:COUNT:SIZE or `none`")),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use ciflow_engine::flow::LatentKind;

    fn recipe(coupling: CouplingKind) -> TrainConfig {
        TrainConfig {
            coupling,
            ..TrainConfig::new("test", LatentKind::GoTo)
        }
    }

    #[test]
    fn nothing_given_keeps_the_recipe() {
        let recipe = recipe(CouplingKind::AFFINE);
        let kept = RecipeOverrides::default()
            .apply(recipe.clone(), None)
            .unwrap();
        assert_eq!(kept, recipe);
        assert_eq!(
            ContextOverrides::default().apply(recipe.clone()).unwrap(),
            recipe
        );
    }

    #[test]
    fn every_setting_given_replaces_the_recipe() {
        let overrides = RecipeOverrides {
            batch_size: Some(64),
            epochs: Some(2),
            validation_fraction: Some(0.1),
            learning_rate: Some(1e-4),
            keep: Some(KeepChoice::Last),
            latent: Some(LatentChoice::LimitCycle),
            ..RecipeOverrides::default()
        };
        let config = overrides.apply(recipe(CouplingKind::AFFINE), None).unwrap();
        assert_eq!((config.optim.batch_size, config.optim.epochs), (64, 2));
        assert_eq!(config.validation_fraction, 0.1);
        assert_eq!(config.optim.learning_rate, 1e-4);
        assert_eq!(config.optim.keep, Keep::Last);
        assert_eq!(config.latent, LatentKind::LimitCycle);
    }

    #[test]
    fn spline_settings_apply_to_a_spline_and_are_refused_for_an_affine_coupling() {
        let bins = RecipeOverrides {
            spline_bins: Some(12),
            ..RecipeOverrides::default()
        };
        let spline = recipe(CouplingKind::Spline {
            bins: 8,
            tail_bound: 3.0,
        });
        assert_eq!(
            bins.apply(spline, None).unwrap().coupling,
            CouplingKind::Spline {
                bins: 12,
                tail_bound: 3.0
            }
        );
        assert!(matches!(
            bins.apply(recipe(CouplingKind::AFFINE), None),
            Err(OverrideError::SplineSettingsOnAffine)
        ));
        let switched = RecipeOverrides {
            coupling: Some(CouplingChoice::Spline),
            ..bins
        };
        assert!(matches!(
            switched
                .apply(recipe(CouplingKind::AFFINE), None)
                .unwrap()
                .coupling,
            CouplingKind::Spline { bins: 12, .. }
        ));
    }

    #[test]
    fn taper_radius_sets_the_affine_taper_and_zero_removes_it() {
        let tapered = |radius: f64| CouplingKind::Affine {
            scale_bound: 2.0,
            taper_radius: Some(radius),
        };
        let taper = |radius: f64| RecipeOverrides {
            taper_radius: Some(radius),
            ..RecipeOverrides::default()
        };
        let affine = || recipe(CouplingKind::AFFINE);
        assert_eq!(
            taper(6.0).apply(affine(), None).unwrap().coupling,
            tapered(6.0)
        );
        assert_eq!(
            taper(0.0)
                .apply(recipe(tapered(6.0)), None)
                .unwrap()
                .coupling,
            CouplingKind::AFFINE
        );
        // Unset, the recipe's taper stays, also when the coupling is named.
        let named = RecipeOverrides {
            coupling: Some(CouplingChoice::Affine),
            ..RecipeOverrides::default()
        };
        assert_eq!(
            named.apply(recipe(tapered(6.0)), None).unwrap().coupling,
            tapered(6.0)
        );
        for radius in [-1.0, f64::NAN, f64::INFINITY] {
            assert!(matches!(
                taper(radius).apply(affine(), None),
                Err(OverrideError::TaperRadius(_))
            ));
        }
        let spline = CouplingKind::Spline {
            bins: 8,
            tail_bound: 3.0,
        };
        assert!(matches!(
            taper(6.0).apply(recipe(spline.clone()), None),
            Err(OverrideError::TaperOnSpline)
        ));
        // "Off" is no contradiction.
        assert_eq!(
            taper(0.0)
                .apply(recipe(spline.clone()), None)
                .unwrap()
                .coupling,
            spline
        );
        let switched = RecipeOverrides {
            coupling: Some(CouplingChoice::Affine),
            ..taper(6.0)
        };
        assert_eq!(
            switched
                .apply(recipe(spline.clone()), None)
                .unwrap()
                .coupling,
            tapered(6.0)
        );
    }

    #[test]
    fn hidden_widths_are_bounded() {
        let hidden = |widths: Vec<usize>| RecipeOverrides {
            hidden: Some(widths),
            ..RecipeOverrides::default()
        };
        let widest = hidden(vec![MAX_WIDTH, 8]).apply(recipe(CouplingKind::AFFINE), None);
        assert_eq!(widest.unwrap().hidden, [MAX_WIDTH, 8]);
        assert!(matches!(
            hidden(vec![8, 100_000]).apply(recipe(CouplingKind::AFFINE), None),
            Err(OverrideError::TooWide {
                flag: "--hidden",
                width: 100_000
            })
        ));
    }

    #[test]
    fn joint_range_comes_from_the_robot_and_is_refused_without_one() {
        let range = JointRange {
            position_min: vec![-1.0; 2],
            position_max: vec![1.0; 2],
            speed_max: vec![1.0; 2],
            acceleration_max: vec![5.0; 2],
        };
        let given = |on| RecipeOverrides {
            joint_range: Some(on),
            ..RecipeOverrides::default()
        };
        let plain = recipe(CouplingKind::AFFINE);
        let on = given(true)
            .apply(plain.clone(), Some(range.clone()))
            .unwrap();
        assert_eq!(on.joint_range, Some(range.clone()));
        assert_eq!(
            given(false)
                .apply(on, Some(range.clone()))
                .unwrap()
                .joint_range,
            None
        );
        let unsaid = RecipeOverrides::default();
        assert_eq!(
            unsaid
                .apply(plain.clone(), Some(range))
                .unwrap()
                .joint_range,
            None
        );
        assert!(matches!(
            given(true).apply(plain, None),
            Err(OverrideError::NoJointRange { .. })
        ));
    }

    #[test]
    fn local_features_are_bounded() {
        let width = |width| ContextOverrides {
            local_features: Some(width),
            ..ContextOverrides::default()
        };
        let widest = width(MAX_WIDTH)
            .apply(recipe(CouplingKind::AFFINE))
            .unwrap();
        assert_eq!(
            widest.set_encoder.local.map(|local| local.width),
            Some(MAX_WIDTH)
        );
        assert!(matches!(
            width(100_000).apply(recipe(CouplingKind::AFFINE)),
            Err(OverrideError::TooWide {
                flag: "--local-features",
                width: 100_000
            })
        ));
    }

    #[test]
    fn contraction_layers_need_centres_and_context_sets_parse() {
        let layers = ContextOverrides {
            contraction_layers: Some(3),
            ..ContextOverrides::default()
        };
        assert!(matches!(
            layers.apply(recipe(CouplingKind::AFFINE)),
            Err(OverrideError::NoCentres { .. })
        ));
        assert_eq!(
            parse_context_set("2:3:2"),
            Ok(Some(ContextSet {
                start: 2,
                count: 3,
                size: 2
            }))
        );
        assert_eq!(parse_context_set("none"), Ok(None));
        assert!(parse_context_set("2:3").is_err());
        assert!(parse_context_set("a:3:2").is_err());
    }
}
