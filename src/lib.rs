//! What the two command-line programs share: `ciflow` (every command that does not train)
//! and `ciflow-torch` (`ciflow train` and `ciflow lasa`, the only ones that run libtorch).
//! They are two programs so that an engine, a router or an evaluation never loads
//! libtorch: loading it took 0.3–0.5 s and 118 MB of resident memory before any command
//! ran (README, "Command line").

pub mod network;
pub mod parse;
pub mod progress;
pub mod report;

/// What `ciflow train` does, for both programs' `--help`.
pub const TRAIN_ABOUT: &str =
    "Train a stable conditioned policy by exact maximum likelihood on demonstrations";

/// What `ciflow lasa` does, for both programs' `--help`.
pub const LASA_ABOUT: &str = "LASA handwriting benchmark: per shape, a stable flow against a \
     behaviour-cloning MLP trained in the same run on the same demonstrations (the training \
     options set the flow's; the MLP keeps its own: all the demonstrations, 200 epochs); writes \
     tables (DTW, swept area, final error, time) and plots";
