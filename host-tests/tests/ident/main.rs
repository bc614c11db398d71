//! Identification, attitude and optics: lost-in-space and tracking identification, the on-board
//! catalog, the q-method, and the camera model and its fit.
//!
//! One module per subject, each with its own module docs; the shared f64 references and table
//! fixtures come from `startrack-test-support`.

mod attitude;
mod attitude_rate;
mod ident;
mod ident_catalog;
mod ident_scale;
mod ident_solve;
mod optics_camera;
mod optics_cli;
mod optics_colour;
mod optics_fit;
mod optics_table;
