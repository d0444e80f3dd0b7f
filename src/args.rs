//! Command-line arguments: one struct per subcommand, documented for `--help`.

use std::ffi::{OsStr, OsString};

use clap::{CommandFactory, Parser, Subcommand};

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
    #[command(about = ciflow_cli::TRAIN_ABOUT, disable_help_flag = true)]
    Train(commands::torch::Forwarded),
    /// Measure how many noise-free rollouts of a trained policy converge.
    Stability(Box<commands::stability::StabilityArgs>),
    /// Evaluate a checkpoint: closed-loop success, collision, spill and push-recovery
    /// rates in its task, log-likelihood on a dataset, or 2-D vector-field figure data (JSON).
    Evaluate(Box<commands::evaluate::EvaluateArgs>),
    #[command(about = ciflow_cli::LASA_ABOUT, disable_help_flag = true)]
    Lasa(commands::torch::Forwarded),
    /// Start an engine that serves every task as a Gymnasium environment over Zenoh.
    Serve(commands::serve::ServeArgs),
    /// Run the Zenoh router that joins machines, optionally with access control.
    Router(commands::router::RouterArgs),
}

/// The command whose help `arguments` (a command line without the program's name) ask for
/// as `help <command>`, if that command runs in `ciflow-torch`: clap's own `help`
/// subcommand would show only the forwarding stub's usage, and `ciflow-torch` knows the
/// real options. Those commands are the ones that leave their help flag to it
/// (`disable_help_flag` above).
pub fn forwarded_help(arguments: &[OsString]) -> Option<&OsStr> {
    let [help, command] = arguments else {
        return None;
    };
    let forwarded = Cli::command()
        .find_subcommand(command)
        .is_some_and(clap::Command::is_disable_help_flag_set);
    (help == "help" && forwarded).then_some(command.as_os_str())
}
