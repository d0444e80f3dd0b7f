//! What each choice of LASA's training recipe buys (`ciflow lasa --ablation`). The flow
//! is retrained on each shape with one setting of the recipe changed at a time, scored
//! with the benchmark's metrics, and set beside the recipe itself and the unconstrained
//! baseline trained once per shape in the same run. Writes `<out>/ablation.md` and
//! `<out>/ablation.csv`.

use std::fmt::Write as _;
use std::path::Path;
use std::time::Instant;

use ciflow_engine::flow::{CouplingKind, LatentKind};
use ciflow_envs::lasa;
use ciflow_evaluation::lasa::{METRICS, Model, Scores, cell, mean};
use ciflow_train::{DEFAULT_STATE_NOISE, Keep, TrainConfig};

use super::{
    RunEpoch, Tally, baseline_config, clear_earlier_run, create_dir, demonstrations, scored,
    settings, train_shape_baseline, train_shape_flow, write,
};
use crate::error::ExperimentResult;

/// One change to the recipe: its label, what it sets, and the change.
struct Variant {
    label: &'static str,
    change: &'static str,
    apply: fn(&mut TrainConfig),
}

/// The recipe, then one change at a time (each the setting the recipe replaced, or a
/// lead worth measuring).
const VARIANTS: [Variant; 12] = [
    Variant {
        label: "recipe",
        change: "the default settings",
        apply: |_| {},
    },
    Variant {
        label: "one-step",
        change: "one-step transitions only (horizon 1, no spans to the end)",
        apply: |c| {
            c.horizon = 1;
            c.arrival = 0.0;
        },
    },
    Variant {
        label: "horizon 20",
        change: "spans of up to 20 steps",
        apply: |c| c.horizon = 20,
    },
    Variant {
        label: "no arrival",
        change: "no spans to the demonstration's end",
        apply: |c| c.arrival = 0.0,
    },
    Variant {
        label: "jitter",
        change: "state jitter 0.1 × RMS step",
        apply: |c| c.state_noise = DEFAULT_STATE_NOISE,
    },
    Variant {
        label: "linear latent",
        change: "linear go-to latent",
        apply: |c| c.latent = LatentKind::GoTo,
    },
    Variant {
        label: "min rate 1",
        change: "guaranteed latent rate 1 /s (the other go-to tasks')",
        apply: |c| c.min_rate = 1.0,
    },
    Variant {
        label: "no taper",
        change: "affine couplings that do not fade beyond the taper radius",
        apply: |c| {
            if let CouplingKind::Affine { taper_radius, .. } = &mut c.coupling {
                *taper_radius = None;
            }
        },
    },
    Variant {
        label: "spline",
        change: "6 spline couplings (8 bins)",
        apply: |c| {
            c.layers = 6;
            c.coupling = CouplingKind::Spline {
                bins: 8,
                tail_bound: 4.0,
            };
        },
    },
    Variant {
        label: "wide",
        change: "conditioners 64-64",
        apply: |c| c.hidden = vec![64, 64],
    },
    Variant {
        label: "early stopping",
        change: "a fifth held out (1 of 7), keep the best validation likelihood",
        apply: |c| {
            c.validation_fraction = 0.2;
            c.optim.keep = Keep::BestValidation;
        },
    },
    Variant {
        label: "double budget",
        change: "60 epochs",
        apply: |c| c.optim.epochs *= 2,
    },
];

/// One variant's scores on every shape.
struct Row {
    label: &'static str,
    change: &'static str,
    scores: Vec<Scores>,
}

/// The recipe `recipe` with each variant's change.
fn variants(recipe: &TrainConfig) -> Vec<TrainConfig> {
    VARIANTS
        .iter()
        .map(|v| {
            let mut config = recipe.clone();
            (v.apply)(&mut config);
            config
        })
        .collect()
}

/// The epochs [`run`] spends at most on `shapes` shapes: every variant's and the baseline's.
pub fn budget(shapes: usize, recipe: &TrainConfig) -> u64 {
    let variants: usize = variants(recipe).iter().map(|c| c.optim.epochs).sum();
    (shapes * (variants + baseline_config(recipe).optim.epochs)) as u64
}

/// What [`run`] writes into its directory.
const RUN_OUTPUTS: [&str; 3] = ["ablation.md", "ablation.csv", "checkpoints"];

/// Retrains the flow with each variant of `recipe` and the baseline once on the shapes
/// `names` into `out` (an earlier run's results there are replaced only when
/// `overwrite`), telling `on_epoch` after every epoch; writes `ablation.md` and
/// `ablation.csv` and returns the table.
pub fn run(
    names: &[String],
    recipe: &TrainConfig,
    out: &Path,
    overwrite: bool,
    mut on_epoch: impl FnMut(&RunEpoch),
) -> ExperimentResult<String> {
    let start = Instant::now();
    clear_earlier_run(out, &RUN_OUTPUTS, overwrite)?;
    create_dir(out)?;
    let configs = variants(recipe);
    let mut tally = Tally {
        done: 0,
        on_epoch: &mut on_epoch,
    };
    let mut rows: Vec<Row> = VARIANTS
        .iter()
        .map(|v| Row {
            label: v.label,
            change: v.change,
            scores: Vec::new(),
        })
        .collect();
    let mut baseline = Vec::new();
    let checkpoints = out.join("checkpoints");
    for name in names {
        let shape = lasa::load(name)?;
        let data = demonstrations(&shape);
        for ((variant, config), row) in VARIANTS.iter().zip(&configs).zip(&mut rows) {
            let dir = checkpoints.join(name).join(variant.label.replace(' ', "-"));
            let trained = train_shape_flow(&shape, &data, config, &mut tally, &dir)?;
            row.scores.push(scored(&trained, &shape, Model::Flow)?.0);
        }
        let dir = checkpoints.join(name).join("baseline");
        let trained = train_shape_baseline(&shape, &data, recipe, &mut tally, &dir)?;
        baseline.push(scored(&trained, &shape, Model::Baseline)?.0);
    }
    rows.push(Row {
        label: "baseline",
        change: "the unconstrained MLP (control)",
        scores: baseline,
    });
    let table = markdown(names, &rows, recipe, start.elapsed().as_secs_f64());
    write(&out.join("ablation.md"), &table)?;
    write(&out.join("ablation.csv"), &csv(names, &rows))?;
    Ok(table)
}

fn markdown(names: &[String], rows: &[Row], recipe: &TrainConfig, seconds: f64) -> String {
    let mut text = format!(
        "# LASA ablation\n\nThe recipe: {}\n\nEach row changes one setting of the flow's \
         recipe; `baseline` is the control. {} shapes in {seconds:.0} s.\n\n{METRICS}\n\
         | variant | change | mean DTW | vs recipe | mean final | worst final | time / shape |",
        settings(recipe),
        names.len(),
    );
    for name in names {
        text += &format!(" {name} |");
    }
    text += "\n|---|---|---:|---:|---:|---:|---:|";
    text += &"---:|".repeat(names.len());
    text += "\n";
    let recipe_dtw = mean(rows[0].scores.iter().map(|s| s.dtw));
    for row in rows {
        let of = |f: fn(&Scores) -> f64| mean(row.scores.iter().map(f));
        let worst = row
            .scores
            .iter()
            .map(|s| s.final_error)
            .fold(f64::NEG_INFINITY, f64::max);
        write!(
            text,
            "| {} | {} | {} | {} | {} | {} | {} |",
            row.label,
            row.change,
            cell(of(|s| s.dtw), 2),
            cell(of(|s| s.dtw) / recipe_dtw, 2),
            cell(of(|s| s.final_error), 2),
            cell(worst, 2),
            cell(of(|s| s.train_seconds), 1),
        )
        .expect("writing to a String");
        for s in &row.scores {
            text += &format!(" {} |", cell(s.dtw, 2));
        }
        text += "\n";
    }
    text
}

fn csv(names: &[String], rows: &[Row]) -> String {
    let mut text = String::from("variant,shape,dtw_mm,final_error_mm,train_seconds\n");
    for row in rows {
        for (name, s) in names.iter().zip(&row.scores) {
            writeln!(
                text,
                "{},{name},{},{},{:.3}",
                row.label, s.dtw, s.final_error, s.train_seconds
            )
            .expect("writing to a String");
        }
    }
    text
}
