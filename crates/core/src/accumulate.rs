//! Triangulated profiles, and their accumulation over a scan into a point cloud and a range image.
//!
//! A [`Profile`] is one frame's coded stripe points in millimetres, in part coordinates (belt coordinates with the
//! conveyor travel since frame 0 subtracted, `DESIGN.md`). [`RangeGrid::accumulate`] resamples a scan's profiles
//! onto a regular x-y grid: every point lands in its cell, and between the points of one stripe on one image row
//! in consecutive frames (or with one frame missing between them; the same sheet sweeping the part) the surface is
//! interpolated linearly when they are
//! close (at most [`RangeParams::max_fill_mm`] apart along x and [`RangeParams::max_fill_step_mm`] apart in
//! height), so that a grid finer than the travel per frame has no stripes of empty cells. Cells where nothing was
//! measured are NaN.

use crate::CoreError;
use crate::code::Coding;
use crate::extract::StripePoint;
use crate::triangulate::{FullModel, LinearModel};

/// Which triangulation model turns pixels into millimetres.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum ModelKind {
    /// Pinhole camera with distortion and a fitted plane per stripe.
    #[default]
    Full,
    /// The paper's linear model (eq. 3); x and y from the camera ray at that height.
    Linear,
}

impl ModelKind {
    /// The name used on the command line.
    pub fn name(self) -> &'static str {
        match self {
            ModelKind::Full => "full",
            ModelKind::Linear => "linear",
        }
    }
}

/// One triangulated stripe point, part coordinates.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ProfilePoint {
    /// Stripe index.
    pub stripe: u16,
    /// Image row.
    pub row: u32,
    /// Sub-pixel column.
    pub u: f64,
    /// Part x (along travel), mm.
    pub x_mm: f64,
    /// Part y, mm.
    pub y_mm: f64,
    /// Height above the belt, mm.
    pub z_mm: f64,
    /// Peak intensity (grey levels).
    pub intensity: f32,
}

/// One frame, triangulated.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Profile {
    /// Frame index in the scan.
    pub frame: usize,
    /// Conveyor travel since frame 0, mm.
    pub travel_mm: f64,
    /// The frame's coded points, in the order of the extraction.
    pub points: Vec<ProfilePoint>,
}

/// Triangulates the coded points of one frame into `out` (replacing its points).
///
/// `linear` is used only with [`ModelKind::Linear`]; a point the model cannot place (a ray parallel to its plane)
/// is left out.
#[allow(clippy::too_many_arguments)]
pub fn profile_into(
    frame: usize,
    travel_mm: f64,
    points: &[StripePoint],
    coding: &Coding,
    full: &FullModel,
    linear: Option<&LinearModel>,
    kind: ModelKind,
    out: &mut Profile,
) {
    out.frame = frame;
    out.travel_mm = travel_mm;
    out.points.clear();
    let cam = &full.camera;
    for (p, s) in points.iter().zip(&coding.stripes) {
        let Some(s) = *s else { continue };
        let (u, v) = (p.x, f64::from(p.row));
        let world = match (kind, linear) {
            (ModelKind::Linear, Some(lin)) => lin.height(usize::from(s), u, v).map(|z| {
                let d = cam.ray_direction(u, v);
                cam.centre() + d * (cam.height_mm - z)
            }),
            _ => full.point(usize::from(s), u, v),
        };
        let Some(w) = world else { continue };
        out.points.push(ProfilePoint {
            stripe: s,
            row: p.row,
            u,
            x_mm: w.x - travel_mm,
            y_mm: w.y,
            z_mm: w.z,
            intensity: p.intensity,
        });
    }
}

/// Samples of one stripe and row at most this many frames apart are joined (when close enough): a frame in which
/// coding dropped a whole stripe segment leaves no empty column behind.
const MAX_FILL_FRAMES: usize = 2;

/// Parameters of the range grid.
#[derive(Debug, Clone, PartialEq)]
pub struct RangeParams {
    /// Cell size along x and y, mm.
    pub spacing_mm: [f64; 2],
    /// Largest x distance (mm) between consecutive samples of one stripe and row that is interpolated.
    pub max_fill_mm: f64,
    /// Largest height difference (mm) between those samples that is interpolated (edges are not smeared).
    pub max_fill_step_mm: f64,
    /// Largest number of cells of a grid.
    pub max_cells: usize,
}

impl Default for RangeParams {
    fn default() -> Self {
        Self {
            spacing_mm: [0.2, 0.2],
            max_fill_mm: 1.5,
            max_fill_step_mm: 0.3,
            max_cells: 64 << 20,
        }
    }
}

/// A range image: heights on a regular grid, NaN where nothing was measured. Column `i` is at
/// `x = origin_mm[0] + i * spacing_mm[0]`, row `j` at `y = origin_mm[1] - j * spacing_mm[1]` (rows run along −y,
/// as the camera's image does).
#[derive(Debug, Clone, PartialEq)]
pub struct RangeImage {
    /// x of column 0 and y of row 0, mm.
    pub origin_mm: [f64; 2],
    /// Cell size along x and y, mm.
    pub spacing_mm: [f64; 2],
    /// Columns.
    pub width: usize,
    /// Rows.
    pub height: usize,
    /// Heights, row-major, mm.
    pub z: Vec<f32>,
}

impl RangeImage {
    /// Cells that hold a height.
    pub fn measured(&self) -> usize {
        self.z.iter().filter(|z| z.is_finite()).count()
    }

    /// Lowest and highest measured height, mm.
    pub fn z_range(&self) -> Option<(f32, f32)> {
        let mut it = self.z.iter().copied().filter(|z| z.is_finite());
        let first = it.next()?;
        Some(it.fold((first, first), |(lo, hi), z| (lo.min(z), hi.max(z))))
    }

    /// Height at part coordinates (x, y), nearest cell; `None` outside the grid or where nothing was measured.
    pub fn at(&self, x_mm: f64, y_mm: f64) -> Option<f32> {
        let k = cell_index(
            self.origin_mm,
            self.spacing_mm,
            self.width,
            self.height,
            x_mm,
            y_mm,
        )?;
        let z = self.z[k];
        z.is_finite().then_some(z)
    }
}

/// Index of the cell nearest to (x, y) in a grid laid out as [`RangeImage`] describes; `None` outside it.
#[inline]
fn cell_index(
    origin: [f64; 2],
    spacing: [f64; 2],
    width: usize,
    height: usize,
    x: f64,
    y: f64,
) -> Option<usize> {
    // Nearest cell by truncation of the position plus one half: `round` is a library call on the baseline x86-64
    // target and costs more than the rest of the accumulation. Both are non-negative when the comparisons hold.
    let i = (x - origin[0]) / spacing[0] + 0.5;
    let j = (origin[1] - y) / spacing[1] + 0.5;
    // NaN coordinates fail these comparisons too.
    if !(i >= 0.0 && j >= 0.0 && i < width as f64 && j < height as f64) {
        return None;
    }
    Some(j as usize * width + i as usize)
}

/// The grid a scan is accumulated on.
#[derive(Debug, Clone, PartialEq)]
pub struct RangeGrid {
    params: RangeParams,
    origin: [f64; 2],
    width: usize,
    height: usize,
    sum: Vec<f64>,
    count: Vec<u32>,
}

impl RangeGrid {
    /// A grid covering every point of `profiles` with one cell of margin.
    pub fn covering(profiles: &[Profile], params: RangeParams) -> Result<Self, CoreError> {
        let [dx, dy] = params.spacing_mm;
        if !(dx.is_finite() && dy.is_finite() && dx > 0.0 && dy > 0.0) {
            return Err(CoreError::InvalidParameter {
                field: "spacing_mm",
                value: format!("{dx},{dy}"),
                reason: "grid spacing must be positive and finite".into(),
            });
        }
        let mut lo = [f64::INFINITY; 2];
        let mut hi = [f64::NEG_INFINITY; 2];
        for p in profiles.iter().flat_map(|p| &p.points) {
            lo[0] = lo[0].min(p.x_mm);
            lo[1] = lo[1].min(p.y_mm);
            hi[0] = hi[0].max(p.x_mm);
            hi[1] = hi[1].max(p.y_mm);
        }
        if !(lo[0].is_finite() && hi[0].is_finite()) {
            return Err(CoreError::InvalidParameter {
                field: "profiles",
                value: "0 points".into(),
                reason: "nothing was measured in the scan".into(),
            });
        }
        let width = ((hi[0] - lo[0]) / dx).ceil() as usize + 3;
        let height = ((hi[1] - lo[1]) / dy).ceil() as usize + 3;
        if width.saturating_mul(height) > params.max_cells {
            return Err(CoreError::InvalidParameter {
                field: "spacing_mm",
                value: format!("{dx},{dy}"),
                reason: format!(
                    "a {width}x{height} grid is larger than the limit of {} cells; use a coarser grid",
                    params.max_cells
                ),
            });
        }
        let origin = [lo[0] - dx, hi[1] + dy];
        Ok(Self {
            params,
            origin,
            width,
            height,
            sum: vec![0.0; width * height],
            count: vec![0; width * height],
        })
    }

    #[inline]
    fn add(&mut self, x: f64, y: f64, z: f64) {
        let Some(k) = cell_index(
            self.origin,
            self.params.spacing_mm,
            self.width,
            self.height,
            x,
            y,
        ) else {
            return;
        };
        self.sum[k] += z;
        self.count[k] += 1;
    }

    /// Adds the profiles of a scan, in frame order.
    pub fn accumulate(&mut self, profiles: &[Profile]) {
        // Last sample of each (stripe, row): (frame, x, y, z).
        let rows = profiles
            .iter()
            .flat_map(|p| &p.points)
            .map(|p| p.row as usize + 1)
            .max()
            .unwrap_or(0);
        let stripes = profiles
            .iter()
            .flat_map(|p| &p.points)
            .map(|p| usize::from(p.stripe) + 1)
            .max()
            .unwrap_or(0);
        let mut last: Vec<(usize, f64, f64, f64)> =
            vec![(usize::MAX, 0.0, 0.0, 0.0); rows * stripes];
        let dx = self.params.spacing_mm[0];
        for prof in profiles {
            for p in &prof.points {
                let key = usize::from(p.stripe) * rows + p.row as usize;
                let (frame, x0, y0, z0) = last[key];
                if frame != usize::MAX
                    && prof.frame > frame
                    && prof.frame - frame <= MAX_FILL_FRAMES
                    && (p.x_mm - x0).abs() <= self.params.max_fill_mm
                    && (p.z_mm - z0).abs() <= self.params.max_fill_step_mm
                {
                    // Cells strictly between the two samples along x.
                    let (xa, xb) = (x0.min(p.x_mm), x0.max(p.x_mm));
                    // A cell or two more on each side than needed (truncation, not a library `floor`); the test
                    // below keeps exactly those strictly between.
                    let first = ((xa - self.origin[0]) / dx) as i64;
                    let lastc = ((xb - self.origin[0]) / dx) as i64 + 1;
                    for c in first..=lastc {
                        let x = self.origin[0] + c as f64 * dx;
                        if x <= xa || x >= xb {
                            continue;
                        }
                        let t = (x - x0) / (p.x_mm - x0);
                        self.add(x, y0 + t * (p.y_mm - y0), z0 + t * (p.z_mm - z0));
                    }
                }
                self.add(p.x_mm, p.y_mm, p.z_mm);
                last[key] = (prof.frame, p.x_mm, p.y_mm, p.z_mm);
            }
        }
    }

    /// The range image: the mean height of each cell.
    pub fn image(&self) -> RangeImage {
        RangeImage {
            origin_mm: self.origin,
            spacing_mm: self.params.spacing_mm,
            width: self.width,
            height: self.height,
            z: self
                .sum
                .iter()
                .zip(&self.count)
                .map(|(&s, &c)| {
                    if c == 0 {
                        f32::NAN
                    } else {
                        (s / f64::from(c)) as f32
                    }
                })
                .collect(),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn prof(frame: usize, pts: &[(f64, f64, f64)]) -> Profile {
        Profile {
            frame,
            travel_mm: 0.0,
            points: pts
                .iter()
                .map(|&(x, y, z)| ProfilePoint {
                    stripe: 0,
                    row: 7,
                    u: 0.0,
                    x_mm: x,
                    y_mm: y,
                    z_mm: z,
                    intensity: 1.0,
                })
                .collect(),
        }
    }

    #[test]
    fn samples_are_interpolated_along_travel_but_not_across_edges() {
        let profiles = vec![
            prof(0, &[(0.0, 0.0, 1.0)]),
            prof(1, &[(1.0, 0.0, 1.2)]),
            prof(2, &[(2.0, 0.0, 5.0)]),
        ];
        let params = RangeParams {
            spacing_mm: [0.25, 0.25],
            ..RangeParams::default()
        };
        let mut g = RangeGrid::covering(&profiles, params).expect("grid");
        g.accumulate(&profiles);
        let r = g.image();
        assert_eq!(r.at(0.0, 0.0), Some(1.0));
        assert!((r.at(0.5, 0.0).expect("filled") - 1.1).abs() < 1e-6);
        assert_eq!(r.at(1.5, 0.0), None, "a 3.8 mm step is not smeared");
        assert_eq!(r.at(2.0, 0.0), Some(5.0));
        assert_eq!(r.at(50.0, 0.0), None);
        assert_eq!(r.measured(), 1 + 3 + 1 + 1);
    }

    #[test]
    fn empty_scans_and_bad_spacing_are_refused() {
        assert!(RangeGrid::covering(&[], RangeParams::default()).is_err());
        let p = vec![prof(0, &[(0.0, 0.0, 1.0)])];
        let bad = RangeParams {
            spacing_mm: [0.0, 0.1],
            ..RangeParams::default()
        };
        assert!(RangeGrid::covering(&p, bad).is_err());
        let huge = RangeParams {
            spacing_mm: [1e-6, 1e-6],
            ..RangeParams::default()
        };
        let p = vec![prof(0, &[(0.0, 0.0, 1.0), (100.0, 100.0, 1.0)])];
        assert!(RangeGrid::covering(&p, huge).is_err());
    }
}
