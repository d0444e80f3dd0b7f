//! `ciflow`: the command-line tool. It only parses and dispatches; the work happens in the
//! library crates.

mod args;
mod commands;
mod parse;
mod progress;

use args::Command;
use clap::Parser;

fn main() -> anyhow::Result<()> {
    match args::Cli::parse().command {
        Command::Robot(args) => commands::robot::run(args),
        Command::Demos(args) => commands::demos::run(args),
        Command::Train(args) => commands::train::run(*args),
        Command::Stability(args) => commands::stability::run(*args),
        Command::Evaluate(args) => commands::evaluate::run(*args),
        Command::Lasa(args) => commands::lasa::run(args),
        Command::Serve(args) => commands::serve::run(args),
        Command::Router(args) => commands::router::run(args),
    }
}
