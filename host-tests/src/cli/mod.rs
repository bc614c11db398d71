//! The `startrack` subcommands: one module per subcommand, each with its clap `Args` struct
//! and a `run`.

pub mod accuracy;
