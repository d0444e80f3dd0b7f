//! Typed errors of the trainer.

use std::path::PathBuf;

use ciflow_engine::flow::FlowError;

#[derive(Debug, thiserror::Error)]
pub enum TrainError {
    #[error("invalid training data: {0}")]
    InvalidData(String),
    #[error("invalid training configuration: {0}")]
    InvalidConfig(String),
    /// A checkpoint would go where something other than a directory is: checked before
    /// training, which would otherwise fail only when it first writes.
    #[error("{} exists and is not a directory: a checkpoint is a directory", path.display())]
    NotADirectory { path: PathBuf },
    /// The baseline an earlier run left beside a flow could not be removed.
    #[error("removing the earlier run's baseline {}", path.display())]
    StaleBaseline {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    #[error("training diverged (non-finite loss) at epoch {epoch}")]
    Diverged { epoch: usize },
    #[error(transparent)]
    Flow(#[from] FlowError),
    #[error(transparent)]
    Dataset(#[from] ciflow_envs::dataset::DatasetError),
    #[error(transparent)]
    Torch(#[from] tch::TchError),
    /// Converting a dataset made elsewhere (`python -m ciflow.convert`) failed; the
    /// source says what and where.
    #[error("converting the dataset")]
    Conversion(#[source] ciflow_envs::python::PythonError),
}

pub type TrainResult<T> = Result<T, TrainError>;
