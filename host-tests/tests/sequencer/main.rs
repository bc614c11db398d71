//! The CCD sequencer: compiled programs, their DMA lists, limits, routing, the charge-transfer
//! model and the readout targets.
//!
//! One module per subject, each with its own module docs; the shared f64 references and table
//! fixtures come from `startrack-test-support`.

mod sequencer_chain;
mod sequencer_limits;
mod sequencer_mdma;
mod sequencer_model;
mod sequencer_route;
mod sequencer_targets;
