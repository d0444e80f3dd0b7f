//! One module per subcommand.

pub mod demos;
pub mod evaluate;
pub mod lasa;
pub mod network;
pub mod robot;
pub mod serve;
pub mod stability;
pub mod train;

use crate::args::Command;

pub fn execute(command: Command) -> anyhow::Result<()> {
    match command {
        Command::Robot(args) => robot::run(args),
        Command::Demos(args) => demos::run(args),
        Command::Train(args) => train::run(args),
        Command::Stability(args) => stability::run(args),
        Command::Evaluate(args) => evaluate::run(args),
        Command::Lasa(args) => lasa::run(args),
        Command::Serve(args) => serve::run(args),
    }
}
