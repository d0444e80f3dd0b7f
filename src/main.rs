//! `ciflow`: the command-line tool. It only parses and dispatches; the work happens in the
//! library crates.

mod args;
mod commands;

use clap::Parser;

fn main() -> anyhow::Result<()> {
    let cli = args::Cli::parse();
    commands::execute(cli.command)
}
