//! Typed errors of the trainer.

use ciflow_engine::flow::FlowError;

#[derive(Debug, thiserror::Error)]
pub enum TrainError {
    #[error("invalid training data: {0}")]
    InvalidData(String),
    #[error("invalid training configuration: {0}")]
    InvalidConfig(String),
    #[error("training diverged (non-finite loss) at epoch {epoch}")]
    Diverged { epoch: usize },
    #[error(transparent)]
    Flow(#[from] FlowError),
    #[error(transparent)]
    Dataset(#[from] ciflow_envs::dataset::DatasetError),
    #[error(transparent)]
    Torch(#[from] tch::TchError),
    /// The project's Python could not be started to convert a dataset made elsewhere.
    #[error(
        "cannot run `{python}` (the project's Python, with the ciflow package) to convert the dataset"
    )]
    ConverterLaunch {
        python: String,
        #[source]
        source: std::io::Error,
    },
    /// `python -m ciflow.convert` refused the dataset; its message says what and where.
    #[error("converting the dataset: {0}")]
    Conversion(String),
}

pub type TrainResult<T> = Result<T, TrainError>;
