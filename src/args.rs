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
}
