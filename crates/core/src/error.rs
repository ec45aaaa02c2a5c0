//! The error type of the algorithm core.

use thiserror::Error;

/// Why inspection cannot judge a part, with what it found; each message says what to check.
#[derive(Debug, Error, Clone, PartialEq)]
pub enum InspectionError {
    /// The range image has no cells, or fewer values than cells.
    #[error("the range image is empty or inconsistent ({width}x{height} cells, {values} values)")]
    InconsistentRange {
        /// Columns.
        width: usize,
        /// Rows.
        height: usize,
        /// Heights held.
        values: usize,
    },
    /// Every cell is NaN.
    #[error("the range image holds no measurement at all (every cell is NaN): nothing was seen")]
    NoMeasurement,
    /// Nothing above the belt.
    #[error("the range image shows no part (nothing above the belt): nothing can be inspected")]
    NoPart,
    /// Too few cells above the belt to fit a reference surface.
    #[error(
        "the range image shows no part: {part_cells} of {cells} cells are above the belt level of {belt_level_mm} mm \
         (at least 20 are needed to fit a reference surface); check that the part was in view and that the scan worked"
    )]
    TooFewPartCells {
        /// Cells above the belt level.
        part_cells: usize,
        /// Cells of the range image.
        cells: usize,
        /// The belt level, mm.
        belt_level_mm: f64,
    },
    /// The part's surface is too small to inspect.
    #[error(
        "the part shows only {area_mm2:.1} mm² of surface: too little to inspect (check the scan)"
    )]
    TooLittleSurface {
        /// Its area, mm².
        area_mm2: f64,
    },
    /// The reference surface fit did not converge.
    #[error("the reference surface fit did not converge (degenerate part shape)")]
    ReferenceDiverged,
    /// The scan or the golden scan has too few part cells to register.
    #[error(
        "cannot register to the golden scan: the scan shows {scan_cells} part cells and the golden scan \
         {golden_cells} (at least 20 each are needed)"
    )]
    TooFewCellsToRegister {
        /// The scan's part cells.
        scan_cells: usize,
        /// The golden scan's.
        golden_cells: usize,
    },
    /// The golden scan does not overlap the part after the best shift.
    #[error(
        "the golden scan does not overlap this scan: only {:.0}% of the part lands on the golden part after the best \
         shift of ({dx_mm:.1}, {dy_mm:.1}) mm (at least {:.0}% needed); is it a scan of the same product?",
        100.0 * overlap,
        100.0 * needed
    )]
    NoOverlap {
        /// Share of the part on the golden part.
        overlap: f64,
        /// The best shift, mm.
        dx_mm: f64,
        /// The best shift, mm.
        dy_mm: f64,
        /// Share needed.
        needed: f64,
    },
    /// A prepared golden scan's parameters differ from the inspection's.
    #[error(
        "the golden scan was prepared with {what} {prepared} but the inspection uses {asked}: prepare it with the \
         inspection's parameters"
    )]
    GoldenPreparedOtherwise {
        /// Which parameter, e.g. "a belt level of".
        what: &'static str,
        /// The prepared value.
        prepared: String,
        /// The inspection's.
        asked: String,
    },
    /// The method compares with a golden scan and none was given.
    #[error(
        "method `{method}` compares parts with a golden scan: give one (inspect --reference DIR)"
    )]
    GoldenNeeded {
        /// The method's name.
        method: String,
    },
}

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
    /// Calibration refused its input (see [`crate::calibrate::CalibrationError`]: the image and what to do).
    #[error("calibration: {0}")]
    Calibration(crate::calibrate::CalibrationError),
    /// Inspection cannot judge the part (see [`InspectionError`]).
    #[error("inspection: {0}")]
    Inspection(InspectionError),
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
    /// A frame source failed (a camera, a recording, the simulator).
    #[error("{source_name}: {message}")]
    Source {
        /// The source, as the user named it.
        source_name: String,
        /// What went wrong and what to do.
        message: String,
    },
}
