//! `ciflow`: the command-line tool. It only parses and dispatches; the work happens in the
//! library crates. `train` and `lasa` run in the sibling program `ciflow-torch`, so that
//! every other command starts without libtorch ([`commands::torch`]).

mod args;
mod commands;

use std::process::ExitCode;

use args::Command;
use clap::Parser;

fn main() -> ExitCode {
    let arguments: Vec<_> = std::env::args_os().skip(1).collect();
    // Before clap, whose own `help train` knows only the forwarding stub.
    if let Some(command) = args::forwarded_help(&arguments) {
        let result = commands::torch::run([command.to_owned(), "--help".into()]);
        return ciflow_cli::report::exit_code(result);
    }
    let result = match args::Cli::parse().command {
        Command::Robot(args) => commands::robot::run(args),
        Command::Demos(args) => commands::demos::run(args),
        Command::Train(_) | Command::Lasa(_) => commands::torch::run(arguments),
        Command::Stability(args) => commands::stability::run(*args),
        Command::Evaluate(args) => commands::evaluate::run(*args),
        Command::Serve(args) => commands::serve::run(args),
        Command::Router(args) => commands::router::run(args),
    };
    ciflow_cli::report::exit_code(result)
}
