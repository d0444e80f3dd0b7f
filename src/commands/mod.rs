//! One module per subcommand.

pub mod robot;

use crate::args::Command;

pub fn execute(command: Command) -> anyhow::Result<()> {
    match command {
        Command::Robot(args) => robot::run(args),
    }
}
