//! The analyses of the tracker on the simulated sensor: how close each centroid method comes to
//! the Cramer-Rao bound ([`accuracy`]), where each sits on the speed/accuracy frontier and where
//! it fails ([`tradeoff`]), the founding paper's figures ([`figures`]), and the whole tracker's
//! accuracy and availability at body rate on the SIL ([`sil_rates`]) and with bright objects,
//! stray light and radiation ([`bright`]). Each writes CSVs (and PNGs
//! where a font is found) that `docs/` quotes and the tests check, so the `startrack` command and
//! the tests run the same code.

pub mod accuracy;
pub mod acquisition_rates;
pub mod bright;
pub mod exposure_chart;
pub mod figures;
pub mod sil_rates;
pub mod tradeoff;
pub mod trail_chart;
