//! The analyses of the core's centroid methods on the simulated sensor: how close each comes to
//! the Cramer-Rao bound ([`accuracy`]), where each sits on the speed/accuracy frontier and where
//! it fails ([`tradeoff`]), and the founding paper's figures ([`figures`]). Each writes CSVs
//! (and PNGs where a font is found) that `docs/` quotes and the tests check; it depends on the
//! core and the simulator only, so the `startrack` command and the tests run the same code.

pub mod accuracy;
pub mod figures;
pub mod tradeoff;
