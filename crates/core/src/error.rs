//! The error type of the algorithm core.

use thiserror::Error;

/// Everything the core can refuse. Fields name what was wrong so a caller can build a precise message.
#[derive(Debug, Error, Clone, PartialEq)]
pub enum CoreError {
    /// An image buffer is too small for the width, height and stride it was given.
    #[error(
        "image buffer holds {len} pixels but {width}x{height} with stride {stride} needs {needed}"
    )]
    BufferTooSmall {
        /// Pixels in the buffer.
        len: usize,
        /// Image width in pixels.
        width: usize,
        /// Image height in pixels.
        height: usize,
        /// Row stride in pixels.
        stride: usize,
        /// Pixels the geometry needs.
        needed: usize,
    },
    /// The row stride is smaller than the width.
    #[error("row stride {stride} is smaller than the width {width}")]
    StrideTooSmall {
        /// Row stride in pixels.
        stride: usize,
        /// Image width in pixels.
        width: usize,
    },
    /// A shipped fuzzy rule base does not load (an edited rule file).
    #[error("rule base {file}: {message}")]
    RuleBase {
        /// The rule file, e.g. `single_peak.fll`.
        file: &'static str,
        /// What the fuzzy engine reported.
        message: String,
    },
    /// A sensor description field holds an impossible value.
    #[error("{field} = {value}: {reason}")]
    InvalidSensor {
        /// Dotted field name as written in `sensor.toml`, e.g. `camera.fx`.
        field: &'static str,
        /// The offending value, as text.
        value: String,
        /// What is wrong and what would be right.
        reason: String,
    },
    /// A parameter of an algorithm holds an impossible value.
    #[error("{field} = {value}: {reason}")]
    InvalidParameter {
        /// The parameter's name.
        field: &'static str,
        /// The offending value, as text.
        value: String,
        /// What is wrong and what would be right.
        reason: String,
    },
    /// Calibration refused its input; the message names the image and what to do.
    #[error("calibration: {message}")]
    Calibration {
        /// What is wrong and what to do.
        message: String,
    },
    /// Inspection cannot judge the part (no part in the scan, a reference that does not fit it).
    #[error("inspection: {message}")]
    Inspection {
        /// What is wrong and what to do.
        message: String,
    },
    /// A scan in which no point could be coded and triangulated.
    #[error(
        "nothing was measured in {frames} frames ({points} stripe points found, none could be coded): check the \
         exposure, the calibration and the measuring range (--range)"
    )]
    NothingMeasured {
        /// Frames of the scan.
        frames: usize,
        /// Stripe points extraction found in them.
        points: usize,
    },
}
