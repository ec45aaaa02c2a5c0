//! Calibration from images of a flat matte plate at known heights (gauge blocks), the way a user calibrates on
//! the line.
//!
//! 1. **Lines.** In each image, the extracted points are linked down the rows into lines (a stripe on a flat plate
//!    is one long, nearly vertical line); pieces of one stripe (broken where it dims, or where the lens bends it out
//!    of the image at a side) are joined, and short fragments are ignored.
//! 2. **Which stripe is which.** A flat plate keeps the stripes in order, so within an image only the index of the
//!    first line is unknown (stripes leave the view at the sides as the plate rises, and over a realistic range a
//!    stripe moves by more than the pitch). The image whose lines fit the nominal geometry of `sensor.toml` best,
//!    by a clear margin, is the anchor (an image showing all the stripes is its own anchor); the others are
//!    identified from their neighbour in height by continuity: each stripe moves between two heights by what the
//!    nominal geometry predicts for that change, which holds even where the nominal position itself is off.
//! 3. **Fits.** Each pixel's ray meets the plate at its known height, giving 3-D points of each stripe's plane; the
//!    plane is fitted by total least squares (full model). The paper's linear model is fitted per stripe by least
//!    squares of height on column (with a quadratic along the row).
//! 4. **Checks.** Fewer than three heights, two images at one height, stripes that move the wrong way between
//!    heights (images swapped), or points that sit off their fitted planes (a mislabelled height) are refused with
//!    a message that names the image. With four heights or more, the image that does not fit is found by leaving
//!    each out in turn.

use crate::CoreError;
use crate::extract::StripePoint;
use crate::sensor::{Camera, Sensor};
use crate::triangulate::{FullModel, LinearModel, LinearStripe, Plane, fit_plane};
use nalgebra::{DMatrix, DVector, Vector3};

/// One calibration image: the plate's height and the points extracted from it.
#[derive(Debug, Clone, PartialEq)]
pub struct PlaneImage {
    /// Name for messages (usually the file name).
    pub name: String,
    /// Height of the plate's top above the belt, mm.
    pub height_mm: f64,
    /// Stripe points extracted along rows.
    pub points: Vec<StripePoint>,
}

/// Parameters of [`calibrate`].
#[derive(Debug, Clone, PartialEq)]
pub struct CalibrationParams {
    /// Largest column change (pixels) between linked points of neighbouring rows of a line.
    pub link_px: f64,
    /// Least share of the image's rows a line must cover to count as a stripe.
    pub min_line_share: f64,
    /// Largest RMS height residual (mm) of a stripe at one height before the images are called inconsistent.
    pub max_residual_mm: f64,
}

impl Default for CalibrationParams {
    fn default() -> Self {
        Self {
            link_px: 2.0,
            min_line_share: 0.3,
            // Ten times the RMS measured with the paper's set-up and default noise (about 0.005 mm): a height
            // mislabelled by 0.05 mm or more is refused.
            max_residual_mm: 0.05,
        }
    }
}

/// What calibration found for one stripe.
#[derive(Debug, Clone, PartialEq)]
pub struct StripeReport {
    /// Stripe index.
    pub stripe: usize,
    /// Heights (mm) of the images in which the stripe was seen.
    pub heights_mm: Vec<f64>,
    /// Points used.
    pub points: usize,
    /// RMS height error of the full model over the stripe's points, mm.
    pub full_rms_mm: f64,
    /// Largest height error of the full model, mm.
    pub full_max_mm: f64,
    /// RMS height error of the linear model, mm.
    pub linear_rms_mm: f64,
    /// Largest height error of the linear model, mm.
    pub linear_max_mm: f64,
}

/// The result of calibration: both triangulation models and the report.
#[derive(Debug, Clone, PartialEq)]
pub struct Calibration {
    /// The full model (camera of `sensor.toml`, fitted stripe planes).
    pub full: FullModel,
    /// The paper's linear model.
    pub linear: LinearModel,
    /// Heights of the calibration images, ascending, mm.
    pub heights_mm: Vec<f64>,
    /// Per stripe.
    pub stripes: Vec<StripeReport>,
}

impl Calibration {
    /// The heights over which the models were fitted, `(lowest, highest)` mm.
    pub fn fitted_range_mm(&self) -> (f64, f64) {
        (
            self.heights_mm.first().copied().unwrap_or(0.0),
            self.heights_mm.last().copied().unwrap_or(0.0),
        )
    }

    /// The heights stripe coding allows by default: the calibrated range, 1 mm below and a quarter of its span
    /// (at least 1 mm) above, where the calibrated planes still extrapolate well.
    pub fn coding_range_mm(&self) -> (f64, f64) {
        let (lo, hi) = self.fitted_range_mm();
        (lo - 1.0, hi + 0.25 * (hi - lo).max(4.0))
    }
}

/// Why calibration refused its plate images, with what it found; each message names the image and what to do.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum CalibrationError {
    /// Fewer than three plate images.
    #[error(
        "{given} plate image(s) given; calibration needs plates at three heights at least (--plane HEIGHT_MM:IMAGE, \
         repeated)"
    )]
    TooFewPlates {
        /// Images given.
        given: usize,
    },
    /// A plate's height is not between the belt and the camera.
    #[error(
        "{image}: height {height_mm} mm is not between the belt (0) and the camera ({camera_mm} mm)"
    )]
    HeightOutOfRange {
        /// The image.
        image: String,
        /// Its height label, mm.
        height_mm: f64,
        /// The camera's height above the belt, mm.
        camera_mm: f64,
    },
    /// Two images carry the same height.
    #[error("{first} and {second} are both labelled {height_mm} mm; give each height once")]
    SameHeight {
        /// One image.
        first: String,
        /// The other.
        second: String,
        /// Their height, mm.
        height_mm: f64,
    },
    /// No stripe in an image.
    #[error("{image}: no stripe found; is the plate lit and in view?")]
    NoStripe {
        /// The image.
        image: String,
    },
    /// More stripe lines in an image than the sensor has stripes.
    #[error(
        "{image}: {lines} stripe lines found but the sensor has {stripes} stripes (reflections or a plate that is not \
         flat?)"
    )]
    TooManyLines {
        /// The image.
        image: String,
        /// Lines found.
        lines: usize,
        /// The sensor's stripes.
        stripes: usize,
    },
    /// No image's stripes match the nominal geometry.
    #[error("no image could be matched to the sensor's stripes")]
    NoImageMatched,
    /// An image's stripes cannot be matched to those of the image next to it in height.
    #[error("{image}: its stripes cannot be matched to those at {from_mm} mm")]
    Unmatched {
        /// The image.
        image: String,
        /// The height of the image it was matched from, mm.
        from_mm: f64,
    },
    /// An image's stripes are not where the image next to it in height puts them.
    #[error(
        "{image} ({height_mm} mm): its stripes do not follow from the image at {from_mm} mm (they are {error_px:.1} px \
         from where the heights say they should be); are the heights right and the images in the right order?"
    )]
    DoesNotFollow {
        /// The image.
        image: String,
        /// Its height label, mm.
        height_mm: f64,
        /// The height of the image it was matched from, mm.
        from_mm: f64,
        /// How far its stripes are from where they should be, px.
        error_px: f64,
    },
    /// A stripe moves against the others between two heights.
    #[error(
        "stripe {stripe} moves the wrong way between {first} ({first_mm} mm) and {second} ({second_mm} mm): were these \
         images swapped?"
    )]
    WrongWay {
        /// The stripe.
        stripe: usize,
        /// The lower image.
        first: String,
        /// Its height, mm.
        first_mm: f64,
        /// The higher image.
        second: String,
        /// Its height, mm.
        second_mm: f64,
    },
    /// A stripe is seen at fewer than three heights.
    #[error(
        "stripe {stripe} is seen at {} height(s) ({}); it needs three: add plate images at heights where it is in view",
        seen_mm.len(),
        heights_list(seen_mm)
    )]
    TooFewHeights {
        /// The stripe.
        stripe: usize,
        /// The heights it is seen at, mm.
        seen_mm: Vec<f64>,
    },
    /// A stripe's points do not define a plane.
    #[error("stripe {stripe}: its points do not define a plane")]
    NoPlane {
        /// The stripe.
        stripe: usize,
    },
    /// One image's stripes lie off the planes the other images define.
    #[error(
        "{image} (labelled {height_mm} mm) does not fit the other images: its stripes sit {rms_mm:.3} mm RMS off the \
         planes the others define (limit {limit_mm} mm); check its height label, or whether images were swapped"
    )]
    ImageOffPlanes {
        /// The image.
        image: String,
        /// Its height label, mm.
        height_mm: f64,
        /// Its RMS distance from the others' planes, mm.
        rms_mm: f64,
        /// The limit, mm.
        limit_mm: f64,
    },
    /// The images do not fit one set of planes, and no single image is to blame.
    #[error(
        "the images do not fit one set of stripe planes: {image} (labelled {height_mm} mm) is {rms_mm:.3} mm RMS off \
         (limit {limit_mm} mm); a height label is wrong or images were swapped (with four heights or more the image \
         at fault is named)"
    )]
    NoCommonPlanes {
        /// The image furthest off.
        image: String,
        /// Its height label, mm.
        height_mm: f64,
        /// Its RMS distance, mm.
        rms_mm: f64,
        /// The limit, mm.
        limit_mm: f64,
    },
    /// The paper's linear model could not be fitted to a stripe.
    #[error("stripe {stripe}: linear model fit failed: {reason}")]
    LinearFit {
        /// The stripe.
        stripe: usize,
        /// Why.
        reason: String,
    },
    /// A calibration made for another image size.
    #[error(
        "the calibration was made for {}x{} images but the sensor has {}x{}; calibrate this sensor",
        calibrated[0],
        calibrated[1],
        sensor[0],
        sensor[1]
    )]
    ImageSize {
        /// The calibrated camera's width and height, px.
        calibrated: [usize; 2],
        /// The sensor's, px.
        sensor: [usize; 2],
    },
    /// A calibration made with another camera.
    #[error(
        "the calibration was made with camera.{field} = {calibrated} but the sensor has {sensor}; calibrate this sensor"
    )]
    CameraDiffers {
        /// The camera field, e.g. `fx`.
        field: &'static str,
        /// The calibrated value.
        calibrated: f64,
        /// The sensor's.
        sensor: f64,
    },
}

/// "none", or the heights as "5 mm, 10 mm".
fn heights_list(heights: &[f64]) -> String {
    if heights.is_empty() {
        "none".to_string()
    } else {
        heights
            .iter()
            .map(|h| format!("{h} mm"))
            .collect::<Vec<_>>()
            .join(", ")
    }
}

fn fail(e: CalibrationError) -> CoreError {
    CoreError::Calibration(e)
}

/// One calibration sample of a stripe: (image index in height order, u, v, world point).
type StripeSample = (usize, f64, f64, Vector3<f64>);

/// A line of one image: (row, column) points, rows ascending.
#[derive(Debug, Clone)]
struct Line {
    points: Vec<(u32, f64)>,
}

impl Line {
    fn median_column(&self) -> f64 {
        let mut c: Vec<f64> = self.points.iter().map(|p| p.1).collect();
        c.sort_by(f64::total_cmp);
        c[c.len() / 2]
    }

    /// Column at `row`, from the nearest point of the line.
    fn column_near(&self, row: u32) -> f64 {
        let i = self.points.partition_point(|p| p.0 < row);
        let cand = [i.checked_sub(1), Some(i)];
        cand.iter()
            .flatten()
            .filter_map(|&k| self.points.get(k))
            .min_by_key(|p| p.0.abs_diff(row))
            .map_or(f64::NAN, |p| p.1)
    }
}

/// Links an image's points into long lines, ordered by column. Pieces of one stripe are joined first: a stripe on a
/// flat plate is one smooth curve, so two pieces whose rows do not overlap and whose facing ends lie within a
/// quarter of the stripe pitch (`pitch_px`) of each other in column are the same stripe, broken where it dims or
/// where the lens's distortion bends it out of the image (as with a stripe at the image's side).
fn lines_of(
    points: &[StripePoint],
    rows: u32,
    pitch_px: f64,
    params: &CalibrationParams,
) -> Vec<Line> {
    let mut pts: Vec<&StripePoint> = points.iter().filter(|p| p.x.is_finite()).collect();
    pts.sort_by(|a, b| a.row.cmp(&b.row).then(a.x.total_cmp(&b.x)));
    let mut lines: Vec<Line> = Vec::new();
    let mut open: Vec<usize> = Vec::new();
    const MAX_GAP_ROWS: u32 = 5;
    for p in pts {
        open.retain(|&l| {
            lines[l]
                .points
                .last()
                .is_some_and(|q| p.row - q.0 <= MAX_GAP_ROWS + 1)
        });
        let best = open
            .iter()
            .copied()
            .filter(|&l| lines[l].points.last().is_some_and(|q| q.0 < p.row))
            .map(|l| {
                (
                    l,
                    lines[l]
                        .points
                        .last()
                        .map_or(f64::INFINITY, |q| (q.1 - p.x).abs()),
                )
            })
            .filter(|&(_, d)| d <= params.link_px)
            .min_by(|a, b| a.1.total_cmp(&b.1));
        match best {
            Some((l, _)) => lines[l].points.push((p.row, p.x)),
            None => {
                lines.push(Line {
                    points: vec![(p.row, p.x)],
                });
                open.push(lines.len() - 1);
            }
        }
    }
    let lines = join_pieces(lines, 0.25 * pitch_px);
    let min_points = (params.min_line_share * f64::from(rows)).max(3.0) as usize;
    let mut long: Vec<Line> = lines
        .into_iter()
        .filter(|l| l.points.len() >= min_points)
        .collect();
    long.sort_by(|a, b| a.median_column().total_cmp(&b.median_column()));
    long
}

/// Joins line pieces (see [`lines_of`]): in order of their first row, each piece continues the piece ending above
/// it whose last point is nearest its first in column, within `reach_px`. Pieces of a few points (noise) stay
/// alone.
fn join_pieces(mut lines: Vec<Line>, reach_px: f64) -> Vec<Line> {
    const MIN_PIECE: usize = 3;
    lines.sort_by_key(|l| l.points.first().map_or(0, |p| p.0));
    let mut joined: Vec<Line> = Vec::with_capacity(lines.len());
    for line in lines {
        let (Some(&(row, col)), true) = (line.points.first(), line.points.len() >= MIN_PIECE)
        else {
            joined.push(line);
            continue;
        };
        let above = joined
            .iter_mut()
            .filter(|l| l.points.len() >= MIN_PIECE)
            .filter_map(|l| {
                let &(r, c) = l.points.last()?;
                (r < row && (c - col).abs() <= reach_px).then_some(((c - col).abs(), l))
            })
            .min_by(|a, b| a.0.total_cmp(&b.0));
        match above {
            Some((_, l)) => l.points.extend_from_slice(&line.points),
            None => joined.push(line),
        }
    }
    joined
}

/// Column of nominal stripe `k` at height `z` on `row`.
fn nominal_column(model: &FullModel, k: usize, row: u32, z: f64) -> f64 {
    model
        .column_at_height(k, f64::from(row), z)
        .unwrap_or(f64::NAN)
}

/// The middle row of a line (where its column is compared).
fn middle_row(line: &Line) -> u32 {
    line.points[line.points.len() / 2].0
}

/// Mean absolute column error of the lines labelled `first + i` against `predict(k, line)`; `None` when a label
/// falls outside the stripes.
fn fit_error(
    lines: &[Line],
    first: usize,
    stripes: usize,
    mut predict: impl FnMut(usize, &Line) -> f64,
) -> Option<f64> {
    if first + lines.len() > stripes {
        return None;
    }
    let mut sum = 0.0;
    for (i, l) in lines.iter().enumerate() {
        let e = (l.column_near(middle_row(l)) - predict(first + i, l)).abs();
        if !e.is_finite() {
            return None;
        }
        sum += e;
    }
    Some(sum / lines.len() as f64)
}

/// Best and second-best first label under `predict`.
fn best_first(
    lines: &[Line],
    stripes: usize,
    mut predict: impl FnMut(usize, &Line) -> f64,
) -> Option<(usize, f64, f64)> {
    let mut best: Option<(usize, f64)> = None;
    let mut second = f64::INFINITY;
    for first in 0..stripes {
        if let Some(e) = fit_error(lines, first, stripes, &mut predict) {
            match best {
                Some((_, b)) if e >= b => second = second.min(e),
                _ => {
                    if let Some((_, b)) = best {
                        second = second.min(b);
                    }
                    best = Some((first, e));
                }
            }
        }
    }
    best.map(|(f, e)| (f, e, second))
}

/// Calibrates `sensor` from plate images; see the module documentation.
pub fn calibrate(
    sensor: &Sensor,
    images: &[PlaneImage],
    params: &CalibrationParams,
) -> Result<Calibration, CoreError> {
    sensor.validate()?;
    if images.len() < 3 {
        return Err(fail(CalibrationError::TooFewPlates {
            given: images.len(),
        }));
    }
    for im in images {
        if !im.height_mm.is_finite()
            || im.height_mm < 0.0
            || im.height_mm >= sensor.camera.height_mm
        {
            return Err(fail(CalibrationError::HeightOutOfRange {
                image: im.name.clone(),
                height_mm: im.height_mm,
                camera_mm: sensor.camera.height_mm,
            }));
        }
    }
    let mut order: Vec<usize> = (0..images.len()).collect();
    order.sort_by(|&a, &b| images[a].height_mm.total_cmp(&images[b].height_mm));
    for w in order.windows(2) {
        let (a, b) = (&images[w[0]], &images[w[1]]);
        if (b.height_mm - a.height_mm).abs() < 1e-9 {
            return Err(fail(CalibrationError::SameHeight {
                first: a.name.clone(),
                second: b.name.clone(),
                height_mm: a.height_mm,
            }));
        }
    }
    let n = sensor.laser.stripes;
    let rows = sensor.camera.height;
    let nominal = FullModel::nominal(sensor);
    let pitch_px = sensor.laser.pitch_mm * sensor.camera.fx / sensor.camera.height_mm;
    let lines: Vec<Vec<Line>> = order
        .iter()
        .map(|&i| lines_of(&images[i].points, rows, pitch_px, params))
        .collect();
    for (k, &i) in order.iter().enumerate() {
        if lines[k].is_empty() {
            return Err(fail(CalibrationError::NoStripe {
                image: images[i].name.clone(),
            }));
        }
        if lines[k].len() > n {
            return Err(fail(CalibrationError::TooManyLines {
                image: images[i].name.clone(),
                lines: lines[k].len(),
                stripes: n,
            }));
        }
    }
    // Anchor: the image identified most clearly by the nominal geometry.
    let heights: Vec<f64> = order.iter().map(|&i| images[i].height_mm).collect();
    // (image, first label, how clearly it beats the next best first label)
    let mut anchor: Option<(usize, usize, f64)> = None;
    for k in 0..order.len() {
        let z = heights[k];
        let fit = best_first(&lines[k], n, |s, l| {
            nominal_column(&nominal, s, middle_row(l), z)
        });
        if let Some((first, err, second)) = fit {
            let ratio = if lines[k].len() == n {
                f64::INFINITY
            } else {
                second / err.max(1e-9)
            };
            if anchor.is_none_or(|(_, _, r)| ratio > r) {
                anchor = Some((k, first, ratio));
            }
        }
    }
    let Some((a, first_a, _)) = anchor else {
        return Err(fail(CalibrationError::NoImageMatched));
    };
    let mut firsts: Vec<Option<usize>> = vec![None; order.len()];
    firsts[a] = Some(first_a);
    // Propagate to the neighbours in height by continuity.
    let mut sequence: Vec<(usize, usize)> = (a + 1..order.len()).map(|k| (k - 1, k)).collect();
    sequence.extend((0..a).rev().map(|k| (k + 1, k)));
    for (from, to) in sequence {
        let Some(ff) = firsts[from] else { continue };
        let (zf, zt) = (heights[from], heights[to]);
        let src = &lines[from];
        let fit = best_first(&lines[to], n, |s, l| {
            let row = middle_row(l);
            let Some(i) = s.checked_sub(ff).filter(|&i| i < src.len()) else {
                // Not seen at the neighbouring height: the nominal position.
                return nominal_column(&nominal, s, row, zt);
            };
            src[i].column_near(row) + nominal_column(&nominal, s, row, zt)
                - nominal_column(&nominal, s, row, zf)
        });
        let Some((first, err, second)) = fit else {
            return Err(fail(CalibrationError::Unmatched {
                image: images[order[to]].name.clone(),
                from_mm: zf,
            }));
        };
        if err > 0.25 * pitch_px || second < 2.0 * err {
            return Err(fail(CalibrationError::DoesNotFollow {
                image: images[order[to]].name.clone(),
                height_mm: zt,
                from_mm: zf,
                error_px: err,
            }));
        }
        firsts[to] = Some(first);
    }
    // Stripes must move the same way between every pair of heights (swapped images reverse them).
    let middle_column = |k: usize, s: usize| -> Option<f64> {
        let f = firsts[k]?;
        let line = lines[k].get(s.checked_sub(f)?)?;
        Some(line.column_near(rows / 2))
    };
    for s in 0..n {
        let cols: Vec<(usize, f64)> = (0..order.len())
            .filter_map(|k| middle_column(k, s).map(|c| (k, c)))
            .collect();
        let nominal_dir = (nominal_column(&nominal, s, rows / 2, 10.0)
            - nominal_column(&nominal, s, rows / 2, 0.0))
        .signum();
        for w in cols.windows(2) {
            let d = (w[1].1 - w[0].1).signum();
            if d != nominal_dir && (w[1].1 - w[0].1).abs() > 0.5 {
                return Err(fail(CalibrationError::WrongWay {
                    stripe: s,
                    first: images[order[w[0].0]].name.clone(),
                    first_mm: heights[w[0].0],
                    second: images[order[w[1].0]].name.clone(),
                    second_mm: heights[w[1].0],
                }));
            }
        }
    }
    // Points of each stripe: (image index in order, u, v, world point).
    let cam = &sensor.camera;
    let mut per_stripe: Vec<Vec<StripeSample>> = vec![Vec::new(); n];
    for k in 0..order.len() {
        let Some(f) = firsts[k] else { continue };
        for (i, line) in lines[k].iter().enumerate() {
            let s = f + i;
            for &(row, u) in &line.points {
                let v = f64::from(row);
                let t = cam.height_mm - heights[k];
                let d = cam.ray_direction(u, v);
                per_stripe[s].push((k, u, v, cam.centre() + d * t));
            }
        }
    }
    let fit_all = |skip: Option<usize>| -> Result<Vec<Plane>, CoreError> {
        let mut planes = Vec::with_capacity(n);
        for (s, pts) in per_stripe.iter().enumerate() {
            let used: Vec<Vector3<f64>> = pts
                .iter()
                .filter(|p| Some(p.0) != skip)
                .map(|p| p.3)
                .collect();
            let mut seen: Vec<usize> = pts
                .iter()
                .filter(|p| Some(p.0) != skip)
                .map(|p| p.0)
                .collect();
            seen.sort_unstable();
            seen.dedup();
            if seen.len() < 3 {
                return Err(fail(CalibrationError::TooFewHeights {
                    stripe: s,
                    seen_mm: seen.iter().map(|&k| heights[k]).collect(),
                }));
            }
            let (plane, _) =
                fit_plane(&used).ok_or_else(|| fail(CalibrationError::NoPlane { stripe: s }))?;
            planes.push(plane);
        }
        Ok(planes)
    };
    let planes = fit_all(None)?;
    let full = FullModel {
        camera: cam.clone(),
        planes,
    };
    // Residuals per (stripe, image): mean height error; a mislabelled image shows on every stripe it holds.
    let residual_of = |model: &FullModel, k: usize| -> f64 {
        let (mut sum, mut count) = (0.0, 0usize);
        for (s, pts) in per_stripe.iter().enumerate() {
            for p in pts.iter().filter(|p| p.0 == k) {
                if let Some(z) = model.height(s, p.1, p.2) {
                    sum += (z - heights[k]).powi(2);
                    count += 1;
                }
            }
        }
        (sum / count.max(1) as f64).sqrt()
    };
    let worst = (0..order.len())
        .map(|k| (k, residual_of(&full, k)))
        .max_by(|a, b| a.1.total_cmp(&b.1));
    if let Some((k, r)) = worst
        && r > params.max_residual_mm
    {
        // With four heights or more, leave each image out in turn: the image at fault is the one without which the
        // others agree best (and it sits off the planes they define).
        let culprit = if order.len() >= 4 {
            (0..order.len())
                .filter_map(|j| {
                    let planes = fit_all(Some(j)).ok()?;
                    let m = FullModel {
                        camera: cam.clone(),
                        planes,
                    };
                    let others = (0..order.len())
                        .filter(|&k| k != j)
                        .map(|k| residual_of(&m, k))
                        .fold(0.0f64, f64::max);
                    Some((j, others, residual_of(&m, j)))
                })
                .min_by(|a, b| a.1.total_cmp(&b.1))
                .filter(|c| c.1 <= params.max_residual_mm)
                .map(|c| (c.0, c.2))
        } else {
            None
        };
        return Err(match culprit {
            Some((j, rj)) => fail(CalibrationError::ImageOffPlanes {
                image: images[order[j]].name.clone(),
                height_mm: heights[j],
                rms_mm: rj,
                limit_mm: params.max_residual_mm,
            }),
            None => fail(CalibrationError::NoCommonPlanes {
                image: images[order[k]].name.clone(),
                height_mm: heights[k],
                rms_mm: r,
                limit_mm: params.max_residual_mm,
            }),
        });
    }
    // The linear model: height = A(r) - B(r) u, quadratics in r, by least squares per stripe.
    let mut linear = Vec::with_capacity(n);
    let mut reports = Vec::with_capacity(n);
    for (s, pts) in per_stripe.iter().enumerate() {
        let m = pts.len();
        let mut a = DMatrix::<f64>::zeros(m, 6);
        let mut b = DVector::<f64>::zeros(m);
        for (i, p) in pts.iter().enumerate() {
            let r = (p.2 - cam.cy) / cam.fy;
            let basis = [1.0, r, r * r];
            for j in 0..3 {
                a[(i, j)] = basis[j];
                a[(i, 3 + j)] = -basis[j] * p.1;
            }
            b[i] = heights[p.0];
        }
        let x = a.svd(true, true).solve(&b, 1e-12).map_err(|e| {
            fail(CalibrationError::LinearFit {
                stripe: s,
                reason: e.to_string(),
            })
        })?;
        let stripe = LinearStripe {
            a: [x[0], x[1], x[2]],
            b: [x[3], x[4], x[5]],
        };
        let (mut fs, mut fmax, mut ls, mut lmax) = (0.0f64, 0.0f64, 0.0f64, 0.0f64);
        for p in pts {
            let z = heights[p.0];
            let ef = full.height(s, p.1, p.2).map_or(f64::INFINITY, |h| h - z);
            let el = stripe.height(p.1, (p.2 - cam.cy) / cam.fy) - z;
            fs += ef * ef;
            ls += el * el;
            fmax = fmax.max(ef.abs());
            lmax = lmax.max(el.abs());
        }
        let mut seen: Vec<f64> = pts.iter().map(|p| heights[p.0]).collect();
        seen.dedup();
        reports.push(StripeReport {
            stripe: s,
            heights_mm: seen,
            points: m,
            full_rms_mm: (fs / m.max(1) as f64).sqrt(),
            full_max_mm: fmax,
            linear_rms_mm: (ls / m.max(1) as f64).sqrt(),
            linear_max_mm: lmax,
        });
        linear.push(stripe);
    }
    Ok(Calibration {
        full,
        linear: LinearModel {
            cy: cam.cy,
            fy: cam.fy,
            stripes: linear,
        },
        heights_mm: heights,
        stripes: reports,
    })
}

/// The camera a calibration was made with must be the one in use: same image size and intrinsics.
pub fn check_camera(calibrated: &Camera, sensor: &Camera) -> Result<(), CoreError> {
    if calibrated.width != sensor.width || calibrated.height != sensor.height {
        return Err(fail(CalibrationError::ImageSize {
            calibrated: [calibrated.width as usize, calibrated.height as usize],
            sensor: [sensor.width as usize, sensor.height as usize],
        }));
    }
    let close = |a: f64, b: f64| (a - b).abs() <= 1e-6 * (1.0 + a.abs().max(b.abs()));
    for (name, a, b) in [
        ("fx", calibrated.fx, sensor.fx),
        ("fy", calibrated.fy, sensor.fy),
        ("cx", calibrated.cx, sensor.cx),
        ("cy", calibrated.cy, sensor.cy),
        ("k1", calibrated.k1, sensor.k1),
        ("height_mm", calibrated.height_mm, sensor.height_mm),
    ] {
        if !close(a, b) {
            return Err(fail(CalibrationError::CameraDiffers {
                field: name,
                calibrated: a,
                sensor: b,
            }));
        }
    }
    Ok(())
}
