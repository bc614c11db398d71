//! The `startrack` command: one module per subcommand ([`cli`]), each parsing its options and
//! calling the library that does the work: the frame cycle's host homes (`startrack-homes`),
//! the lab and sky tools (`startrack-lab`), the analyses (`startrack-analysis`), the simulated
//! sensor (`startrack-sim`) and the ground client (`startrack-ground`). The binary is
//! `src/bin/startrack.rs`; the tests of every crate live in `tests/`.

pub mod cli;
