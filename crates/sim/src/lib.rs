//! # stripe3d-sim
//!
//! A physically based laser-stripe renderer with exact ground truth, written from first principles so that every
//! accuracy claim of stripe3d can be measured.
//!
//! - [`scene`]: parts as height maps (plate, steps, bosses, chamfers; bumps, dents and through-holes as defects;
//!   albedo and glossy patches), rasterised to a [`heightfield::HeightField`].
//! - [`render`]: the camera (pinhole, radial k1), the multi-line projector (Gaussian sheets fanning from one
//!   source), light transport (Lambertian reflection with albedo and cosine of incidence, shadowing, camera
//!   occlusion by first hit, ambient light with cos⁴ vignetting, Phong highlights and ghost stripes from glossy
//!   patches acting as mirrors), speckle, optical blur, shot and read noise, quantisation and saturation; conveyor
//!   motion; and for every frame the exact sub-pixel column where each row's camera ray meets the lit surface on
//!   each sheet's centre plane.
//! - [`batch`]: simulated production batches (plates from a process with a seeded fault), idealised range images of
//!   them, and scoring found defects against the truth.
//! - [`random`]: random scenes drawn over what production lines show (the robustness bench).
//! - [`pipeline`]: the measuring chain on simulated frames in memory (calibration from rendered plates, scans through
//!   `stripe3d_core::scan::Scanner`), for benchmarks and ground-truth tests.
#![deny(missing_docs)]

pub mod batch;
pub mod belt;
pub mod evaluate;
pub mod heightfield;
pub mod pipeline;
pub mod random;
pub mod render;
pub mod scene;

pub use render::{EdgeMap, Frame, RenderOptions, Simulator, TruthPoint};
pub use scene::{DefectTruth, Feature, Scene};

use thiserror::Error;

/// What the simulator refuses.
#[derive(Debug, Error, Clone, PartialEq)]
pub enum SimError {
    /// A scene field is out of range.
    #[error("scene field {field}: {reason}")]
    InvalidScene {
        /// Dotted field name, e.g. `feature[2].diameter_mm`.
        field: String,
        /// What is wrong.
        reason: String,
    },
    /// The sensor description is impossible.
    #[error("sensor: {0}")]
    Sensor(#[from] stripe3d_core::CoreError),
}
