//! An evaluation's rates divided by what the model saw in training: the episodes that
//! replay demonstrations it fitted, those that replay the demonstrations its training held
//! out for validation, and the rest ([`TrainingSplit::role`] decides, from each episode's
//! seed, start and context).
//!
//! Evaluating a model on its own demonstrations' seeds asks whether it fits its data; the
//! answer means that only for the fitted part; the held-out part is a generalisation
//! figure like any other unseen episode.

use serde::Serialize;

use ciflow_engine::flow::checkpoint::split::{SplitRole, TrainingSplit};

use crate::closed_loop::{EpisodeResult, rate};
use crate::summary::Summary;

/// The outcome rates of some episodes.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct Rates {
    pub episodes: usize,
    pub success_rate: f64,
    pub collision_rate: Option<f64>,
    pub spill_rate: Option<f64>,
    pub final_distance: Option<Summary>,
}

impl Rates {
    /// The rates of `results`; `None` when there are none.
    pub fn of(results: &[&EpisodeResult]) -> Option<Self> {
        if results.is_empty() {
            return None;
        }
        let distances: Vec<f64> = results.iter().filter_map(|r| r.final_distance).collect();
        Some(Self {
            episodes: results.len(),
            success_rate: results.iter().filter(|r| r.success).count() as f64
                / results.len() as f64,
            collision_rate: rate(results.iter().map(|r| r.collision)),
            spill_rate: rate(results.iter().map(|r| r.spill)),
            final_distance: Summary::of(&distances),
        })
    }
}

/// An evaluation's episodes by their part in the model's training.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct SplitRates {
    /// Episodes that replay demonstrations the model was fitted to.
    pub fitted: Option<Rates>,
    /// Episodes that replay demonstrations held out for validation (never fitted).
    pub held_out: Option<Rates>,
    /// Episodes that replay no demonstration.
    pub not_in_data: Option<Rates>,
}

impl SplitRates {
    pub fn of(results: &[EpisodeResult], split: &TrainingSplit) -> Self {
        let part = |role: SplitRole| {
            let members: Vec<&EpisodeResult> = results
                .iter()
                .filter(|r| split.role(r.seed, &r.start, &r.context) == role)
                .collect();
            Rates::of(&members)
        };
        Self {
            fitted: part(SplitRole::Fitted),
            held_out: part(SplitRole::HeldOut),
            not_in_data: part(SplitRole::NotInData),
        }
    }

    /// Whether any episode replays a demonstration (else the division says nothing).
    pub fn touches_data(&self) -> bool {
        self.fitted.is_some() || self.held_out.is_some()
    }
}

impl std::fmt::Display for SplitRates {
    /// One line per part, e.g. "fitted in training: success 99.9%, collision 0.1% (800)".
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let parts = [
            ("fitted in training", &self.fitted),
            ("held out of training", &self.held_out),
            ("not among the demonstrations", &self.not_in_data),
        ];
        for (name, rates) in parts {
            let Some(rates) = rates else { continue };
            write!(f, "{name}: success {:.1}%", 100.0 * rates.success_rate)?;
            if let Some(r) = rates.collision_rate {
                write!(f, ", collision {:.1}%", 100.0 * r)?;
            }
            if let Some(r) = rates.spill_rate {
                write!(f, ", spill {:.1}%", 100.0 * r)?;
            }
            writeln!(f, " ({} episodes)", rates.episodes)?;
        }
        Ok(())
    }
}
