//! `ciflow train` and `ciflow lasa`, run by the sibling program `ciflow-torch` (the same
//! directory, built with this one): the only commands that run libtorch, which this
//! program therefore never loads.
//!
//! On Unix the process becomes `ciflow-torch` (`exec`): same process id, signals, standard
//! streams and exit status, so that whoever started `ciflow train` (a test, a supervisor)
//! can stop it as before.

use std::ffi::OsString;
use std::path::PathBuf;
use std::process::Command;

use anyhow::{Context, bail};

/// The name of the program that runs the libtorch commands.
const PROGRAM: &str = "ciflow-torch";

/// A command's arguments, passed on untouched.
#[derive(clap::Args, Debug)]
pub struct Forwarded {
    /// The command's options: `ciflow train --help` (or `lasa`) lists them.
    #[arg(trailing_var_arg = true, allow_hyphen_values = true)]
    pub args: Vec<OsString>,
}

/// Runs `arguments` (`train …`, `lasa …`: the command line without the program's name,
/// untouched, as clap's parse of them would lose what `ciflow-torch` must see) in
/// `ciflow-torch`; returns only if it could not be started (on Unix), or with its failure.
pub fn run(arguments: impl IntoIterator<Item = OsString>) -> anyhow::Result<()> {
    let program = program()?;
    let mut command = Command::new(&program);
    command.args(arguments);
    #[cfg(unix)]
    {
        use std::os::unix::process::CommandExt;
        let error = command.exec();
        Err(error).with_context(|| format!("starting {}", program.display()))
    }
    #[cfg(not(unix))]
    {
        let status = command
            .status()
            .with_context(|| format!("starting {}", program.display()))?;
        std::process::exit(status.code().unwrap_or(1))
    }
}

/// `ciflow-torch` beside this program.
fn program() -> anyhow::Result<PathBuf> {
    let this = std::env::current_exe().context("finding the ciflow program's directory")?;
    let program = this.with_file_name(format!("{PROGRAM}{}", std::env::consts::EXE_SUFFIX));
    if !program.is_file() {
        bail!(
            "{} not found: `ciflow train` and `ciflow lasa` run it, and `cargo build \
             --release` (or `make`) builds it beside {}",
            program.display(),
            this.display()
        );
    }
    Ok(program)
}
