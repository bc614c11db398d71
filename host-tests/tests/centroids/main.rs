//! Detection and centroids: streaming detection, window capture, the scans, tracking windows
//! and every centroid method against f64 references.
//!
//! One module per subject, each with its own module docs; the shared f64 references and table
//! fixtures come from `startrack-test-support`.

mod capture;
mod centroid_cog;
mod centroid_cog_noise;
mod centroid_degenerate;
mod centroid_gauss_fit;
mod centroid_gauss_fit_width;
mod centroid_math;
mod centroid_trail_accel;
mod centroid_trail_fit;
mod centroid_trail_free;
mod detect;
mod pixcorr;
mod raw_cog;
mod scan;
mod track;
