//! Subcommands of the `startrack` command whose logic lives in the library (argument
//! parsing with clap, and a `run` that returns the process exit code).

pub mod figures;
