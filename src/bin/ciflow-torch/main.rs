//! `ciflow-torch`: `ciflow train` and `ciflow lasa`, the commands that run libtorch, in a
//! program of their own that `ciflow` hands them to (`src/commands/torch.rs`). It parses
//! and dispatches like `ciflow`, under the same name in its help.

mod lasa;
mod train;

use std::process::ExitCode;

use clap::{Parser, Subcommand};

/// The libtorch half of `ciflow`; run through `ciflow train` and `ciflow lasa`.
#[derive(Parser, Debug)]
#[command(name = "ciflow", bin_name = "ciflow", version, long_about = None)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand, Debug)]
enum Command {
    #[command(about = ciflow_cli::TRAIN_ABOUT)]
    Train(Box<train::TrainArgs>),
    #[command(about = ciflow_cli::LASA_ABOUT)]
    Lasa(Box<lasa::LasaArgs>),
}

fn main() -> ExitCode {
    let result = match Cli::parse().command {
        Command::Train(args) => train::run(*args),
        Command::Lasa(args) => lasa::run(*args),
    };
    ciflow_cli::report::exit_code(result)
}
