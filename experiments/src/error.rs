//! Why an experiment could not run.

use std::path::PathBuf;

use ciflow_engine::flow::FlowError;
use ciflow_envs::lasa::LasaError;
use ciflow_train::TrainError;

#[derive(Debug, thiserror::Error)]
pub enum ExperimentError {
    #[error("no shape to run")]
    NoShapes,
    #[error(transparent)]
    Lasa(#[from] LasaError),
    #[error("training the {model} on {shape}")]
    Training {
        shape: String,
        model: &'static str,
        #[source]
        source: TrainError,
    },
    #[error("writing the checkpoint {}", path.display())]
    SaveCheckpoint {
        path: PathBuf,
        #[source]
        source: TrainError,
    },
    #[error("loading the checkpoint {}", path.display())]
    LoadCheckpoint {
        path: PathBuf,
        #[source]
        source: FlowError,
    },
    #[error("scoring the {model} on {shape}")]
    Scoring {
        shape: String,
        model: &'static str,
        #[source]
        source: FlowError,
    },
    #[error(
        "{} holds an earlier run's results (one of {outputs}): pass --overwrite to replace \
         them, or choose another directory",
        path.display()
    )]
    EarlierRun { path: PathBuf, outputs: String },
    #[error("writing {}", path.display())]
    Write {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    #[error("encoding the plot data")]
    PlotData(#[from] serde_json::Error),
    #[error("running {python}")]
    PlotLaunch {
        python: String,
        #[source]
        source: std::io::Error,
    },
    #[error("plotting with {python} failed (pass --no-plots to skip): {stderr}")]
    Plot { python: String, stderr: String },
}

pub type ExperimentResult<T> = Result<T, ExperimentError>;
