//! Errors raised while building a [`Model`](super::Model).

use thiserror::Error;

#[derive(Debug, Error)]
pub enum ModelError {
    #[error("cannot parse URDF: {0}")]
    Urdf(#[from] urdf_rs::UrdfError),
    #[error("cannot read {path}")]
    Read {
        path: std::path::PathBuf,
        source: std::io::Error,
    },
    #[error(
        "joint `{joint}` is {kind}; a model is a fixed-base chain of revolute, continuous, \
         prismatic and fixed joints"
    )]
    UnsupportedJoint { joint: String, kind: String },
    #[error("cannot lock joint `{joint}`: {reason}")]
    Lock { joint: String, reason: String },
    #[error(
        "joint `{joint}` moves no mass: link `{link}` and every link after it have zero mass \
         and inertia (a URDF link without <inertial> is massless)"
    )]
    Massless { joint: String, link: String },
    #[error(
        "joint `{joint}` ({kind}) has position limits [{lower}, {upper}], which leave it no \
         motion: a revolute or prismatic joint needs a <limit> with lower < upper (a missing \
         <limit> reads as [0, 0]); make it continuous or fixed, or lock it at a position"
    )]
    NoMotion {
        joint: String,
        kind: &'static str,
        lower: f64,
        upper: f64,
    },
    #[error("the URDF has two {kind}s named `{name}`")]
    DuplicateName { kind: &'static str, name: String },
    #[error("the URDF is not a serial chain: {0}")]
    NotSerialChain(String),
    #[error("{what} is not finite")]
    NonFinite { what: String },
    #[error("joint `{joint}` has a zero axis")]
    ZeroAxis { joint: String },
    #[error("body `{body}` has an invalid inertia: {reason}")]
    InvalidInertia { body: String, reason: &'static str },
    #[error("frame `{frame}` refers to body {body}, but the model has {bodies} bodies")]
    NoSuchBody {
        frame: String,
        body: usize,
        bodies: usize,
    },
    #[error("no frame named `{0}`")]
    NoSuchFrame(String),
    #[error("frame name `{0}` is used twice")]
    DuplicateFrame(String),
    #[error("joint limit {what}[{joint}] is invalid: {reason}")]
    InvalidLimits {
        what: &'static str,
        joint: usize,
        reason: &'static str,
    },
    #[error("armature[{joint}] is invalid: {reason}")]
    InvalidArmature { joint: usize, reason: &'static str },
    #[error("{what}: expected {expected} entries, got {actual}")]
    Dimension {
        what: &'static str,
        expected: usize,
        actual: usize,
    },
}
