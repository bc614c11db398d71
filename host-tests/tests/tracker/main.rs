//! The tracker and the SIL: the core's application through its host homes, its mode rules, the
//! frame cycle, safe states, the dark drift, the attitude stage, tracking from the attitude
//! (the catalog's predicted windows), the sky turning during the exposure and the demo.
//!
//! One module per subject, each with its own module docs; the shared f64 references and table
//! fixtures come from `startrack-test-support`.

mod catalog_windows;
mod dark_drift;
mod demo;
mod frame_cycle;
mod safe_states;
mod sil_acquire_rate;
mod sil_bright;
mod sil_motion;
mod sil_second_bright;
mod sil_second_sky;
mod sil_sky;
mod tracker;
mod tracker_rules;
