//! Command-line arguments: one struct per subcommand, documented for `--help`.

use clap::{Parser, Subcommand};

use crate::commands;

/// Learn provably stable robot motions and serve them as Gymnasium environments over Zenoh.
#[derive(Parser, Debug)]
#[command(name = "ciflow", version, about, long_about = None)]
pub struct Cli {
    #[command(subcommand)]
    pub command: Command,
}

#[derive(Subcommand, Debug)]
pub enum Command {
    /// Inspect a robot model: kinematics and dynamics at a given state, printed as JSON.
    Robot(commands::robot::RobotArgs),
    /// Record expert demonstrations of a task into a Minari dataset.
    Demos(commands::demos::DemosArgs),
    /// Train a stable conditioned policy by exact maximum likelihood on demonstrations.
    Train(Box<commands::train::TrainArgs>),
    /// Measure how many noise-free rollouts of a trained policy converge.
    Stability(Box<commands::stability::StabilityArgs>),
    /// Evaluate a checkpoint: closed-loop success, collision, spill and push-recovery
    /// rates in its task, log-likelihood on a dataset, or 2-D vector-field figure data (JSON).
    Evaluate(Box<commands::evaluate::EvaluateArgs>),
    /// LASA handwriting benchmark: per shape, a stable flow against a behaviour-cloning
    /// MLP trained in the same run on the same demonstrations (the training options set the
    /// flow's; the MLP keeps its own: up to 200 epochs, early-stopped); writes tables (DTW,
    /// swept area, final error, time) and plots.
    Lasa(commands::lasa::LasaArgs),
    /// Start an engine that serves every task as a Gymnasium environment over Zenoh.
    Serve(commands::serve::ServeArgs),
    /// Run the Zenoh router that joins machines, optionally with access control.
    Router(commands::router::RouterArgs),
}
