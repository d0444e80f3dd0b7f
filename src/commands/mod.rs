//! One module per subcommand.

pub mod demos;
pub mod evaluate;
pub mod robot;
pub mod router;
pub mod serve;
pub mod stability;
pub mod torch;
