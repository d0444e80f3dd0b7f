//! Demonstration datasets in Minari's Arrow layout (see `envs/DATASET.md`).
//!
//! A dataset is a directory that `minari.load_dataset` opens without ciflow:
//!
//! ```text
//! <dir>/data/metadata.json          dataset: spaces, counts, id, the environment's
//!                                   Gymnasium spec, ciflow extras (dt, context)
//! <dir>/data/<i>/metadata.json      episode i: id, total_steps, seed
//! <dir>/data/<i>/part-0.arrow       episode i: Arrow IPC file, T + 1 rows
//! ```
//!
//! Columns of an episode file: `observations` and `actions` as fixed-size lists,
//! `rewards` (f64), `terminations`, `truncations` (bool) and `infos`, a struct holding
//! `context` (fixed-size list) and the scalar info series. As in Minari, observations
//! have `T + 1` rows (the reset observation first) and the per-step columns are padded
//! with one trailing zero row.
//!
//! Writes are atomic: [`DatasetWriter`] fills a hidden sibling directory and renames it
//! into place in [`DatasetWriter::finish`]; a writer that dies leaves only that hidden
//! directory, never a dataset that looks complete.

use std::collections::BTreeMap;
use std::fs;
use std::path::{Path, PathBuf};
use std::sync::Arc;

use arrow_array::{
    Array, ArrayRef, BooleanArray, FixedSizeListArray, Float32Array, Float64Array, RecordBatch,
    StructArray,
};
use arrow_schema::{DataType, Field, Fields, Schema};
use serde_json::{Value, json};

use crate::env::{PERTURBED_INFO, SUCCESS_INFO};
use crate::registry::{Kwarg, Kwargs};
use crate::space::{BoxSpace, Dtype};

/// The Minari release whose layout this module writes.
pub const MINARI_VERSION: &str = "0.5.4";
/// Where Gymnasium finds ciflow's environment classes (`python/ciflow/registration.py`
/// registers every task with these): the `env_spec` of a dataset names them so that
/// Minari's `recover_environment()` rebuilds the environment.
pub const GYMNASIUM_ENTRY_POINT: &str = "ciflow.env:CiflowEnv";
pub const GYMNASIUM_VECTOR_ENTRY_POINT: &str = "ciflow.vector:CiflowVectorEnv";
/// The Python package a recovered environment needs, at this build's version.
const REQUIREMENT: &str = concat!("ciflow==", env!("CARGO_PKG_VERSION"));
const METADATA_FILE: &str = "metadata.json";
const EPISODE_FILE: &str = "part-0.arrow";
const CONTEXT_INFO: &str = "context";

/// Why a dataset could not be written or read.
#[derive(Debug, thiserror::Error)]
pub enum DatasetError {
    #[error("{path}: {source}")]
    Io {
        path: PathBuf,
        source: std::io::Error,
    },
    #[error("{path}: arrow: {source}")]
    Arrow {
        path: PathBuf,
        source: arrow_schema::ArrowError,
    },
    #[error("{path}: not a ciflow/Minari dataset: {detail}")]
    Format { path: PathBuf, detail: String },
    #[error("{path}: not a ciflow/Minari dataset: malformed JSON")]
    Json {
        path: PathBuf,
        #[source]
        source: serde_json::Error,
    },
    /// A field of the metadata that holds serialized JSON (`observation_space`, …,
    /// `env_spec`) does not.
    #[error("{path}: not a ciflow/Minari dataset: `{field}` is not valid serialized JSON")]
    FieldJson {
        path: PathBuf,
        field: &'static str,
        #[source]
        source: serde_json::Error,
    },
    #[error("episode {episode}: {detail}")]
    InvalidEpisode { episode: usize, detail: String },
    #[error("{0} already exists (pass `--overwrite`, or `overwrite=True`, to replace it)")]
    AlreadyExists(PathBuf),
    #[error(
        "{0} exists and is not a dataset (neither data/metadata.json nor meta/info.json in \
         it, nor an empty directory): refusing to replace it"
    )]
    NotADataset(PathBuf),
    #[error(
        "dataset id `{0}` is not one Minari opens: ids are `namespace/name-vN` or \
         `name-vN` (letters, digits, `_`, `-`; the namespace of at least two characters, \
         `/` inside it allowed), e.g. `ciflow/limit-cycle-expert-v0`"
    )]
    InvalidId(String),
    #[error("writing the LeRobot dataset {path}")]
    Lerobot {
        path: PathBuf,
        #[source]
        source: crate::python::PythonError,
    },
}

/// The layouts ciflow writes datasets in (with the `clap` feature, `--format`'s values).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
#[cfg_attr(feature = "clap", derive(clap::ValueEnum))]
pub enum DatasetFormat {
    /// Minari's Arrow layout (`envs/DATASET.md`), which `ciflow train` reads.
    #[default]
    Minari,
    /// LeRobot v3.0, numbers as float32 (see [`write_lerobot`]).
    Lerobot,
}

/// Writes the dataset at `source` (this module's layout) as a LeRobot v3.0 dataset at
/// `out`, with `python -m ciflow.convert --to-lerobot` (pyarrow): per frame the position
/// `observation.state`, its rate `observation.velocity`, the context
/// `observation.environment_state`, `action`, `next.reward`, `next.done`, as float32.
pub fn write_lerobot(source: &Path, out: &Path, overwrite: bool) -> Result<()> {
    let mut args = vec!["--to-lerobot".as_ref(), source.as_os_str(), out.as_os_str()];
    if overwrite {
        args.push("--overwrite".as_ref());
    }
    crate::python::run_module("ciflow.convert", args)
        .map(drop)
        .map_err(|source| DatasetError::Lerobot {
            path: out.to_path_buf(),
            source,
        })
}

type Result<T> = std::result::Result<T, DatasetError>;

/// Checks that a dataset may be written at `path`: nothing is there, or — with
/// `overwrite` — what is there is a dataset (Minari's `data/metadata.json` or LeRobot's
/// `meta/info.json`) or an empty directory. Replacing means deleting, so a mistyped
/// `--out` (a home directory, a file) must not be taken for an old dataset.
pub fn check_replaceable(path: &Path, overwrite: bool) -> Result<()> {
    if !path.exists() {
        return Ok(());
    }
    if !overwrite {
        return Err(DatasetError::AlreadyExists(path.to_path_buf()));
    }
    let holds = |parts: &[&str]| parts.iter().collect::<PathBuf>();
    let is_dataset = [
        holds(&["data", METADATA_FILE]),
        holds(&["meta", "info.json"]),
    ]
    .iter()
    .any(|file| path.join(file).is_file());
    let is_empty_dir =
        path.is_dir() && fs::read_dir(path).map_err(io_error(path))?.next().is_none();
    if is_dataset || is_empty_dir {
        Ok(())
    } else {
        Err(DatasetError::NotADataset(path.to_path_buf()))
    }
}

/// Checks that Minari accepts `id` as a dataset id: `(namespace/)name-vN` as
/// `minari.dataset.minari_dataset.parse_dataset_id` (0.5) parses it, which `MinariDataset`
/// calls on opening. Its pattern takes `name` and `namespace` as runs of word characters
/// and `-` (the namespace also `/`, but neither first nor last, and at least two
/// characters) and makes the version optional, but a missing version then fails converting
/// to a number, so it is required here.
pub fn check_dataset_id(id: &str) -> Result<()> {
    let word = |c: char| c.is_alphanumeric() || c == '_' || c == '-';
    let valid = id.rsplit_once("-v").is_some_and(|(rest, version)| {
        let version_ok = !version.is_empty() && version.bytes().all(|b| b.is_ascii_digit());
        let (namespace, name) = match rest.rsplit_once('/') {
            Some((namespace, name)) => (Some(namespace), name),
            None => (None, rest),
        };
        let namespace_ok = namespace.is_none_or(|n| {
            n.chars().count() >= 2
                && !n.starts_with('/')
                && !n.ends_with('/')
                && n.chars().all(|c| word(c) || c == '/')
        });
        version_ok && namespace_ok && !name.is_empty() && name.chars().all(word)
    });
    if valid {
        Ok(())
    } else {
        Err(DatasetError::InvalidId(id.to_owned()))
    }
}

/// What every episode of a dataset shares.
#[derive(Clone, Debug, PartialEq)]
pub struct DatasetSpec {
    /// Minari id, `namespace/name-vN`, e.g. `ciflow/limit-cycle-expert-v0`.
    pub dataset_id: String,
    /// The Gymnasium id of the environment that produced the data.
    pub env_id: String,
    /// Its construction arguments: `gymnasium.make(env_id, **env_kwargs)` rebuilds it.
    pub env_kwargs: Kwargs,
    pub observation_space: BoxSpace,
    pub action_space: BoxSpace,
    pub context_space: BoxSpace,
    /// Seconds between consecutive observations.
    pub control_dt: f64,
    /// Who produced the actions, e.g. `expert`.
    pub algorithm_name: String,
    /// Who made the dataset and how to reach them (Minari's `minari show` lists these).
    pub credits: Credits,
}

/// The free-text fields of Minari's dataset metadata (with the `clap` feature, the
/// command line's flags for them).
#[derive(Clone, Debug, PartialEq)]
#[cfg_attr(feature = "clap", derive(clap::Args))]
pub struct Credits {
    /// Author of the dataset (Minari's `author`); repeatable.
    #[cfg_attr(feature = "clap", arg(long = "author", default_value = "ciflow"))]
    pub author: Vec<String>,
    /// Contact address of the author (Minari's `author_email`); repeatable.
    #[cfg_attr(feature = "clap", arg(long = "author-email"))]
    pub author_email: Vec<String>,
    /// Link to the versioned code that produced the data (Minari's `code_permalink`).
    #[cfg_attr(feature = "clap", arg(long))]
    pub code_permalink: Option<String>,
    /// What the dataset holds (Minari's `description`; default: one naming the task, its
    /// arguments, the time step and where the context is).
    #[cfg_attr(feature = "clap", arg(long))]
    pub description: Option<String>,
}

impl Default for Credits {
    fn default() -> Self {
        Self {
            author: vec!["ciflow".into()],
            author_email: Vec::new(),
            code_permalink: None,
            description: None,
        }
    }
}

/// One episode: `T` steps, `T + 1` observations.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Episode {
    /// The seed passed to `reset`, if any.
    pub seed: Option<u64>,
    /// `T + 1` observations, the reset observation first.
    pub observations: Vec<Vec<f64>>,
    /// `T` actions; `actions[t]` led from `observations[t]` to `observations[t + 1]`.
    pub actions: Vec<Vec<f64>>,
    pub rewards: Vec<f64>,
    pub terminations: Vec<bool>,
    pub truncations: Vec<bool>,
    /// `T + 1` contexts, aligned with the observations.
    pub contexts: Vec<Vec<f64>>,
    /// Scalar info series, `T + 1` values each (the reset info first).
    pub infos: BTreeMap<String, Vec<f64>>,
}

impl Episode {
    /// Number of steps `T`.
    pub fn len(&self) -> usize {
        self.actions.len()
    }

    pub fn is_empty(&self) -> bool {
        self.actions.is_empty()
    }

    /// Whether step `t` (`observations[t] → observations[t + 1]`) was moved by an external
    /// force: the [`PERTURBED_INFO`] recorded after it (false when the dataset has none).
    pub fn perturbed(&self, t: usize) -> bool {
        self.infos
            .get(PERTURBED_INFO)
            .and_then(|flags| flags.get(t + 1))
            .is_some_and(|&flag| flag == 1.0)
    }

    /// Whether the episode records that it achieved its task: its last [`SUCCESS_INFO`]
    /// is 1.
    pub fn succeeded(&self) -> bool {
        self.infos
            .get(SUCCESS_INFO)
            .and_then(|flags| flags.last())
            .is_some_and(|&last| last == 1.0)
    }

    /// Whether the episode records that it ended without achieving its task: its last
    /// [`SUCCESS_INFO`] is not 1 (a dataset without that info records no failure).
    pub fn failed(&self) -> bool {
        self.infos
            .get(SUCCESS_INFO)
            .and_then(|flags| flags.last())
            .is_some_and(|&last| last != 1.0)
    }

    fn validate(&self, index: usize, spec: &DatasetSpec) -> Result<()> {
        let invalid = |detail: String| DatasetError::InvalidEpisode {
            episode: index,
            detail,
        };
        let steps = self.len();
        let lengths = [
            ("observations", self.observations.len(), steps + 1),
            ("contexts", self.contexts.len(), steps + 1),
            ("rewards", self.rewards.len(), steps),
            ("terminations", self.terminations.len(), steps),
            ("truncations", self.truncations.len(), steps),
        ];
        for (name, got, expected) in lengths {
            if got != expected {
                return Err(invalid(format!(
                    "{name} has {got} rows, expected {expected} for {steps} steps"
                )));
            }
        }
        for (name, series) in &self.infos {
            if series.len() != steps + 1 {
                return Err(invalid(format!(
                    "info `{name}` has {} values, expected {}",
                    series.len(),
                    steps + 1
                )));
            }
        }
        let rows = [
            ("observations", &self.observations, &spec.observation_space),
            ("actions", &self.actions, &spec.action_space),
            ("contexts", &self.contexts, &spec.context_space),
        ];
        for (name, rows, space) in rows {
            if let Some(row) = rows.iter().find(|row| row.len() != space.dim()) {
                return Err(invalid(format!(
                    "{name} row has {} elements, expected {}",
                    row.len(),
                    space.dim()
                )));
            }
            if rows.iter().flatten().any(|v| !v.is_finite()) {
                return Err(invalid(format!("{name} contain NaN or inf")));
            }
        }
        Ok(())
    }
}

/// Writes `episodes` as a dataset at `dir` (atomically; see [`DatasetWriter`]).
pub fn write(dir: &Path, spec: &DatasetSpec, episodes: &[Episode], overwrite: bool) -> Result<()> {
    let mut writer = DatasetWriter::create(dir, spec.clone(), overwrite)?;
    for episode in episodes {
        writer.append(episode)?;
    }
    writer.finish().map(drop)
}

/// Streams episodes into a hidden directory next to the target and renames it into place
/// when finished. Dropping an unfinished writer deletes the partial data.
pub struct DatasetWriter {
    target: PathBuf,
    partial: PathBuf,
    spec: DatasetSpec,
    overwrite: bool,
    total_episodes: usize,
    total_steps: usize,
    finished: bool,
}

impl DatasetWriter {
    /// Starts a dataset at `dir` described by `spec`; a description naming the environment
    /// is filled in when `spec` has none (see [`DatasetWriter::spec`]).
    pub fn create(dir: &Path, mut spec: DatasetSpec, overwrite: bool) -> Result<Self> {
        check_dataset_id(&spec.dataset_id)?;
        if spec.credits.description.is_none() {
            spec.credits.description = Some(default_description(&spec));
        }
        check_replaceable(dir, overwrite)?;
        let name = dir
            .file_name()
            .ok_or_else(|| DatasetError::Format {
                path: dir.to_path_buf(),
                detail: "the dataset path needs a final component".into(),
            })?
            .to_string_lossy();
        let partial = dir.with_file_name(format!(".{name}.partial-{}", std::process::id()));
        if partial.exists() {
            fs::remove_dir_all(&partial).map_err(io_error(&partial))?;
        }
        let data = partial.join("data");
        fs::create_dir_all(&data).map_err(io_error(&data))?;
        Ok(Self {
            target: dir.to_path_buf(),
            partial,
            spec,
            overwrite,
            total_episodes: 0,
            total_steps: 0,
            finished: false,
        })
    }

    /// The description written to the dataset's metadata.
    pub fn spec(&self) -> &DatasetSpec {
        &self.spec
    }

    /// Writes the next episode (its id is the number of episodes written before it).
    pub fn append(&mut self, episode: &Episode) -> Result<()> {
        let id = self.total_episodes;
        episode.validate(id, &self.spec)?;
        let dir = self.partial.join("data").join(id.to_string());
        fs::create_dir_all(&dir).map_err(io_error(&dir))?;
        let path = dir.join(EPISODE_FILE);
        let batch = episode_batch(episode, &self.spec).map_err(arrow_error(&path))?;
        let file = fs::File::create(&path).map_err(io_error(&path))?;
        let mut writer = arrow_ipc::writer::FileWriter::try_new_buffered(file, &batch.schema())
            .map_err(arrow_error(&path))?;
        writer.write(&batch).map_err(arrow_error(&path))?;
        writer.finish().map_err(arrow_error(&path))?;
        let mut metadata = json!({"id": id, "total_steps": episode.len()});
        if let Some(seed) = episode.seed {
            metadata["seed"] = json!(seed);
        }
        write_json(&dir.join(METADATA_FILE), &metadata)?;
        self.total_episodes += 1;
        self.total_steps += episode.len();
        Ok(())
    }

    /// Writes the dataset metadata and moves the dataset into place; returns its path.
    pub fn finish(mut self) -> Result<PathBuf> {
        let metadata = dataset_metadata(&self.spec, self.total_episodes, self.total_steps);
        write_json(&self.partial.join("data").join(METADATA_FILE), &metadata)?;
        if self.target.exists() && self.overwrite {
            let stale = self
                .partial
                .with_extension(format!("stale-{}", std::process::id()));
            fs::rename(&self.target, &stale).map_err(io_error(&self.target))?;
            fs::rename(&self.partial, &self.target).map_err(io_error(&self.target))?;
            fs::remove_dir_all(&stale).map_err(io_error(&stale))?;
        } else {
            if let Some(parent) = self.target.parent().filter(|p| !p.as_os_str().is_empty()) {
                fs::create_dir_all(parent).map_err(io_error(parent))?;
            }
            fs::rename(&self.partial, &self.target).map_err(io_error(&self.target))?;
        }
        self.finished = true;
        Ok(self.target.clone())
    }
}

impl Drop for DatasetWriter {
    fn drop(&mut self) {
        if !self.finished {
            // Best effort: a leftover hidden directory is harmless, just untidy.
            let _ = fs::remove_dir_all(&self.partial);
        }
    }
}

/// Reads a dataset written by [`write()`] or by Minari (Arrow format, Box spaces).
pub fn read(dir: &Path) -> Result<(DatasetSpec, Vec<Episode>)> {
    let data = dir.join("data");
    let metadata_path = data.join(METADATA_FILE);
    if !metadata_path.exists() && dir.join("meta").join("info.json").is_file() {
        return Err(DatasetError::Format {
            path: dir.to_path_buf(),
            detail: "this is a LeRobot dataset (meta/info.json); name the fields that hold \
                     the state with `ciflow train --state FIELD` or convert it with \
                     `python -m ciflow.convert SOURCE OUT --state FIELD`"
                .into(),
        });
    }
    let metadata = read_json(&metadata_path)?;
    let spec = spec_from_metadata(&metadata).map_err(|error| match error {
        MetadataError::Invalid(detail) => DatasetError::Format {
            path: metadata_path.clone(),
            detail,
        },
        MetadataError::Json { field, source } => DatasetError::FieldJson {
            path: metadata_path.clone(),
            field,
            source,
        },
    })?;
    let total = metadata["total_episodes"]
        .as_u64()
        .ok_or_else(|| DatasetError::Format {
            path: metadata_path.clone(),
            detail: "missing total_episodes".into(),
        })?;
    let episodes = (0..total as usize)
        .map(|id| read_episode(&data.join(id.to_string()), &spec))
        .collect::<Result<Vec<_>>>()?;
    Ok((spec, episodes))
}

fn read_episode(dir: &Path, spec: &DatasetSpec) -> Result<Episode> {
    let metadata = read_json(&dir.join(METADATA_FILE))?;
    let path = arrow_file_in(dir)?;
    let file = fs::File::open(&path).map_err(io_error(&path))?;
    // Arrow reads an empty file as an I/O error ("Invalid argument"), which hides that
    // the recording stopped before the episode was written.
    if file.metadata().map_err(io_error(&path))?.len() == 0 {
        return Err(DatasetError::Format {
            path,
            detail: "the episode file is empty (0 bytes): the recording stopped before \
                     writing it"
                .into(),
        });
    }
    let reader =
        arrow_ipc::reader::FileReader::try_new_buffered(file, None).map_err(arrow_error(&path))?;
    let batches = reader
        .collect::<std::result::Result<Vec<_>, _>>()
        .map_err(arrow_error(&path))?;
    let format = |detail: String| DatasetError::Format {
        path: path.clone(),
        detail,
    };
    let mut columns = EpisodeColumns::default();
    for batch in &batches {
        columns.extend(batch).map_err(format)?;
    }
    let steps = columns
        .observations
        .len()
        .checked_sub(1)
        .ok_or_else(|| format("an episode needs at least its reset observation".into()))?;
    let contexts = match columns.contexts.is_empty() {
        false => columns.contexts,
        // A recorder that stores no `context` info still has it as the observation's tail.
        true => columns
            .observations
            .iter()
            .map(|o| o[o.len().saturating_sub(spec.context_space.dim())..].to_vec())
            .collect(),
    };
    let episode = Episode {
        seed: metadata["seed"].as_u64(),
        observations: columns.observations,
        actions: truncate(columns.actions, steps),
        rewards: truncate(columns.rewards, steps),
        terminations: truncate(columns.terminations, steps),
        truncations: truncate(columns.truncations, steps),
        contexts,
        infos: columns.infos,
    };
    let index = metadata["id"].as_u64().unwrap_or_default() as usize;
    episode.validate(index, spec)?;
    Ok(episode)
}

fn truncate<T>(mut rows: Vec<T>, len: usize) -> Vec<T> {
    rows.truncate(len);
    rows
}

fn arrow_file_in(dir: &Path) -> Result<PathBuf> {
    let entries = fs::read_dir(dir).map_err(io_error(dir))?;
    let mut files = entries
        .filter_map(|entry| entry.ok().map(|e| e.path()))
        .filter(|p| p.extension().is_some_and(|ext| ext == "arrow"))
        .collect::<Vec<_>>();
    files.sort();
    files
        .into_iter()
        .next()
        .ok_or_else(|| DatasetError::Format {
            path: dir.to_path_buf(),
            detail: "no .arrow file in the episode directory".into(),
        })
}

/// Builds the `T + 1`-row record batch of one episode.
fn episode_batch(
    episode: &Episode,
    spec: &DatasetSpec,
) -> std::result::Result<RecordBatch, arrow_schema::ArrowError> {
    let rows = episode.observations.len();
    let pad = |values: &[f64]| {
        let mut padded = values.to_vec();
        padded.push(0.0);
        padded
    };
    let pad_flags = |values: &[bool]| {
        let mut padded = values.to_vec();
        padded.push(false);
        BooleanArray::from(padded)
    };
    let mut actions = episode.actions.clone();
    actions.push(vec![0.0; spec.action_space.dim()]);

    let mut info_fields = vec![
        Field::new(
            CONTEXT_INFO,
            fixed_list_type(DataType::Float64, spec.context_space.dim()),
            true,
        )
        .with_metadata(std::collections::HashMap::from([(
            "shape".to_string(),
            spec.context_space.dim().to_string(),
        )])),
    ];
    let mut info_columns: Vec<ArrayRef> = vec![Arc::new(fixed_list(
        &episode.contexts,
        spec.context_space.dim(),
        Dtype::Float64,
    )?)];
    for (name, series) in &episode.infos {
        info_fields.push(Field::new(name, DataType::Float64, true));
        info_columns.push(Arc::new(Float64Array::from(series.clone())));
    }
    let infos = StructArray::try_new(Fields::from(info_fields), info_columns, None)?;

    let columns: Vec<(&str, ArrayRef)> = vec![
        (
            "observations",
            Arc::new(fixed_list(
                &episode.observations,
                spec.observation_space.dim(),
                spec.observation_space.dtype,
            )?),
        ),
        (
            "actions",
            Arc::new(fixed_list(
                &actions,
                spec.action_space.dim(),
                spec.action_space.dtype,
            )?),
        ),
        (
            "rewards",
            Arc::new(Float64Array::from(pad(&episode.rewards))),
        ),
        ("terminations", Arc::new(pad_flags(&episode.terminations))),
        ("truncations", Arc::new(pad_flags(&episode.truncations))),
        ("infos", Arc::new(infos)),
    ];
    debug_assert!(columns.iter().all(|(_, c)| c.len() == rows));
    let schema = Schema::new(
        columns
            .iter()
            .map(|(name, column)| Field::new(*name, column.data_type().clone(), true))
            .collect::<Vec<_>>(),
    );
    RecordBatch::try_new(
        Arc::new(schema),
        columns.into_iter().map(|(_, c)| c).collect(),
    )
}

fn fixed_list_type(item: DataType, size: usize) -> DataType {
    DataType::FixedSizeList(Arc::new(Field::new_list_field(item, true)), size as i32)
}

fn fixed_list(
    rows: &[Vec<f64>],
    size: usize,
    dtype: Dtype,
) -> std::result::Result<FixedSizeListArray, arrow_schema::ArrowError> {
    let flat = rows.iter().flatten().copied();
    let (values, item): (ArrayRef, DataType) = match dtype {
        Dtype::Float64 => (
            Arc::new(Float64Array::from_iter_values(flat)),
            DataType::Float64,
        ),
        Dtype::Float32 => (
            Arc::new(Float32Array::from_iter_values(flat.map(|v| v as f32))),
            DataType::Float32,
        ),
    };
    FixedSizeListArray::try_new_with_length(
        Arc::new(Field::new_list_field(item, true)),
        size as i32,
        values,
        None,
        rows.len(),
    )
}

/// The columns of an episode file, as rows of `f64`.
#[derive(Default)]
struct EpisodeColumns {
    observations: Vec<Vec<f64>>,
    actions: Vec<Vec<f64>>,
    rewards: Vec<f64>,
    terminations: Vec<bool>,
    truncations: Vec<bool>,
    contexts: Vec<Vec<f64>>,
    infos: BTreeMap<String, Vec<f64>>,
}

impl EpisodeColumns {
    fn extend(&mut self, batch: &RecordBatch) -> std::result::Result<(), String> {
        let column = |name: &str| {
            batch
                .column_by_name(name)
                .ok_or_else(|| format!("missing column `{name}`"))
        };
        self.observations
            .extend(list_rows(column("observations")?)?);
        self.actions.extend(list_rows(column("actions")?)?);
        self.rewards.extend(scalars(column("rewards")?)?);
        self.terminations.extend(flags(column("terminations")?)?);
        self.truncations.extend(flags(column("truncations")?)?);
        if let Some(infos) = batch.column_by_name("infos") {
            let infos = infos
                .as_any()
                .downcast_ref::<StructArray>()
                .ok_or("`infos` is not a struct")?;
            for (field, values) in infos.fields().iter().zip(infos.columns()) {
                if field.name() == CONTEXT_INFO {
                    self.contexts.extend(list_rows(values)?);
                } else if let Ok(series) = scalars(values) {
                    self.infos
                        .entry(field.name().clone())
                        .or_default()
                        .extend(series);
                }
            }
        }
        Ok(())
    }
}

fn scalars(array: &ArrayRef) -> std::result::Result<Vec<f64>, String> {
    if let Some(a) = array.as_any().downcast_ref::<Float64Array>() {
        Ok(a.iter().map(|v| v.unwrap_or(f64::NAN)).collect())
    } else if let Some(a) = array.as_any().downcast_ref::<Float32Array>() {
        Ok(a.iter().map(|v| v.map_or(f64::NAN, f64::from)).collect())
    } else {
        Err(format!("expected floats, found {}", array.data_type()))
    }
}

fn flags(array: &ArrayRef) -> std::result::Result<Vec<bool>, String> {
    let a = array
        .as_any()
        .downcast_ref::<BooleanArray>()
        .ok_or_else(|| format!("expected booleans, found {}", array.data_type()))?;
    Ok(a.iter().map(|v| v.unwrap_or(false)).collect())
}

fn list_rows(array: &ArrayRef) -> std::result::Result<Vec<Vec<f64>>, String> {
    let list = array
        .as_any()
        .downcast_ref::<FixedSizeListArray>()
        .ok_or_else(|| format!("expected a fixed-size list, found {}", array.data_type()))?;
    let size = list.value_length() as usize;
    let values = scalars(list.values())?;
    let offset = list.offset();
    Ok((0..list.len())
        .map(|row| values[(offset + row) * size..(offset + row + 1) * size].to_vec())
        .collect())
}

fn dataset_metadata(spec: &DatasetSpec, total_episodes: usize, total_steps: usize) -> Value {
    let credits = &spec.credits;
    let mut metadata = json!({
        "dataset_id": spec.dataset_id,
        "algorithm_name": spec.algorithm_name,
        "total_episodes": total_episodes,
        "total_steps": total_steps,
        "data_format": "arrow",
        "jpeg_encoding": false,
        "observation_space": minari_box(&spec.observation_space),
        "action_space": minari_box(&spec.action_space),
        "env_spec": gymnasium_env_spec(spec),
        "requirements": [REQUIREMENT],
        "minari_version": MINARI_VERSION,
        "author": credits.author,
        "ciflow": {
            "env_id": spec.env_id,
            "control_dt": spec.control_dt,
            "context_space": minari_box(&spec.context_space),
        },
    });
    if !credits.author_email.is_empty() {
        metadata["author_email"] = json!(credits.author_email);
    }
    if let Some(link) = &credits.code_permalink {
        metadata["code_permalink"] = json!(link);
    }
    if let Some(description) = &credits.description {
        metadata["description"] = json!(description);
    }
    metadata
}

/// The environment as Gymnasium's `EnvSpec.to_json()` writes it, which Minari stores as
/// `env_spec` and `recover_environment()` hands to `gymnasium.make`. No time limit: the
/// tasks truncate their episodes themselves, as registered.
fn gymnasium_env_spec(spec: &DatasetSpec) -> String {
    let mut kwargs = serde_json::Map::from_iter([("task".to_string(), json!(spec.env_id))]);
    kwargs.extend(spec.env_kwargs.iter().map(|(name, value)| {
        let value = match value {
            Kwarg::Number(number) => json_number(*number),
            Kwarg::Text(text) => json!(text),
        };
        (name.clone(), value)
    }));
    json!({
        "id": spec.env_id,
        "entry_point": GYMNASIUM_ENTRY_POINT,
        "reward_threshold": null,
        "nondeterministic": false,
        "max_episode_steps": null,
        "order_enforce": true,
        "disable_env_checker": false,
        "kwargs": kwargs,
        "additional_wrappers": [],
        "vector_entry_point": GYMNASIUM_VECTOR_ENTRY_POINT,
    })
    .to_string()
}

/// An integer where the value is one (`obstacles: 2`, as a person would write it).
fn json_number(value: f64) -> Value {
    const EXACT: f64 = (1u64 << 53) as f64;
    if value.fract() == 0.0 && value.abs() < EXACT {
        json!(value as i64)
    } else {
        json!(value)
    }
}

/// What a dataset of `spec` holds, for Minari's `description` when none is given.
fn default_description(spec: &DatasetSpec) -> String {
    let arguments = spec
        .env_kwargs
        .iter()
        .map(|(name, value)| format!("{name}={value}"))
        .collect::<Vec<_>>();
    let with = match arguments.is_empty() {
        true => String::new(),
        false => format!(" ({})", arguments.join(", ")),
    };
    format!(
        "Demonstrations of {}{with} by its `{}` policy, recorded by ciflow {}: one \
         observation every {} s; the context is the observation's last {} values and the \
         `context` info.",
        spec.env_id,
        spec.algorithm_name,
        env!("CARGO_PKG_VERSION"),
        spec.control_dt,
        spec.context_space.dim()
    )
}

/// Why metadata do not describe a dataset: a check of ours failed, or a field that holds
/// serialized JSON (a space, the environment's spec) is not JSON.
#[derive(Debug)]
enum MetadataError {
    Invalid(String),
    Json {
        field: &'static str,
        source: serde_json::Error,
    },
}

impl From<String> for MetadataError {
    fn from(detail: String) -> Self {
        Self::Invalid(detail)
    }
}

fn spec_from_metadata(metadata: &Value) -> std::result::Result<DatasetSpec, MetadataError> {
    let text = |value: &Value, name: &str| {
        value[name]
            .as_str()
            .map(str::to_owned)
            .ok_or_else(|| format!("missing `{name}`"))
    };
    let texts = |name: &str| -> Vec<String> {
        match &metadata[name] {
            Value::String(one) => vec![one.clone()],
            many => many
                .as_array()
                .into_iter()
                .flatten()
                .filter_map(|v| v.as_str().map(str::to_owned))
                .collect(),
        }
    };
    let ciflow = &metadata["ciflow"];
    let env_spec = match metadata["env_spec"].as_str() {
        Some(serialized) => {
            serde_json::from_str(serialized).map_err(|source| MetadataError::Json {
                field: "env_spec",
                source,
            })?
        }
        None => Value::Null,
    };
    let observation_space =
        parse_minari_box("observation_space", &text(metadata, "observation_space")?)?;
    let context_space = match ciflow["context_space"].as_str() {
        Some(serialized) => parse_minari_box("context_space", serialized)?,
        None => BoxSpace::new(vec![], vec![], observation_space.dtype),
    };
    Ok(DatasetSpec {
        dataset_id: text(metadata, "dataset_id")?,
        env_id: text(ciflow, "env_id")
            .or_else(|_| text(&env_spec, "id"))
            .unwrap_or_default(),
        // The numbers and texts among the construction arguments, which are what
        // ciflow's take; `task` only repeats the id.
        env_kwargs: env_spec["kwargs"]
            .as_object()
            .into_iter()
            .flatten()
            .filter(|(name, _)| name.as_str() != "task")
            .filter_map(|(name, value)| {
                let value = match value {
                    Value::String(text) => Kwarg::Text(text.clone()),
                    other => Kwarg::Number(other.as_f64()?),
                };
                Some((name.clone(), value))
            })
            .collect(),
        action_space: parse_minari_box("action_space", &text(metadata, "action_space")?)?,
        observation_space,
        context_space,
        control_dt: ciflow["control_dt"].as_f64().unwrap_or(f64::NAN),
        algorithm_name: text(metadata, "algorithm_name").unwrap_or_default(),
        credits: Credits {
            author: texts("author"),
            author_email: texts("author_email"),
            code_permalink: text(metadata, "code_permalink").ok(),
            description: text(metadata, "description").ok(),
        },
    })
}

/// A `Box` as Minari serializes it: a JSON string in Python's dialect, whose infinite
/// bounds are the bare tokens `Infinity` / `-Infinity`.
fn minari_box(space: &BoxSpace) -> String {
    let numbers = |values: &[f64]| {
        values
            .iter()
            .map(|v| match *v {
                v if v == f64::INFINITY => "Infinity".to_string(),
                v if v == f64::NEG_INFINITY => "-Infinity".to_string(),
                v => format!("{v:?}"),
            })
            .collect::<Vec<_>>()
            .join(", ")
    };
    let dtype = match space.dtype {
        Dtype::Float32 => "float32",
        Dtype::Float64 => "float64",
    };
    format!(
        r#"{{"type": "Box", "dtype": "{dtype}", "shape": [{}], "low": [{}], "high": [{}]}}"#,
        space.dim(),
        numbers(&space.low),
        numbers(&space.high)
    )
}

/// The space `field` of the metadata from its serialization `serialized`.
fn parse_minari_box(
    field: &'static str,
    serialized: &str,
) -> std::result::Result<BoxSpace, MetadataError> {
    let standard = serialized
        .replace("-Infinity", "\"-inf\"")
        .replace("Infinity", "\"inf\"");
    let value: Value =
        serde_json::from_str(&standard).map_err(|source| MetadataError::Json { field, source })?;
    if value["type"] != "Box" {
        return Err(format!(
            "its {field} is a {} space; this layout holds Box spaces only (a dataset made by \
             another tool is read by naming the fields that hold the state: `ciflow train \
             --state FIELD`, or `python -m ciflow.convert SOURCE OUT --state FIELD`)",
            value["type"].as_str().unwrap_or("non-Box")
        )
        .into());
    }
    let bounds = |name: &str| -> std::result::Result<Vec<f64>, String> {
        value[name]
            .as_array()
            .ok_or_else(|| format!("Box without `{name}`"))?
            .iter()
            .map(|v| match v {
                Value::String(s) if s == "inf" => Ok(f64::INFINITY),
                Value::String(s) if s == "-inf" => Ok(f64::NEG_INFINITY),
                v => v.as_f64().ok_or_else(|| format!("bad bound {v}")),
            })
            .collect()
    };
    let (low, high) = (bounds("low")?, bounds("high")?);
    if low.len() != high.len() {
        return Err(String::from("Box bounds differ in length").into());
    }
    let dtype = match value["dtype"].as_str() {
        Some("float32") => Dtype::Float32,
        _ => Dtype::Float64,
    };
    Ok(BoxSpace::new(low, high, dtype))
}

fn write_json(path: &Path, value: &Value) -> Result<()> {
    let text = serde_json::to_string_pretty(value).expect("JSON values always serialize");
    fs::write(path, text).map_err(io_error(path))
}

fn read_json(path: &Path) -> Result<Value> {
    let text = fs::read_to_string(path).map_err(io_error(path))?;
    serde_json::from_str(&text).map_err(|source| DatasetError::Json {
        path: path.to_path_buf(),
        source,
    })
}

fn io_error(path: &Path) -> impl FnOnce(std::io::Error) -> DatasetError + '_ {
    move |source| DatasetError::Io {
        path: path.to_path_buf(),
        source,
    }
}

fn arrow_error(path: &Path) -> impl FnOnce(arrow_schema::ArrowError) -> DatasetError + '_ {
    move |source| DatasetError::Arrow {
        path: path.to_path_buf(),
        source,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn minari_box_round_trips_with_infinite_bounds() {
        let space = BoxSpace::new(
            vec![f64::NEG_INFINITY, -1.5],
            vec![f64::INFINITY, 2.0],
            Dtype::Float32,
        );
        let parsed = parse_minari_box("observation_space", &minari_box(&space)).unwrap();
        assert_eq!(parsed, space);
    }
}
