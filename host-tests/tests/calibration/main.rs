//! Calibration: electrons from ADU, the lab-frame calibration, charge traps, the defect watch
//! and table amendments, and the calibration-table format.
//!
//! One module per subject, each with its own module docs; the shared f64 references and table
//! fixtures come from `startrack-test-support`.

mod calib_frames;
mod calib_frames_campaign;
mod calib_frames_errors;
mod calib_frames_rts;
mod calibration;
mod cti;
mod cti_eper;
mod defect_commit;
mod lab_campaign;
mod refresh;
mod table_amend;
mod table_format;
mod table_fuzz;
