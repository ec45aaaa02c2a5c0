//! # stripe3d-io
//!
//! Everything of stripe3d that touches the outside world: `sensor.toml` and scene files (TOML), images
//! (PNG 8/16-bit, PGM, TIFF), the simulator's ground truth (CSV, JSON, float32 TIFF), knowledge-base folders, the
//! SQLite inspection history, and safe file writing.
//!
//! Every error names the file, and where it can the line and field, and says what to do. Files are written to a
//! temporary name in the same folder and renamed into place, so a failed run never leaves a half-written file
//! that looks complete.
#![deny(missing_docs)]

pub mod calib;
pub mod cloud;
pub mod config;
pub mod encoder;
pub mod error;
pub mod files;
pub mod history;
pub mod images;
pub mod knowledge;
pub mod report;
pub mod source;
pub mod truth;
pub mod validation;

pub use calib::{calibration_to_toml, read_calibration};
pub use config::{read_coding_params, read_scene, read_sensor, scene_to_toml, sensor_to_toml};
pub use error::IoError;
pub use files::write_atomic;
