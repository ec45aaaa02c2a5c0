//! # stripe3d-core
//!
//! The algorithms of stripe3d, with no I/O at all: borrowed image views ([`image`]), stripe extraction
//! ([`extract`]), stripe coding ([`code`]), calibration from plate images ([`calibrate`]), triangulation
//! ([`triangulate`]), the curvature bias of a sheet of finite thickness ([`curvature`]), profiles and range grids
//! ([`accumulate`]), frames to profiles to range images ([`scan`]),
//! reference surfaces, deviation and curvature ([`characterize`]), defects found, named and measured ([`detect`]),
//! the sensor geometry and the conventions every crate shares ([`sensor`]), and the fuzzy rule bases of the paper
//! ([`rules`]).
//!
//! Conventions (see `docs/design.md`): millimetres, seconds, radians; world frame z up from the belt, x along conveyor
//! travel, right-handed, origin on the belt below the camera's optical centre; the camera looks straight down with
//! image u along +x and v along −y; pixel centres at integer coordinates.
#![deny(missing_docs)]

pub mod accumulate;
pub mod calibrate;
pub mod code;
pub mod curvature;
pub mod error;
pub mod extract;
pub mod geometry;
pub mod image;
pub mod line;
pub mod rules;
pub mod scan;
pub mod sensor;
pub mod spacetime;
pub mod surface;
pub mod triangulate;

/// A seeded xorshift generator for the unit tests' random lines: reproducible, no dependency.
#[cfg(test)]
pub(crate) fn test_rng(seed: u32) -> impl FnMut() -> u32 {
    let mut rng = seed;
    move || {
        rng ^= rng << 13;
        rng ^= rng >> 17;
        rng ^= rng << 5;
        rng
    }
}

pub use error::{CoreError, InspectionError};
pub use image::{Image, ImageView, Pixel};
pub use sensor::{Camera, Conveyor, Laser, LaserPlane, Sensor};
pub use surface::{characterize, detect};
