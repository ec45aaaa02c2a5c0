//! Surface characterization: what the part should look like (a reference surface), and maps of how it differs —
//! deviation, surface normal, mean and Gaussian curvature — on the range image's grid.
//!
//! The reference comes from one of three places: a robust fit of the part's own top surface ([`fit_reference`]:
//! plane or quadratic, Tukey-biweight iteratively reweighted least squares started at the modal height, so that
//! defects, steps and the belt do not pull it), a golden scan of a good part registered to this one ([`register`]:
//! rigid in x-y and height), or a product's nominal model (the knowledge base). Every source ends as one
//! reference height per cell, NaN where no surface is expected (outside the part, in a designed hole).
//!
//! Derivatives are the coefficients of a local quadratic least-squares fit over a square window (a 2-D
//! Savitzky-Golay filter; on a full square window the fit separates into 1-D kernels). A cell whose window is not
//! complete — it touches missing data, the belt or the part's edge — gets NaN normals and curvature: nothing is
//! smeared across holes and edges.

use crate::CoreError;
use crate::accumulate::{RangeImage, floor_index, index_f64};
use nalgebra::{DMatrix, DVector};

/// What a range cell shows.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum CellClass {
    /// Nothing was measured.
    Missing,
    /// The belt (at or below [`CharacterizeParams::belt_level_mm`]).
    Belt,
    /// The part.
    Part,
}

/// The shape of a fitted reference surface.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum ReferenceShape {
    /// z = a + b x + c y.
    #[default]
    Plane,
    /// A full quadratic in x and y, for gently curved parts.
    Quadratic,
}

impl ReferenceShape {
    /// The name used on the command line and in reports.
    pub fn name(self) -> &'static str {
        match self {
            ReferenceShape::Plane => "plane",
            ReferenceShape::Quadratic => "quadratic",
        }
    }
}

/// Parameters of characterization.
#[derive(Debug, Clone, PartialEq)]
pub struct CharacterizeParams {
    /// Cells at or below this height are the belt, not the part, mm. Half of the thinnest part expected.
    pub belt_level_mm: f64,
    /// Shape of the fitted reference.
    pub shape: ReferenceShape,
    /// Side of the derivative window, mm (rounded to an odd number of cells, at least 3). 1 mm keeps the
    /// curvature noise near 0.03 /mm at 0.007 mm height noise on a 0.22 mm grid while resolving 2 mm defects.
    pub window_mm: f64,
    /// Reweighting rounds of the robust fit.
    pub iterations: usize,
    /// Most cells the robust fit uses (a regular subsample beyond that). 20,000 cells put a plane's height
    /// uncertainty from noise below 0.0001 mm.
    pub max_fit_cells: usize,
}

impl Default for CharacterizeParams {
    fn default() -> Self {
        Self {
            belt_level_mm: 0.5,
            shape: ReferenceShape::Plane,
            window_mm: 1.0,
            iterations: 15,
            max_fit_cells: 20_000,
        }
    }
}

impl CharacterizeParams {
    /// Checks every field.
    pub fn validate(&self) -> Result<(), CoreError> {
        let bad = |field, value: f64, reason: &str| {
            Err(CoreError::InvalidParameter {
                field,
                value: value.to_string(),
                reason: reason.into(),
            })
        };
        if !self.belt_level_mm.is_finite() {
            return bad("belt_level_mm", self.belt_level_mm, "must be finite");
        }
        if !(self.window_mm.is_finite() && self.window_mm > 0.0 && self.window_mm <= 20.0) {
            return bad(
                "window_mm",
                self.window_mm,
                "must be above 0 and at most 20 mm",
            );
        }
        if self.max_fit_cells < 10 {
            return bad(
                "max_fit_cells",
                self.max_fit_cells as f64,
                "must be at least 10",
            );
        }
        Ok(())
    }
}

/// Classifies every cell of a range image.
pub fn classify(range: &RangeImage, belt_level_mm: f64) -> Vec<CellClass> {
    range
        .z
        .iter()
        .map(|&z| {
            if !z.is_finite() {
                CellClass::Missing
            } else if f64::from(z) <= belt_level_mm {
                CellClass::Belt
            } else {
                CellClass::Part
            }
        })
        .collect()
}

/// A fitted reference surface.
#[derive(Debug, Clone, PartialEq)]
pub struct Reference {
    /// Plane or quadratic.
    pub shape: ReferenceShape,
    /// Coordinates are taken relative to this point (conditioning), mm.
    pub centre_mm: [f64; 2],
    /// a, b, c (plane) then d, e, f: z = a + b x' + c y' + d x'² + e x'y' + f y'², x' = (x − centre) / 10 mm.
    pub coefficients: [f64; 6],
    /// Robust standard deviation of the part's heights about the reference, mm.
    pub sigma_mm: f64,
    /// Share of the part's cells within 3 sigma of the reference (the rest: defects, features, outliers).
    pub inlier_share: f64,
}

/// Coordinates are scaled by this before fitting, mm.
const FIT_SCALE_MM: f64 = 10.0;

impl Reference {
    fn terms(&self, x: f64, y: f64) -> [f64; 6] {
        let (u, v) = (
            (x - self.centre_mm[0]) / FIT_SCALE_MM,
            (y - self.centre_mm[1]) / FIT_SCALE_MM,
        );
        [1.0, u, v, u * u, u * v, v * v]
    }

    /// Reference height at (x, y), mm.
    pub fn height(&self, x_mm: f64, y_mm: f64) -> f64 {
        self.terms(x_mm, y_mm)
            .iter()
            .zip(&self.coefficients)
            .map(|(t, c)| t * c)
            .sum()
    }

    /// The reference height of every cell of `range` (defined everywhere: the fitted surface has no outline).
    pub fn heights(&self, range: &RangeImage) -> Vec<f32> {
        let mut out = Vec::with_capacity(range.z.len());
        for j in 0..range.height {
            for i in 0..range.width {
                let (x, y) = cell_xy(range, i, j);
                out.push(self.height(x, y) as f32);
            }
        }
        out
    }
}

/// Part coordinates of cell (i, j), mm.
#[inline]
pub fn cell_xy(range: &RangeImage, i: usize, j: usize) -> (f64, f64) {
    (
        range.origin_mm[0] + index_f64(i) * range.spacing_mm[0],
        range.origin_mm[1] - index_f64(j) * range.spacing_mm[1],
    )
}

/// Cells between the samples of the noise estimate of [`surface_maps`].
const NOISE_STRIDE: usize = 7;

/// Mean of the finite values of each cell's 3 x 3 window, where the cell itself is finite and at least 5 of the 9
/// are (NaN elsewhere). Separable: sums and counts along rows, then along columns.
pub(crate) fn smooth3(w: usize, h: usize, v: &[f32]) -> Vec<f32> {
    let mut rs = vec![0.0f32; w * h];
    let mut rc = vec![0u8; w * h];
    for j in 0..h {
        let line = &v[j * w..(j + 1) * w];
        for i in 0..w {
            let (mut s, mut c) = (0.0f32, 0u8);
            for &d in &line[i.saturating_sub(1)..(i + 2).min(w)] {
                if d.is_finite() {
                    s += d;
                    c += 1;
                }
            }
            rs[j * w + i] = s;
            rc[j * w + i] = c;
        }
    }
    let mut out = vec![f32::NAN; w * h];
    for j in 0..h {
        let (a, b) = (j.saturating_sub(1), (j + 2).min(h));
        for i in 0..w {
            let (mut s, mut c) = (0.0f32, 0u8);
            for jj in a..b {
                s += rs[jj * w + i];
                c += rc[jj * w + i];
            }
            if c >= 5 && v[j * w + i].is_finite() {
                out[j * w + i] = s / f32::from(c);
            }
        }
    }
    out
}

/// Median of a slice (reorders it); NaN when empty.
pub(crate) fn median(v: &mut [f64]) -> f64 {
    if v.is_empty() {
        return f64::NAN;
    }
    let mid = v.len() / 2;
    let (_, m, _) = v.select_nth_unstable_by(mid, f64::total_cmp);
    *m
}

/// Fits the part's top surface robustly: every part cell (above the belt level) votes, defects and raised or
/// lowered features are down-weighted to nothing by the Tukey biweight, and the fit starts at the most common
/// height so that it settles on the largest surface of the part.
pub fn fit_reference(
    range: &RangeImage,
    params: &CharacterizeParams,
) -> Result<Reference, CoreError> {
    params.validate()?;
    let class = classify(range, params.belt_level_mm);
    let part: Vec<usize> = (0..class.len())
        .filter(|&k| class[k] == CellClass::Part)
        .collect();
    let needed = match params.shape {
        ReferenceShape::Plane => 3,
        ReferenceShape::Quadratic => 6,
    };
    if part.len() < needed.max(20) {
        return Err(CoreError::Inspection {
            message: format!(
                "the range image shows no part: {} of {} cells are above the belt level of {} mm (at least 20 are \
                 needed to fit a reference surface); check that the part was in view and that the scan worked",
                part.len(),
                range.z.len(),
                params.belt_level_mm
            ),
        });
    }
    let stride = part.len().div_ceil(params.max_fit_cells).max(1);
    let sample: Vec<(f64, f64, f64)> = part
        .iter()
        .step_by(stride)
        .map(|&k| {
            let (x, y) = cell_xy(range, k % range.width, k / range.width);
            (x, y, f64::from(range.z[k]))
        })
        .collect();
    let n = sample.len() as f64;
    let centre = [
        sample.iter().map(|s| s.0).sum::<f64>() / n,
        sample.iter().map(|s| s.1).sum::<f64>() / n,
    ];
    // Start at the modal height (0.1 mm bins).
    let (lo, hi) = sample
        .iter()
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), s| {
            (a.min(s.2), b.max(s.2))
        });
    const BIN_MM: f64 = 0.1;
    let bins = (((hi - lo) / BIN_MM) as usize + 1).min(100_000);
    let mut hist = vec![0u32; bins];
    for s in &sample {
        let b = (((s.2 - lo) / BIN_MM) as usize).min(bins - 1);
        hist[b] += 1;
    }
    let mode_bin = (0..bins).max_by_key(|&b| hist[b]).unwrap_or(0);
    let mut r = Reference {
        shape: params.shape,
        centre_mm: centre,
        coefficients: [
            lo + (mode_bin as f64 + 0.5) * BIN_MM,
            0.0,
            0.0,
            0.0,
            0.0,
            0.0,
        ],
        sigma_mm: f64::NAN,
        inlier_share: 0.0,
    };
    let mut resid: Vec<f64> = Vec::with_capacity(sample.len());
    // The first round trusts only heights near the mode; later rounds use the residuals' own spread.
    let mut scale = 1.0;
    for round in 0..params.iterations {
        resid.clear();
        resid.extend(sample.iter().map(|s| (s.2 - r.height(s.0, s.1)).abs()));
        let mut abs = resid.clone();
        let mad = median(&mut abs) * 1.4826;
        if round > 0 {
            scale = mad.max(0.002);
        }
        let c = 4.685 * scale;
        let mut ata = DMatrix::<f64>::zeros(needed, needed);
        let mut atb = DVector::<f64>::zeros(needed);
        let mut used = 0usize;
        for (s, &e) in sample.iter().zip(&resid) {
            if e >= c {
                continue;
            }
            let w = (1.0 - (e / c).powi(2)).powi(2);
            let t = r.terms(s.0, s.1);
            for a in 0..needed {
                atb[a] += w * t[a] * s.2;
                for b in 0..needed {
                    ata[(a, b)] += w * t[a] * t[b];
                }
            }
            used += 1;
        }
        if used < needed * 3 {
            break;
        }
        let Some(sol) = ata.lu().solve(&atb) else {
            break;
        };
        let mut next = r.coefficients;
        for (a, v) in sol.iter().enumerate() {
            next[a] = *v;
        }
        let change = next
            .iter()
            .zip(&r.coefficients)
            .map(|(a, b)| (a - b).abs())
            .fold(0.0, f64::max);
        r.coefficients = next;
        if round > 2 && change < 1e-6 {
            break;
        }
    }
    resid.clear();
    resid.extend(sample.iter().map(|s| (s.2 - r.height(s.0, s.1)).abs()));
    let mut abs = resid.clone();
    r.sigma_mm = median(&mut abs) * 1.4826;
    let lim = 3.0 * r.sigma_mm.max(0.002);
    r.inlier_share = resid.iter().filter(|&&e| e <= lim).count() as f64 / n;
    if !r.coefficients.iter().all(|c| c.is_finite()) {
        return Err(CoreError::Inspection {
            message: "the reference surface fit did not converge (degenerate part shape)".into(),
        });
    }
    Ok(r)
}

/// Where a scan sits on a golden scan: a point (x, y) of the scan is at
/// `R(theta) (x − cx, y − cy) + (cx + dx, cy + dy)` on the golden part, and the scan is `dz` higher.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Registration {
    /// Shift along x, mm.
    pub dx_mm: f64,
    /// Shift along y, mm.
    pub dy_mm: f64,
    /// Rotation about z, rad (counter-clockwise seen from above).
    pub theta_rad: f64,
    /// Height offset of the scan above the golden part, mm.
    pub dz_mm: f64,
    /// Centre of rotation (the scan part's centre), mm.
    pub centre_mm: [f64; 2],
    /// Mean height difference after registration (each cell clipped at 1 mm, cells off the golden part count
    /// 1 mm), mm.
    pub mean_difference_mm: f64,
    /// Share of the scan's part cells that land on the golden part.
    pub overlap: f64,
}

impl Registration {
    /// Golden-part coordinates of scan point (x, y).
    pub fn map(&self, x: f64, y: f64) -> (f64, f64) {
        self.mapper()(x, y)
    }

    /// [`Registration::map`] with the rotation's sine and cosine computed once, for loops over many points.
    fn mapper(&self) -> impl Fn(f64, f64) -> (f64, f64) + use<> {
        let (c, s) = (self.theta_rad.cos(), self.theta_rad.sin());
        let ([cx, cy], dx, dy) = (self.centre_mm, self.dx_mm, self.dy_mm);
        move |x, y| {
            let (u, v) = (x - cx, y - cy);
            (c * u - s * v + cx + dx, s * u + c * v + cy + dy)
        }
    }

    /// [`Registration::map`] straight to `golden`'s grid: the fractional cell indices ([`grid_coords`]) of the golden
    /// point of the scan point at (u, v) mm from the registration's centre. One affine map, without the two
    /// divisions per point that mapping and then converting costs (the per-cell loops of the golden inspection
    /// and the registration's cost are made of these).
    fn grid_mapper(&self, golden: &RangeImage) -> impl Fn(f64, f64) -> (f64, f64) + use<> {
        let (c, s) = (self.theta_rad.cos(), self.theta_rad.sin());
        let ([cx, cy], dx, dy) = (self.centre_mm, self.dx_mm, self.dy_mm);
        let (rx, ry) = (1.0 / golden.spacing_mm[0], 1.0 / golden.spacing_mm[1]);
        let (a, b, k) = (c * rx, -s * rx, (cx + dx - golden.origin_mm[0]) * rx);
        let (d, e, l) = (-s * ry, -c * ry, (golden.origin_mm[1] - cy - dy) * ry);
        move |u, v| (a * u + b * v + k, d * u + e * v + l)
    }

    /// The golden heights (plus the height offset) at every cell of `scan`; NaN where the golden scan shows no
    /// part (outside it, in its holes) or has no data.
    ///
    /// On a wall of the golden part — where its heights around the point span more than [`GOLDEN_WALL_MM`] — the
    /// reference is the scan's own height wherever that lies within the span: there a cell's height depends on
    /// exactly where the wall is, which neither scan pins down to a cell (each codes a slightly different piece of a
    /// boss's rim; a cell compared across them is off by millimetres), so only a height outside everything the
    /// golden part shows around the point is a deviation. "Around" is the bilinear neighbourhood and one cell beyond
    /// it along y (the stripes' direction, sampled every image row), and along x (the conveyor's travel) one
    /// `travel_step_mm` beyond it ([`wall_reach_cells`]): the last sample before a wall lies anywhere up to a step
    /// short of it, so two scans can put the same wall a step apart in the grid. (Traced on the demo part rendered
    /// with seed 3: its boss's rim 0.4 mm further in than the golden scan's, a 2.4 mm² "anomaly" 3.7 mm deep with a
    /// one-cell reach.) Elsewhere the reference is the height itself when it lies within the golden heights
    /// [`GOLDEN_REGISTRATION_TOLERANCE_MM`] around the point, and the nearest of them otherwise.
    pub fn heights(
        &self,
        scan: &RangeImage,
        golden: &RangeImage,
        belt_level_mm: f64,
        travel_step_mm: Option<f64>,
    ) -> Vec<f32> {
        let reach = wall_reach_cells(golden, travel_step_mm);
        self.heights_with(scan, golden, &SpanMap::new(golden, belt_level_mm, reach))
    }

    /// [`Registration::heights`] with the golden scan's span map made already.
    ///
    /// Two passes: the golden heights are resampled onto the scan's grid first (one bilinear sample per cell), and
    /// the tolerance band's four samples, [`GOLDEN_REGISTRATION_TOLERANCE_MM`] along the scan's rows and columns,
    /// are read from that map (linear between two of its cells) instead of four more bilinear samples of the
    /// golden scan each (the band's samples were two thirds of the golden inspection's reference cost). The band is
    /// then turned by the registration's rotation (at most hundredths of a radian: thousandths of a millimetre) and
    /// its samples are smoothed once more by the resampling; the demo's report is the same to 0.001 mm.
    fn heights_with(&self, scan: &RangeImage, golden: &RangeImage, spans: &SpanMap) -> Vec<f32> {
        let floor = spans.floor_mm;
        let (w, h) = (scan.width, scan.height);
        let to_grid = self.grid_mapper(golden);
        let [cx, cy] = self.centre_mm;
        let mut reference = Vec::with_capacity(w * h);
        for j in 0..h {
            for i in 0..w {
                let (x, y) = cell_xy(scan, i, j);
                let (fi, fj) = to_grid(x - cx, y - cy);
                reference.push(
                    bilinear_cell(golden, fi, fj, floor).map_or(f64::NAN, |z| z + self.dz_mm),
                );
            }
        }
        // The band's four samples, +d and -d mm along x (the rows), then +d and -d along y (j decreasing first):
        // each a cell step and a fraction towards the next cell.
        let d = GOLDEN_REGISTRATION_TOLERANCE_MM;
        let step = |cells: f64| {
            let n = cells.floor();
            (n as isize, cells - n)
        };
        let (di, dj) = (d / scan.spacing_mm[0], d / scan.spacing_mm[1]);
        let band = [
            (step(di), 1isize),
            (step(-di), 1),
            (step(-dj), w as isize),
            (step(dj), w as isize),
        ];
        let mut out = Vec::with_capacity(w * h);
        for j in 0..h {
            for i in 0..w {
                let k = j * w + i;
                let r = reference[k];
                if r.is_nan() {
                    out.push(f32::NAN);
                    continue;
                }
                let z = f64::from(scan.z[k]);
                if !z.is_finite() {
                    out.push(r as f32);
                    continue;
                }
                let (x, y) = cell_xy(scan, i, j);
                let (fi, fj) = to_grid(x - cx, y - cy);
                let wall = spans
                    .at(golden, fi, fj)
                    .filter(|(lo, hi)| hi - lo > GOLDEN_WALL_MM);
                out.push(match wall {
                    Some((lo, hi)) => z.clamp(lo + self.dz_mm, hi + self.dz_mm) as f32,
                    // Elsewhere the golden heights within the registration's tolerance of the point: the height
                    // itself when one of them reaches it, else the nearest of them. (The samples are taken one by
                    // one and the first that reaches it ends the search: the same value as clamping to their span.)
                    None => {
                        let above = z >= r;
                        let mut nearest = r;
                        for ((n, f), stride) in band {
                            // Cells k + n * stride and the next one along the same row or column, both inside.
                            let along = if stride == 1 { i } else { j } as isize;
                            let len = if stride == 1 { w } else { h } as isize;
                            if along + n < 0 || along + n + 1 >= len {
                                continue;
                            }
                            let a = (k as isize + n * stride) as usize;
                            let g = (1.0 - f) * reference[a] + f * reference[a + stride as usize];
                            if !g.is_finite() {
                                continue;
                            }
                            if (above && g >= z) || (!above && g <= z) {
                                nearest = z;
                                break;
                            }
                            nearest = if above {
                                nearest.max(g)
                            } else {
                                nearest.min(g)
                            };
                        }
                        nearest as f32
                    }
                });
            }
        }
        out
    }
}

/// Least height span of a golden scan around a point that makes it a wall there ([`Registration::heights`]), mm. A
/// dent or bump the inspection measures (slopes up to about 0.3) rises a few tenths of a millimetre over the four
/// cells the span is taken over along y (0.9 mm at the default 0.22 mm cell; along x it is taken over a travel step
/// more on each side, where such a slope can reach 1 mm only on the steepest small bumps, whose tops stay outside
/// their own span); a boss's or a step's side spans millimetres.
pub const GOLDEN_WALL_MM: f64 = 1.0;

/// Cells beyond the bilinear neighbourhood along x that the golden wall span covers ([`Registration::heights`]): a
/// travel step's worth (rounded up), at least one.
pub fn wall_reach_cells(golden: &RangeImage, travel_step_mm: Option<f64>) -> usize {
    let cells = travel_step_mm.map_or(1.0, |s| (s / golden.spacing_mm[0]).ceil());
    if cells.is_finite() {
        cells.clamp(1.0, 64.0) as usize
    } else {
        1
    }
}

/// How far (mm) from where the registration maps a point the golden heights still count as its reference
/// ([`Registration::heights`]): a part's outline pins the registration down to a fraction of a cell, and two scans
/// that code slightly different points move it by as much (0.05-0.1 mm at the demo part's far edge); on a slope
/// that is a height difference (0.05 mm on the demo's 0.6 chamfer) no part has. A height within the golden heights
/// this far around the point deviates by nothing; on flat surfaces the band is the noise's width.
pub const GOLDEN_REGISTRATION_TOLERANCE_MM: f64 = 0.15;

/// The least and greatest part height (above `floor_mm`) of the cells around the point at fractional cell indices
/// (fi, fj) ([`grid_coords`]) — the bilinear neighbourhood and `reach` cells beyond it along x, one along y (4 x 4
/// cells with a reach of 1); `None` when none holds one.
fn local_span(
    range: &RangeImage,
    fi: f64,
    fj: f64,
    floor_mm: f64,
    reach: usize,
) -> Option<(f64, f64)> {
    let (fi, fj) = (fi.floor(), fj.floor());
    if !(fi.is_finite() && fj.is_finite()) {
        return None;
    }
    let r = reach as i32;
    let (mut lo, mut hi) = (f64::INFINITY, f64::NEG_INFINITY);
    for dj in -1..=2 {
        for di in -r..=1 + r {
            let (i, j) = (fi + f64::from(di), fj + f64::from(dj));
            if i < 0.0 || j < 0.0 || i >= range.width as f64 || j >= range.height as f64 {
                continue;
            }
            let v = f64::from(range.z[j as usize * range.width + i as usize]);
            if v > floor_mm {
                lo = lo.min(v);
                hi = hi.max(v);
            }
        }
    }
    (lo <= hi).then_some((lo, hi))
}

/// `out[i]` = `f` over `vals[i..i + len]` (f a minimum or maximum), by doubling: after the passes with widths 1, 2,
/// 4, ... up to `len`, entry i holds `f` over `vals[i..i + width]`, and two such windows cover `len`. Each pass is
/// one comparison per cell over whole slices (vectorised); `a` and `b` are scratch.
fn sliding(
    vals: &[f32],
    len: usize,
    f: impl Fn(f32, f32) -> f32 + Copy,
    (a, b): (&mut Vec<f32>, &mut Vec<f32>),
    out: &mut [f32],
) {
    a.clear();
    a.extend_from_slice(vals);
    let mut width = 1;
    while 2 * width <= len {
        b.clear();
        b.extend(a.iter().zip(&a[width..]).map(|(&x, &y)| f(x, y)));
        std::mem::swap(a, b);
        width *= 2;
    }
    for ((o, &x), &y) in out.iter_mut().zip(a.iter()).zip(&a[len - width..]) {
        *o = f(x, y);
    }
}

/// [`local_span`] of every cell of a range image, computed once (a minimum and maximum over the window, separably):
/// the span around (x, y) is the entry of the cell that holds it.
#[derive(Debug, Clone)]
struct SpanMap {
    lo: Vec<f32>,
    hi: Vec<f32>,
    floor_mm: f64,
    reach: usize,
}

impl SpanMap {
    fn new(range: &RangeImage, floor_mm: f64, reach: usize) -> Self {
        let (w, h) = (range.width, range.height);
        // Along rows: cells i-reach..=i+1+reach; then along columns: rows j-1..=j+2 of those. Cells without a part
        // height (NaN, the belt) enter as +inf to the minimum and -inf to the maximum, so that both are plain
        // comparisons (which vectorise; `f32::min` with its NaN rule does not).
        let (mn, mx) = (
            |a: f32, b: f32| if a < b { a } else { b },
            |a: f32, b: f32| if a > b { a } else { b },
        );
        let (mut row_lo, mut row_hi) = (vec![f32::INFINITY; w * h], vec![f32::NEG_INFINITY; w * h]);
        // One row, padded with `reach` empty cells before it and 1 + `reach` after it.
        let len = 2 * reach + 2;
        let (mut pad_lo, mut pad_hi) = (
            vec![f32::INFINITY; w + len - 1],
            vec![f32::NEG_INFINITY; w + len - 1],
        );
        let mut scratch = (Vec::new(), Vec::new());
        for j in 0..h {
            for (i, &v) in range.z[j * w..(j + 1) * w].iter().enumerate() {
                let part = f64::from(v) > floor_mm;
                pad_lo[i + reach] = if part { v } else { f32::INFINITY };
                pad_hi[i + reach] = if part { v } else { f32::NEG_INFINITY };
            }
            let (out_lo, out_hi) = (
                &mut row_lo[j * w..(j + 1) * w],
                &mut row_hi[j * w..(j + 1) * w],
            );
            sliding(&pad_lo, len, mn, (&mut scratch.0, &mut scratch.1), out_lo);
            sliding(&pad_hi, len, mx, (&mut scratch.0, &mut scratch.1), out_hi);
        }
        let window = |k: usize, n: usize| k.saturating_sub(1)..(k + 3).min(n);
        let (mut lo, mut hi) = (vec![f32::INFINITY; w * h], vec![f32::NEG_INFINITY; w * h]);
        for j in 0..h {
            let (out_lo, out_hi) = (&mut lo[j * w..(j + 1) * w], &mut hi[j * w..(j + 1) * w]);
            for jj in window(j, h) {
                let (src_lo, src_hi) =
                    (&row_lo[jj * w..(jj + 1) * w], &row_hi[jj * w..(jj + 1) * w]);
                for (o, &v) in out_lo.iter_mut().zip(src_lo) {
                    *o = mn(*o, v);
                }
                for (o, &v) in out_hi.iter_mut().zip(src_hi) {
                    *o = mx(*o, v);
                }
            }
        }
        Self {
            lo,
            hi,
            floor_mm,
            reach,
        }
    }

    /// The span around fractional cell indices (fi, fj) of `range` (the one the map was made of).
    fn at(&self, range: &RangeImage, fi: f64, fj: f64) -> Option<(f64, f64)> {
        if !(fi >= 0.0 && fj >= 0.0 && fi < index_f64(range.width) && fj < index_f64(range.height))
        {
            return local_span(range, fi, fj, self.floor_mm, self.reach);
        }
        // Truncation is the floor here.
        let k = floor_index(fj) * range.width + floor_index(fi);
        let (lo, hi) = (self.lo[k], self.hi[k]);
        (lo <= hi).then_some((f64::from(lo), f64::from(hi)))
    }
}

/// Bilinear height at (x, y): `None` unless all four surrounding cells hold a height.
pub fn bilinear(range: &RangeImage, x: f64, y: f64) -> Option<f64> {
    bilinear_above(range, x, y, f64::NEG_INFINITY)
}

/// Bilinear height at (x, y): `None` unless all four surrounding cells hold a height above `floor_mm` (the part,
/// not the belt: a value interpolated between the part and the belt is neither).
pub fn bilinear_above(range: &RangeImage, x: f64, y: f64, floor_mm: f64) -> Option<f64> {
    let (fi, fj) = grid_coords(range, x, y);
    bilinear_cell(range, fi, fj, floor_mm)
}

/// Fractional cell indices (i, j) of part point (x, y) on `range`'s grid (cell centres at integers; [`cell_xy`]
/// inverted).
#[inline]
fn grid_coords(range: &RangeImage, x: f64, y: f64) -> (f64, f64) {
    (
        (x - range.origin_mm[0]) / range.spacing_mm[0],
        (range.origin_mm[1] - y) / range.spacing_mm[1],
    )
}

/// [`bilinear_above`] at fractional cell indices.
#[inline]
fn bilinear_cell(range: &RangeImage, fi: f64, fj: f64, floor_mm: f64) -> Option<f64> {
    // (The conversions truncate, which for these non-negative values is the floor, without a libm call.)
    if !(fi >= 0.0
        && fj >= 0.0
        && fi + 1.0 < index_f64(range.width)
        && fj + 1.0 < index_f64(range.height))
    {
        return None;
    }
    let (i, j) = (floor_index(fi), floor_index(fj));
    let (a, b) = (fi - index_f64(i), fj - index_f64(j));
    let at = |i: usize, j: usize| f64::from(range.z[j * range.width + i]);
    let (z00, z10, z01, z11) = (at(i, j), at(i + 1, j), at(i, j + 1), at(i + 1, j + 1));
    // NaN fails the comparison too.
    if !(z00 > floor_mm && z10 > floor_mm && z01 > floor_mm && z11 > floor_mm) {
        return None;
    }
    let z = (1.0 - b) * ((1.0 - a) * z00 + a * z10) + b * ((1.0 - a) * z01 + a * z11);
    z.is_finite().then_some(z)
}

/// Parameters of golden-scan registration.
#[derive(Debug, Clone, PartialEq)]
pub struct RegisterParams {
    /// Largest shift searched along x and y around the match of the parts' centroids, mm.
    pub search_mm: f64,
    /// Largest rotation searched, rad.
    pub search_rad: f64,
    /// Belt level, mm (cells below are not the part).
    pub belt_level_mm: f64,
    /// Least share of the scan's part that must land on the golden part.
    pub min_overlap: f64,
}

impl Default for RegisterParams {
    fn default() -> Self {
        Self {
            search_mm: 5.0,
            search_rad: 0.02,
            belt_level_mm: 0.5,
            min_overlap: 0.6,
        }
    }
}

/// Coarse registration candidates rated on the whole coarse sample after a first rating on a quarter of it
/// ([`coarse_search`]).
const COARSE_SHORTLIST: usize = 8;

/// Robust cost of a registration over sample points (u, v, z), (u, v) mm from the registration's centre: the mean
/// absolute height difference after the median offset, each clipped at 1 mm, with points off the golden part counted
/// as 1 mm off. Returns (cost, dz, overlap).
fn registration_cost(
    golden: &RangeImage,
    sample: &[(f64, f64, f64)],
    r: &Registration,
    belt: f64,
    scratch: &mut Vec<f64>,
) -> (f64, f64, f64) {
    scratch.clear();
    let mut off = 0usize;
    let to_grid = r.grid_mapper(golden);
    for &(u, v, z) in sample {
        let (fi, fj) = to_grid(u, v);
        match bilinear_cell(golden, fi, fj, belt) {
            Some(g) => scratch.push(z - g),
            None => off += 1,
        }
    }
    let on = scratch.len();
    if on == 0 {
        return (f64::INFINITY, 0.0, 0.0);
    }
    let dz = median(scratch);
    // The clipped deviations, then 1 mm for every point off the golden part (summed in that order, without a
    // vector of them).
    let mut total = scratch.iter().map(|d| (d - dz).abs().min(1.0)).sum::<f64>();
    for _ in 0..off {
        total += 1.0;
    }
    let cost = total / (on + off) as f64;
    (cost, dz, on as f64 / sample.len() as f64)
}

/// The coarse registration search: 1 mm shifts around `start` (the centroids' match) up to the search's reach,
/// rotations in 0.01 rad steps, the one of least [`registration_cost`] on `sample` (`start` itself on a tie). Every
/// candidate is rated on a quarter of the sample first and the `shortlist` best are rated again on all of it: the
/// search's cost was its 605 ratings on 1,500 cells, and a candidate that loses on 375 of them to eight others is not
/// the best (unit-tested against the full search).
fn coarse_search(
    golden: &RangeImage,
    sample: &[(f64, f64, f64)],
    start: Registration,
    params: &RegisterParams,
    shortlist: usize,
    scratch: &mut Vec<f64>,
) -> Registration {
    let belt = params.belt_level_mm;
    let steps = (params.search_mm / 1.0).ceil() as i32;
    let rsteps = (params.search_rad / 0.01).ceil() as i32;
    let mut candidates = Vec::new();
    for it in -rsteps..=rsteps {
        for iy in -steps..=steps {
            for ix in -steps..=steps {
                candidates.push(Registration {
                    dx_mm: start.dx_mm + f64::from(ix),
                    dy_mm: start.dy_mm + f64::from(iy),
                    theta_rad: f64::from(it) * 0.01,
                    ..start
                });
            }
        }
    }
    let quarter: Vec<(f64, f64, f64)> = sample.iter().copied().step_by(4).collect();
    let mut rated: Vec<(f64, usize)> = candidates
        .iter()
        .enumerate()
        .map(|(k, r)| (registration_cost(golden, &quarter, r, belt, scratch).0, k))
        .collect();
    if rated.len() > shortlist {
        rated.select_nth_unstable_by(shortlist, |a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
        rated.truncate(shortlist);
    }
    // In the grid's order, so that ties go as the full search's would.
    rated.sort_by_key(|&(_, k)| k);
    let mut best = start;
    let mut best_cost = registration_cost(golden, sample, &start, belt, scratch).0;
    for &(_, k) in &rated {
        let c = registration_cost(golden, sample, &candidates[k], belt, scratch).0;
        if c < best_cost {
            best_cost = c;
            best = candidates[k];
        }
    }
    best
}

/// Registers a scan to a golden scan of a good part: a coarse search over shifts (and small rotations), then
/// refinement by halving steps, minimising the mean clipped height difference (a surface-to-surface match that
/// edges, steps and holes drive and that a few defects cannot pull).
pub fn register(
    scan: &RangeImage,
    golden: &RangeImage,
    params: &RegisterParams,
) -> Result<Registration, CoreError> {
    let belt = params.belt_level_mm;
    // The part's cells (above the belt), in row order, without a vector of them all: their count and centroid,
    // then every k-th of them as the samples. Cells as (i, j, height), row by row (no division of a flat index
    // per cell; each a 64-bit division, the pass's largest cost), and their coordinates only where used.
    fn part_cells(r: &RangeImage, belt: f64) -> impl Iterator<Item = (usize, usize, f64)> + '_ {
        r.z.chunks(r.width.max(1))
            .enumerate()
            .flat_map(move |(j, row)| {
                row.iter().enumerate().filter_map(move |(i, &z)| {
                    let z = f64::from(z);
                    (z > belt).then_some((i, j, z))
                })
            })
    }
    let centroid = |r: &RangeImage| {
        let (mut n, mut sx, mut sy) = (0usize, 0.0, 0.0);
        for (i, j, _) in part_cells(r, belt) {
            let (x, y) = cell_xy(r, i, j);
            n += 1;
            sx += x;
            sy += y;
        }
        (n, [sx / n as f64, sy / n as f64])
    };
    let (count, centre) = centroid(scan);
    let (golden_part, gcentre) = centroid(golden);
    if count < 20 || golden_part < 20 {
        return Err(CoreError::Inspection {
            message: format!(
                "cannot register to the golden scan: the scan shows {} part cells and the golden scan {} (at least 20 \
                 each are needed)",
                count, golden_part
            ),
        });
    }
    // The samples as offsets from the centre of rotation, which every candidate shares.
    let from_centre = |(i, j, z)| {
        let (x, y) = cell_xy(scan, i, j);
        (x - centre[0], y - centre[1], z)
    };
    let coarse: Vec<(f64, f64, f64)> = part_cells(scan, belt)
        .step_by((count / 1500).max(1))
        .map(from_centre)
        .collect();
    // 10,000 cells for the refinement (was 40,000: the same registration to within 0.03 mm on the demo, which the
    // golden reference's tolerance band absorbs, in half the time; `cargo bench --bench inspect`).
    let fine: Vec<(f64, f64, f64)> = part_cells(scan, belt)
        .step_by((count / 10_000).max(1))
        .map(from_centre)
        .collect();
    let mut scratch = Vec::new();
    let mut best = Registration {
        dx_mm: gcentre[0] - centre[0],
        dy_mm: gcentre[1] - centre[1],
        theta_rad: 0.0,
        dz_mm: 0.0,
        centre_mm: centre,
        mean_difference_mm: f64::NAN,
        overlap: 0.0,
    };
    let start = best;
    best = coarse_search(
        golden,
        &coarse,
        start,
        params,
        COARSE_SHORTLIST,
        &mut scratch,
    );
    // Refine: pattern search with halving steps on the fine sample.
    let mut step = [0.5, 0.5, 0.005];
    let mut best_cost = registration_cost(golden, &fine, &best, belt, &mut scratch).0;
    while step[0] > 0.002 {
        let mut improved = false;
        for (d, sgn) in [
            (0, 1.0),
            (0, -1.0),
            (1, 1.0),
            (1, -1.0),
            (2, 1.0),
            (2, -1.0),
        ] {
            let mut r = best;
            match d {
                0 => r.dx_mm += sgn * step[0],
                1 => r.dy_mm += sgn * step[1],
                _ => r.theta_rad += sgn * step[2],
            }
            let c = registration_cost(golden, &fine, &r, belt, &mut scratch).0;
            if c < best_cost {
                best_cost = c;
                best = r;
                improved = true;
            }
        }
        if !improved {
            for s in &mut step {
                *s *= 0.5;
            }
        }
    }
    let (cost, dz, overlap) = registration_cost(golden, &fine, &best, belt, &mut scratch);
    best.dz_mm = dz;
    best.overlap = overlap;
    best.mean_difference_mm = cost;
    if overlap < params.min_overlap {
        return Err(CoreError::Inspection {
            message: format!(
                "the golden scan does not overlap this scan: only {:.0}% of the part lands on the golden part after \
                 the best shift of ({:.1}, {:.1}) mm (at least {:.0}% needed); is it a scan of the same product?",
                100.0 * overlap,
                best.dx_mm,
                best.dy_mm,
                100.0 * params.min_overlap
            ),
        });
    }
    Ok(best)
}

/// Where the reference surface comes from.
#[derive(Debug, Clone, Copy)]
pub enum ReferenceSource<'a> {
    /// A robust fit of the part's own top surface.
    Fit(ReferenceShape),
    /// A golden scan of a good part, registered to the scan.
    Golden(&'a RangeImage),
    /// A golden scan prepared once for many parts ([`PreparedGolden`]).
    Prepared(&'a PreparedGolden),
}

/// A golden scan made ready for inspecting many parts against it: cleaned of outlier heights
/// ([`remove_outliers`], as every scan is before inspection) and its wall spans mapped ([`Registration::heights`]),
/// once, instead of for every part. On the 80 x 60 mm part of `cargo bench --bench inspect` those two are a tenth
/// of a golden inspection. Inspection checks that the preparation matches its own parameters.
#[derive(Debug, Clone)]
pub struct PreparedGolden {
    range: RangeImage,
    spans: SpanMap,
    outlier_mm: f64,
    travel_step_mm: Option<f64>,
}

impl PreparedGolden {
    /// `golden` cleaned of heights more than `outlier_mm` off their neighbourhood, with the span map of its part
    /// (cells above `belt_level_mm`) reaching a travel step of `travel_step_mm` along x (when known).
    pub fn new(
        golden: &RangeImage,
        outlier_mm: f64,
        belt_level_mm: f64,
        travel_step_mm: Option<f64>,
    ) -> Self {
        let mut range = golden.clone();
        remove_outliers(&mut range, outlier_mm);
        let reach = wall_reach_cells(&range, travel_step_mm);
        let spans = SpanMap::new(&range, belt_level_mm, reach);
        Self {
            range,
            spans,
            outlier_mm,
            travel_step_mm,
        }
    }

    /// The cleaned golden scan.
    pub fn range(&self) -> &RangeImage {
        &self.range
    }

    /// Whether this preparation is the one inspecting with these parameters would make (the same outlier limit,
    /// belt level and travel step); `Err` says which differs.
    pub fn check(
        &self,
        outlier_mm: f64,
        belt_level_mm: f64,
        travel_step_mm: Option<f64>,
    ) -> Result<(), CoreError> {
        let differs = |what: &str, prepared: String, asked: String| CoreError::Inspection {
            message: format!(
                "the golden scan was prepared with {what} {prepared} but the inspection uses {asked}: prepare it \
                 with the inspection's parameters"
            ),
        };
        if self.outlier_mm.to_bits() != outlier_mm.to_bits() {
            return Err(differs(
                "an outlier limit of",
                format!("{} mm", self.outlier_mm),
                format!("{outlier_mm} mm"),
            ));
        }
        if self.spans.floor_mm.to_bits() != belt_level_mm.to_bits() {
            return Err(differs(
                "a belt level of",
                format!("{} mm", self.spans.floor_mm),
                format!("{belt_level_mm} mm"),
            ));
        }
        if self.travel_step_mm.map(f64::to_bits) != travel_step_mm.map(f64::to_bits) {
            let show = |s: Option<f64>| s.map_or("none".to_string(), |s| format!("{s} mm"));
            return Err(differs(
                "a travel step of",
                show(self.travel_step_mm),
                show(travel_step_mm),
            ));
        }
        Ok(())
    }
}

/// What the reference turned out to be, for the report.
#[derive(Debug, Clone, PartialEq)]
pub enum ReferenceInfo {
    /// The fitted surface.
    Fitted(Reference),
    /// The golden scan's registration.
    Golden(Registration),
}

/// The reference height of every cell of `range`, from `source`; `travel_step_mm` (when known) sets how far along x
/// a golden scan's walls reach ([`Registration::heights`]).
pub fn reference_heights(
    range: &RangeImage,
    source: ReferenceSource<'_>,
    params: &CharacterizeParams,
    travel_step_mm: Option<f64>,
) -> Result<(Vec<f32>, ReferenceInfo), CoreError> {
    let register_params = RegisterParams {
        belt_level_mm: params.belt_level_mm,
        ..RegisterParams::default()
    };
    match source {
        ReferenceSource::Fit(shape) => {
            let p = CharacterizeParams {
                shape,
                ..params.clone()
            };
            let r = fit_reference(range, &p)?;
            Ok((r.heights(range), ReferenceInfo::Fitted(r)))
        }
        ReferenceSource::Golden(golden) => {
            let reg = register(range, golden, &register_params)?;
            Ok((
                reg.heights(range, golden, params.belt_level_mm, travel_step_mm),
                ReferenceInfo::Golden(reg),
            ))
        }
        ReferenceSource::Prepared(prepared) => {
            let golden = &prepared.range;
            let reg = register(range, golden, &register_params)?;
            let spans = &prepared.spans;
            let heights = if spans.floor_mm.to_bits() == params.belt_level_mm.to_bits()
                && spans.reach == wall_reach_cells(golden, travel_step_mm)
            {
                reg.heights_with(range, golden, spans)
            } else {
                // Prepared for another belt level or travel step: the map this reference needs.
                reg.heights(range, golden, params.belt_level_mm, travel_step_mm)
            };
            Ok((heights, ReferenceInfo::Golden(reg)))
        }
    }
}

/// Removes outlier heights: cells more than `limit_mm` from the median of the measured cells in their 5 x 5
/// neighbourhood, where that neighbourhood agrees with itself (most of it within `limit_mm` of its median). A stripe
/// fragment coded with a wrong index lands as a thin column of heights millimetres off; a true edge is kept,
/// because half or more of the window lies on each of its sides (at worst a cell at a corner is lost). Returns the
/// number of cells set to NaN.
pub fn remove_outliers(range: &mut RangeImage, limit_mm: f64) -> usize {
    let (w, h) = (range.width, range.height);
    if w == 0 || h == 0 || range.z.len() != w * h {
        return 0;
    }
    let limit = limit_mm as f32;
    let z = range.z.clone();
    let mut removed = 0;
    // Cheap test first: only cells that differ from a 4-neighbour by more than the limit (both finite) are
    // examined. The test is symmetric, so each pair of neighbours is compared once, a whole row (or pair of rows) at
    // a time without branches (vectorised).
    let differs = |a: f32, b: f32| a.is_finite() & b.is_finite() & ((a - b).abs() > limit);
    let mut rough = vec![false; w * h];
    // The differences of horizontal neighbours of a row, then the flags from them: two passes without a dependence
    // from one cell to the next (one pass that sets both cells of each pair does not vectorise).
    let mut pair = vec![false; w.saturating_sub(1)];
    for j in 0..h {
        let row = &z[j * w..(j + 1) * w];
        for (d, (a, b)) in pair.iter_mut().zip(row.iter().zip(&row[1..])) {
            *d = differs(*a, *b);
        }
        let flags = &mut rough[j * w..(j + 1) * w];
        if let (Some(first), Some(last)) = (pair.first(), pair.last()) {
            flags[0] |= *first;
            flags[w - 1] |= *last;
        }
        for (f, (l, r)) in flags[1..w.saturating_sub(1).max(1)]
            .iter_mut()
            .zip(pair.iter().zip(pair.iter().skip(1)))
        {
            *f |= *l | *r;
        }
        if j > 0 {
            let (above, here) = rough[(j - 1) * w..(j + 1) * w].split_at_mut(w);
            let up = &z[(j - 1) * w..j * w];
            for ((a, hh), (u, r)) in above
                .iter_mut()
                .zip(here.iter_mut())
                .zip(up.iter().zip(row))
            {
                let d = differs(*u, *r);
                *a |= d;
                *hh |= d;
            }
        }
    }
    let mut window: Vec<f32> = Vec::with_capacity(25);
    for j in 0..h {
        for i in 0..w {
            let k = j * w + i;
            if !rough[k] {
                continue;
            }
            let v = z[k];
            window.clear();
            for jj in j.saturating_sub(2)..(j + 3).min(h) {
                for ii in i.saturating_sub(2)..(i + 3).min(w) {
                    let n = z[jj * w + ii];
                    if n.is_finite() {
                        window.push(n);
                    }
                }
            }
            if window.len() < 9 {
                continue;
            }
            let mid = window.len() / 2;
            let (_, m, _) = window.select_nth_unstable_by(mid, f32::total_cmp);
            let m = *m;
            let agree = window.iter().filter(|&&n| (n - m).abs() <= limit).count();
            if (v - m).abs() > limit && 3 * agree >= 2 * window.len() {
                range.z[k] = f32::NAN;
                removed += 1;
            }
        }
    }
    removed
}

/// The characterization maps of a range image against a reference.
#[derive(Debug, Clone, PartialEq)]
pub struct SurfaceMaps {
    /// What each cell shows.
    pub class: Vec<CellClass>,
    /// The reference height of each cell, mm; NaN where no surface is expected.
    pub reference_mm: Vec<f32>,
    /// Measured minus reference height, mm; NaN where either is missing or the cell is not the part.
    pub deviation_mm: Vec<f32>,
    /// Deviation averaged over the 3 x 3 cells around (those that hold one; at least 5), mm.
    pub smoothed_mm: Vec<f32>,
    /// Robust standard deviation of the deviation over the part, mm.
    pub noise_mm: f64,
    /// Half-width of the derivative window, cells (normals and curvature: [`geometry_at`], [`derivative_maps`]).
    pub window_cells: usize,
}

/// 1-D least-squares kernels over 2r+1 samples: (mean, first derivative, second-order coefficient).
fn kernels(r: usize) -> (Vec<f64>, Vec<f64>, Vec<f64>) {
    let n = 2 * r + 1;
    let xs: Vec<f64> = (0..n).map(|k| k as f64 - r as f64).collect();
    let sx2: f64 = xs.iter().map(|x| x * x).sum();
    let m = sx2 / n as f64;
    let sq: f64 = xs.iter().map(|x| (x * x - m).powi(2)).sum();
    (
        vec![1.0 / n as f64; n],
        xs.iter().map(|x| x / sx2).collect(),
        xs.iter().map(|x| (x * x - m) / sq).collect(),
    )
}

/// Characterizes `range` against per-cell reference heights (from [`Reference::heights`] or
/// [`Registration::heights`]).
pub fn surface_maps(
    range: &RangeImage,
    reference_mm: Vec<f32>,
    params: &CharacterizeParams,
) -> Result<SurfaceMaps, CoreError> {
    params.validate()?;
    let (w, h) = (range.width, range.height);
    if reference_mm.len() != w * h {
        return Err(CoreError::InvalidParameter {
            field: "reference_mm",
            value: reference_mm.len().to_string(),
            reason: format!("one reference height per cell is needed ({w}x{h})"),
        });
    }
    let class = classify(range, params.belt_level_mm);
    let deviation: Vec<f32> = (0..w * h)
        .map(|k| {
            if class[k] == CellClass::Part {
                range.z[k] - reference_mm[k]
            } else {
                f32::NAN
            }
        })
        .collect();
    let smoothed = smooth3(w, h, &deviation);
    // The noise from every 7th cell: a robust spread needs tens of thousands of samples, not the whole grid.
    let mut abs: Vec<f64> = deviation
        .iter()
        .step_by(NOISE_STRIDE)
        .filter(|d| d.is_finite())
        .map(|d| f64::from(d.abs()))
        .collect();
    let noise = median(&mut abs) * 1.4826;
    let r = window_radius(range, params);
    Ok(SurfaceMaps {
        class,
        reference_mm,
        deviation_mm: deviation,
        smoothed_mm: smoothed,
        noise_mm: noise,
        window_cells: r,
    })
}

/// Half-width (cells) of the derivative window.
fn window_radius(range: &RangeImage, params: &CharacterizeParams) -> usize {
    ((params.window_mm / range.spacing_mm[0].min(range.spacing_mm[1]) - 1.0) / 2.0)
        .round()
        .max(1.0) as usize
}

/// Local surface geometry at one cell.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Geometry {
    /// Unit normal (x, y, z).
    pub normal: [f64; 3],
    /// Mean curvature, 1/mm, positive where convex (a bump's top).
    pub mean_curvature: f64,
    /// Gaussian curvature, 1/mm².
    pub gaussian_curvature: f64,
}

/// Normal and curvatures from the derivatives of z = f(x, y) (Monge patch).
fn geometry(gx: f64, gy: f64, gxx: f64, gyy: f64, gxy: f64) -> Geometry {
    let q = 1.0 + gx * gx + gy * gy;
    let len = q.sqrt();
    Geometry {
        normal: [-gx / len, -gy / len, 1.0 / len],
        // The graph's mean curvature with the sign chosen so that a bump's top is positive.
        mean_curvature: -((1.0 + gy * gy) * gxx - 2.0 * gx * gy * gxy + (1.0 + gx * gx) * gyy)
            / (2.0 * q * len),
        gaussian_curvature: (gxx * gyy - gxy * gxy) / (q * q),
    }
}

/// The geometry at cell (i, j) from the quadratic fit over its window; `None` where the window is not all part.
/// Detection evaluates only the cells of candidate regions with it; [`derivative_maps`] gives whole maps.
pub fn geometry_at(range: &RangeImage, maps: &SurfaceMaps, i: usize, j: usize) -> Option<Geometry> {
    let (w, h) = (range.width, range.height);
    let r = maps.window_cells;
    if i < r || j < r || i + r >= w || j + r >= h {
        return None;
    }
    let (k0, k1, k2) = kernels(r);
    let (mut fx, mut fy, mut fxx, mut fyy, mut fxy) = (0.0, 0.0, 0.0, 0.0, 0.0);
    for (tj, jj) in (j - r..=j + r).enumerate() {
        for (ti, ii) in (i - r..=i + r).enumerate() {
            let k = jj * w + ii;
            if maps.class[k] != CellClass::Part {
                return None;
            }
            let z = f64::from(range.z[k]);
            fx += k1[ti] * k0[tj] * z;
            fy += k0[ti] * k1[tj] * z;
            fxx += k2[ti] * k0[tj] * z;
            fyy += k0[ti] * k2[tj] * z;
            fxy += k1[ti] * k1[tj] * z;
        }
    }
    let (dx, dy) = (range.spacing_mm[0], range.spacing_mm[1]);
    // Along j, y decreases: d/dy = −d/dj.
    Some(geometry(
        fx / dx,
        -fy / dy,
        2.0 * fxx / (dx * dx),
        2.0 * fyy / (dy * dy),
        -fxy / (dx * dy),
    ))
}

/// Normal and curvature maps of the whole range image (NaN where the window is not all part).
#[derive(Debug, Clone, PartialEq)]
pub struct DerivativeMaps {
    /// Unit surface normal (x, y, z).
    pub normal: Vec<[f32; 3]>,
    /// Mean curvature, 1/mm (positive where the surface is convex, a bump's top).
    pub mean_curvature: Vec<f32>,
    /// Gaussian curvature, 1/mm².
    pub gaussian_curvature: Vec<f32>,
}

/// The normal and curvature maps, by separable filtering (the same fit as [`geometry_at`], for every cell).
pub fn derivative_maps(range: &RangeImage, maps: &SurfaceMaps) -> DerivativeMaps {
    let (w, h) = (range.width, range.height);
    let class = &maps.class;
    let r = maps.window_cells;
    // Derivatives of the measured heights over a full window of part cells.
    let (k0, k1, k2) = kernels(r);
    // Summed-area table of cells that are not the part.
    let mut bad = vec![0u32; (w + 1) * (h + 1)];
    for j in 0..h {
        for i in 0..w {
            let v = u32::from(class[j * w + i] != CellClass::Part);
            bad[(j + 1) * (w + 1) + i + 1] =
                v + bad[j * (w + 1) + i + 1] + bad[(j + 1) * (w + 1) + i] - bad[j * (w + 1) + i];
        }
    }
    let complete = |i: usize, j: usize| -> bool {
        if i < r || j < r || i + r >= w || j + r >= h {
            return false;
        }
        let (a, b, c, d) = (i - r, j - r, i + r + 1, j + r + 1);
        bad[d * (w + 1) + c] + bad[b * (w + 1) + a] == bad[b * (w + 1) + c] + bad[d * (w + 1) + a]
    };
    // Horizontal passes (along i) with the three kernels, on part heights (others as 0; masked later).
    let z: Vec<f64> = (0..w * h)
        .map(|k| {
            if class[k] == CellClass::Part {
                f64::from(range.z[k])
            } else {
                0.0
            }
        })
        .collect();
    let pass_x = |kern: &[f64]| -> Vec<f64> {
        let mut out = vec![0.0; w * h];
        for j in 0..h {
            for i in r..w.saturating_sub(r) {
                let mut s = 0.0;
                for (t, kv) in kern.iter().enumerate() {
                    s += kv * z[j * w + i + t - r];
                }
                out[j * w + i] = s;
            }
        }
        out
    };
    let pass_y = |src: &[f64], kern: &[f64]| -> Vec<f64> {
        let mut out = vec![0.0; w * h];
        for j in r..h.saturating_sub(r) {
            for i in 0..w {
                let mut s = 0.0;
                for (t, kv) in kern.iter().enumerate() {
                    s += kv * src[(j + t - r) * w + i];
                }
                out[j * w + i] = s;
            }
        }
        out
    };
    let (x0, x1, x2) = (pass_x(&k0), pass_x(&k1), pass_x(&k2));
    // Along j, y decreases: d/dy = −d/dj.
    let (dx, dy) = (range.spacing_mm[0], range.spacing_mm[1]);
    let fx = pass_y(&x1, &k0);
    let fy = pass_y(&x0, &k1);
    let fxx = pass_y(&x2, &k0);
    let fyy = pass_y(&x0, &k2);
    let fxy = pass_y(&x1, &k1);
    let mut normal = vec![[f32::NAN; 3]; w * h];
    let mut mean_c = vec![f32::NAN; w * h];
    let mut gauss_c = vec![f32::NAN; w * h];
    for j in 0..h {
        for i in 0..w {
            if !complete(i, j) {
                continue;
            }
            let k = j * w + i;
            let g = geometry(
                fx[k] / dx,
                -fy[k] / dy,
                2.0 * fxx[k] / (dx * dx),
                2.0 * fyy[k] / (dy * dy),
                -fxy[k] / (dx * dy),
            );
            normal[k] = g.normal.map(|v| v as f32);
            mean_c[k] = g.mean_curvature as f32;
            gauss_c[k] = g.gaussian_curvature as f32;
        }
    }
    DerivativeMaps {
        normal,
        mean_curvature: mean_c,
        gaussian_curvature: gauss_c,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    proptest::proptest! {
        /// The separable 3 x 3 smoothing equals the direct window mean.
        #[test]
        fn separable_smoothing_equals_the_window_mean(
            w in 1usize..12,
            h in 1usize..12,
            vals in proptest::collection::vec(proptest::option::of(-1.0f32..1.0), 144),
        ) {
            let v: Vec<f32> = (0..w * h).map(|k| vals[k].unwrap_or(f32::NAN)).collect();
            let fast = smooth3(w, h, &v);
            for j in 0..h {
                for i in 0..w {
                    let (mut s, mut c) = (0.0f32, 0u32);
                    for jj in j.saturating_sub(1)..(j + 2).min(h) {
                        for ii in i.saturating_sub(1)..(i + 2).min(w) {
                            if v[jj * w + ii].is_finite() {
                                s += v[jj * w + ii];
                                c += 1;
                            }
                        }
                    }
                    let want = if c >= 5 && v[j * w + i].is_finite() { s / c as f32 } else { f32::NAN };
                    let got = fast[j * w + i];
                    proptest::prop_assert!(
                        (want.is_nan() && got.is_nan()) || (want - got).abs() < 1e-5,
                        "({}, {}): {} vs {}", i, j, got, want
                    );
                }
            }
        }
    }

    /// A range image of `f` on a `w` x `h` grid of 0.2 mm cells starting at (−w/10, h/10).
    fn image(w: usize, h: usize, f: impl Fn(f64, f64) -> f64) -> RangeImage {
        let mut r = RangeImage {
            origin_mm: [-(w as f64) * 0.1, h as f64 * 0.1],
            spacing_mm: [0.2, 0.2],
            width: w,
            height: h,
            z: vec![0.0; w * h],
            intensity: None,
        };
        for j in 0..h {
            for i in 0..w {
                let (x, y) = cell_xy(&r, i, j);
                r.z[j * w + i] = f(x, y) as f32;
            }
        }
        r
    }

    /// The registration that maps every point onto itself.
    const IDENTITY: Registration = Registration {
        dx_mm: 0.0,
        dy_mm: 0.0,
        theta_rad: 0.0,
        dz_mm: 0.0,
        centre_mm: [0.0, 0.0],
        mean_difference_mm: 0.0,
        overlap: 1.0,
    };

    #[test]
    fn a_golden_wall_reaches_a_travel_step_along_x() {
        // A step from 10 to 17 mm at x = 0 in the golden scan; the scan sees it 0.5 mm further along x (its last
        // sample before the step fell a whole 0.5 mm travel step short of it), and has a 0.2 mm dent 3 mm away.
        let golden = image(100, 60, |x, _| if x > 0.0 { 17.0 } else { 10.0 });
        let scan = image(100, 60, |x, _| {
            if x > 0.5 {
                17.0
            } else if (x + 3.0).abs() < 0.5 {
                9.8
            } else {
                10.0
            }
        });
        let worst = |step: Option<f64>| {
            let reference = IDENTITY.heights(&scan, &golden, 0.5, step);
            let mut worst = 0.0f64;
            for (k, (&z, &r)) in scan.z.iter().zip(&reference).enumerate() {
                let x = cell_xy(&scan, k % scan.width, k / scan.width).0;
                if x.abs() < 1.0 && r.is_finite() {
                    worst = worst.max(f64::from((z - r).abs()));
                }
            }
            let dent = scan.width * 30 + 35; // x = -3
            (worst, f64::from(scan.z[dent] - reference[dent]))
        };
        let (one_cell, dent) = worst(None);
        assert!(one_cell > 6.0, "{one_cell}: the wall a cell's reach misses");
        assert!((dent + 0.2).abs() < 1e-3, "{dent}");
        let (a_step, dent) = worst(Some(0.5));
        assert!(a_step < 1e-3, "{a_step}");
        assert!((dent + 0.2).abs() < 1e-3, "{dent}");
    }

    #[test]
    fn a_golden_wall_is_compared_within_its_span_and_flat_ground_as_it_is() {
        // A boss 8 mm high on a 10 mm plate; the scan sees it 0.1 mm (half a cell) further along x, and has a dent
        // 0.4 mm deep on the plate away from it.
        let boss = |x: f64, y: f64| if x.hypot(y) < 5.0 { 18.0 } else { 10.0 };
        let golden = image(100, 100, boss);
        let scan = image(100, 100, |x, y| {
            let d = (x - 6.5).hypot(y + 6.5);
            boss(x - 0.1, y) - if d < 1.5 { 0.4 * (1.0 - d / 1.5) } else { 0.0 }
        });
        let reference = IDENTITY.heights(&scan, &golden, 0.5, None);
        let (mut plain_max, mut wall_max) = (0.0f64, 0.0f64);
        for j in 0..scan.height {
            for i in 0..scan.width {
                let (x, y) = cell_xy(&scan, i, j);
                let k = j * scan.width + i;
                let z = f64::from(scan.z[k]);
                if (x.hypot(y) - 5.0).abs() < 0.5 {
                    let plain = bilinear_above(&golden, x, y, 0.5).expect("golden");
                    plain_max = plain_max.max((z - plain).abs());
                    wall_max = wall_max.max((z - f64::from(reference[k])).abs());
                }
            }
        }
        assert!(
            plain_max > 5.0,
            "cell by cell the rim is millimetres off: {plain_max}"
        );
        assert!(
            wall_max < 1e-6,
            "within the wall's span it is not: {wall_max}"
        );
        // The dent keeps its depth.
        let (i, j) = (
            ((6.5 - scan.origin_mm[0]) / 0.2).round() as usize,
            ((scan.origin_mm[1] + 6.5) / 0.2).round() as usize,
        );
        let k = j * scan.width + i;
        let dev = f64::from(scan.z[k] - reference[k]);
        assert!((dev + 0.4).abs() < 0.06, "{dev}");
    }

    #[test]
    fn the_span_map_is_the_span_of_every_point() {
        // Steps, a hole (NaN) and belt cells (below the floor), at points inside and off the grid.
        let r = image(37, 23, |x, y| {
            if x.hypot(y) < 0.7 {
                f64::NAN
            } else if x < -2.0 {
                0.1
            } else {
                10.0 + (3.0 * x).sin() + if y > 1.0 { 2.0 } else { 0.0 }
            }
        });
        // The usual window and wider ones (three cells along x: a 0.5 mm travel step on a 0.2 mm grid).
        for reach in [1, 2, 3, 5] {
            let spans = SpanMap::new(&r, 0.5, reach);
            let mut rng = 12345u64;
            for _ in 0..2000 {
                rng = rng
                    .wrapping_mul(6364136223846793005)
                    .wrapping_add(1442695040888963407);
                let x = ((rng >> 11) % 10_000) as f64 / 10_000.0 * 9.0 - 4.5;
                let y = ((rng >> 35) % 10_000) as f64 / 10_000.0 * 6.0 - 3.0;
                let (fi, fj) = grid_coords(&r, x, y);
                let want = local_span(&r, fi, fj, 0.5, reach).map(|(a, b)| (a as f32, b as f32));
                let got = spans.at(&r, fi, fj).map(|(a, b)| (a as f32, b as f32));
                assert_eq!(got, want, "reach {reach} at ({x}, {y})");
            }
        }
        assert_eq!(wall_reach_cells(&r, Some(0.5)), 3);
        assert_eq!(wall_reach_cells(&r, None), 1);
        assert_eq!(wall_reach_cells(&r, Some(0.1)), 1);
    }

    #[test]
    fn a_golden_slope_seen_slightly_misregistered_does_not_deviate_but_a_dent_does() {
        // A 10 mm plate whose edge x < -5 is a chamfer of slope 0.6 down to 8.5 mm (a span of 0.48 mm over the
        // wall band's four cells: not a wall). The scan is registered 0.1 mm off along x and has a dent 0.2 mm deep
        // on the plate.
        let part = |x: f64| {
            if x < -5.0 {
                (10.0 + 0.6 * (x + 5.0)).max(8.5)
            } else {
                10.0
            }
        };
        let golden = image(100, 100, |x, _| part(x));
        let scan = image(100, 100, |x, y| {
            let d = (x - 5.0).hypot(y);
            part(x - 0.1) - if d < 2.0 { 0.2 * (1.0 - d / 2.0) } else { 0.0 }
        });
        let reference = IDENTITY.heights(&scan, &golden, 0.5, None);
        let mut chamfer_max = 0.0f64;
        let mut dent_min = 0.0f64;
        for j in 0..scan.height {
            for i in 0..scan.width {
                let (x, y) = cell_xy(&scan, i, j);
                let k = j * scan.width + i;
                let dev = f64::from(scan.z[k] - reference[k]);
                if (-7.0..-5.5).contains(&x) && y.abs() < 8.0 {
                    chamfer_max = chamfer_max.max(dev.abs());
                }
                if (x - 5.0).hypot(y) < 0.3 {
                    dent_min = dent_min.min(dev);
                }
            }
        }
        // Compared cell by cell the chamfer is 0.06 mm off everywhere (more than a small defect's threshold).
        assert!(chamfer_max < 1e-6, "chamfer deviates by {chamfer_max}");
        assert!(dent_min < -0.15, "the dent is {dent_min} deep");
    }

    #[test]
    fn robust_fit_ignores_defects_steps_and_belt() {
        // A tilted 10 mm plate with a 3 mm step on a quarter of it and a dent, on the belt.
        let r = image(300, 200, |x, y| {
            if x.abs() > 25.0 || y.abs() > 17.0 {
                0.0
            } else if x > 10.0 && y > 5.0 {
                13.0 + 0.01 * x
            } else if (x + 5.0).hypot(y) < 3.0 {
                9.5 + 0.01 * x
            } else {
                10.0 + 0.01 * x - 0.005 * y
            }
        });
        let f = fit_reference(&r, &CharacterizeParams::default()).expect("fit");
        assert!((f.height(0.0, 0.0) - 10.0).abs() < 1e-3, "{f:?}");
        assert!((f.height(10.0, -10.0) - 10.15).abs() < 1e-3, "{f:?}");
        let q = fit_reference(
            &r,
            &CharacterizeParams {
                shape: ReferenceShape::Quadratic,
                ..CharacterizeParams::default()
            },
        )
        .expect("fit");
        assert!((q.height(-20.0, -15.0) - (10.0 - 0.2 + 0.075)).abs() < 1e-3);
        let empty = image(10, 10, |_, _| 0.0);
        let e = fit_reference(&empty, &CharacterizeParams::default()).expect_err("belt only");
        assert!(e.to_string().contains("no part"), "{e}");
    }

    #[test]
    fn curvature_and_normals_match_a_sphere_and_stop_at_holes() {
        // A sphere cap of radius 50 mm: mean curvature 1/50, Gaussian 1/2500, normals radial.
        let rad = 50.0;
        let mut r = image(100, 100, |x, y| {
            10.0 + (rad * rad - x * x - y * y).sqrt() - rad
        });
        // A hole at the centre.
        for j in 45..55 {
            for i in 45..55 {
                r.z[j * 100 + i] = f32::NAN;
            }
        }
        let refh = vec![10.0f32; 100 * 100];
        let maps = surface_maps(&r, refh, &CharacterizeParams::default()).expect("maps");
        let m = derivative_maps(&r, &maps);
        let k = 20 * 100 + 70; // x = 4, y = 6
        // One cell at a time gives the same.
        let g = geometry_at(&r, &maps, 70, 20).expect("complete window");
        assert!((g.mean_curvature - f64::from(m.mean_curvature[k])).abs() < 1e-5);
        assert!(geometry_at(&r, &maps, 43, 50).is_none());
        let (x, y) = cell_xy(&r, 70, 20);
        assert!(
            (f64::from(m.mean_curvature[k]) - 1.0 / rad).abs() < 1e-3,
            "{}",
            m.mean_curvature[k]
        );
        assert!((f64::from(m.gaussian_curvature[k]) - 1.0 / (rad * rad)).abs() < 1e-4);
        let n = m.normal[k];
        let zc = (rad * rad - x * x - y * y).sqrt();
        assert!(
            (f64::from(n[0]) - x / rad).abs() < 1e-3 && (f64::from(n[1]) - y / rad).abs() < 1e-3
        );
        assert!((f64::from(n[2]) - zc / rad).abs() < 1e-3);
        // Next to the hole: no value (the window would cross it); inside: no deviation either.
        assert!(m.mean_curvature[50 * 100 + 43].is_nan());
        assert!(maps.deviation_mm[50 * 100 + 50].is_nan());
        assert!(m.mean_curvature[50 * 100 + 40].is_finite());
    }

    /// [`remove_outliers`] as first written: the neighbour test cell by cell.
    fn remove_outliers_cell_by_cell(range: &mut RangeImage, limit_mm: f64) -> usize {
        let (w, h) = (range.width, range.height);
        let limit = limit_mm as f32;
        let z = range.z.clone();
        let mut removed = 0;
        for j in 0..h {
            for i in 0..w {
                let k = j * w + i;
                let v = z[k];
                if !v.is_finite() {
                    continue;
                }
                let differs = |n: f32| n.is_finite() && (n - v).abs() > limit;
                let rough = (i > 0 && differs(z[k - 1]))
                    || (i + 1 < w && differs(z[k + 1]))
                    || (j > 0 && differs(z[k - w]))
                    || (j + 1 < h && differs(z[k + w]));
                if !rough {
                    continue;
                }
                let mut window = Vec::new();
                for jj in j.saturating_sub(2)..(j + 3).min(h) {
                    for ii in i.saturating_sub(2)..(i + 3).min(w) {
                        if z[jj * w + ii].is_finite() {
                            window.push(z[jj * w + ii]);
                        }
                    }
                }
                if window.len() < 9 {
                    continue;
                }
                let mid = window.len() / 2;
                let m = *window.select_nth_unstable_by(mid, f32::total_cmp).1;
                let agree = window.iter().filter(|&&n| (n - m).abs() <= limit).count();
                if (v - m).abs() > limit && 3 * agree >= 2 * window.len() {
                    range.z[k] = f32::NAN;
                    removed += 1;
                }
            }
        }
        removed
    }

    #[test]
    fn outliers_are_the_ones_the_cell_by_cell_test_finds() {
        // Steps, holes, infinities, spikes and lone cells, on images down to one cell wide.
        let mut rng = 99u64;
        let mut next = move || {
            rng = rng
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            (rng >> 33) as u32
        };
        for (w, h) in [
            (0, 4),
            (4, 0),
            (1, 7),
            (7, 1),
            (2, 2),
            (3, 11),
            (13, 9),
            (40, 31),
        ] {
            for _ in 0..20 {
                let z: Vec<f32> = (0..w * h)
                    .map(|k| match next() % 20 {
                        0 => f32::NAN,
                        1 => 14.0,
                        2 => f32::INFINITY,
                        3 => 10.0 + (next() % 100) as f32 * 0.05,
                        _ => 10.0 + (k % w) as f32 * 0.01 + if k % w > w / 2 { 2.0 } else { 0.0 },
                    })
                    .collect();
                let r = RangeImage {
                    origin_mm: [0.0, 0.0],
                    spacing_mm: [0.1, 0.1],
                    width: w,
                    height: h,
                    z,
                    intensity: None,
                };
                let (mut fast, mut plain) = (r.clone(), r.clone());
                let n = remove_outliers(&mut fast, 1.0);
                assert_eq!(n, remove_outliers_cell_by_cell(&mut plain, 1.0));
                let bits = |r: &RangeImage| r.z.iter().map(|v| v.to_bits()).collect::<Vec<_>>();
                assert_eq!(bits(&fast), bits(&plain), "{w}x{h}");
            }
        }
    }

    /// The registration tests' part: a 30 x 20 mm plate with a hole and a 4 mm step in one corner; `top` is the
    /// height of the rest of its top at (x, y).
    fn stepped_plate(x: f64, y: f64, top: impl Fn(f64, f64) -> f64) -> f64 {
        if x.abs() > 15.0 || y.abs() > 10.0 || (x - 5.0).hypot(y - 3.0) < 2.0 {
            0.0
        } else if x < -5.0 && y > 0.0 {
            14.0
        } else {
            top(x, y)
        }
    }

    #[test]
    fn the_coarse_searchs_shortlist_picks_what_the_full_search_picks() {
        // A gentle tilt and some deterministic roughness on the top, so that the costs are not flat.
        let part = |x: f64, y: f64| {
            stepped_plate(x, y, |x, y| {
                10.0 + 0.02 * x + 0.01 * ((7.0 * x).sin() * (5.0 * y).cos())
            })
        };
        let golden = image(200, 150, part);
        let params = RegisterParams::default();
        let mut scratch = Vec::new();
        for (dx, dy, th) in [
            (1.3, -0.7, 0.02),
            (-3.6, 2.4, -0.015),
            (4.4, 3.8, 0.004),
            (-0.4, 4.9, 0.0),
        ] {
            let scan = image(200, 150, |x, y| {
                let (c, s) = (f64::cos(th), f64::sin(th));
                part(c * x - s * y + dx, s * x + c * y + dy)
            });
            let cells: Vec<(f64, f64, f64)> = (0..scan.z.len())
                .filter(|&k| f64::from(scan.z[k]) > params.belt_level_mm)
                .map(|k| {
                    let (x, y) = cell_xy(&scan, k % scan.width, k / scan.width);
                    (x, y, f64::from(scan.z[k]))
                })
                .collect();
            let n = cells.len() as f64;
            let centre = [
                cells.iter().map(|c| c.0).sum::<f64>() / n,
                cells.iter().map(|c| c.1).sum::<f64>() / n,
            ];
            let sample: Vec<(f64, f64, f64)> = cells
                .iter()
                .step_by(cells.len() / 1500)
                .map(|&(x, y, z)| (x - centre[0], y - centre[1], z))
                .collect();
            // The centroids' match, here off by the move (the golden part's centroid is near the origin).
            let start = Registration {
                dx_mm: -centre[0],
                dy_mm: -centre[1],
                theta_rad: 0.0,
                dz_mm: 0.0,
                centre_mm: centre,
                mean_difference_mm: f64::NAN,
                overlap: 0.0,
            };
            let short = coarse_search(
                &golden,
                &sample,
                start,
                &params,
                COARSE_SHORTLIST,
                &mut scratch,
            );
            let full = coarse_search(&golden, &sample, start, &params, usize::MAX, &mut scratch);
            assert_eq!(
                (short.dx_mm, short.dy_mm, short.theta_rad),
                (full.dx_mm, full.dy_mm, full.theta_rad)
            );
            // And it lands within a step of the move: the coarse search is not idle here.
            let (gx, gy) = short.map(centre[0], centre[1]);
            let (ex, ey) = (
                th.cos() * centre[0] - th.sin() * centre[1] + dx,
                th.sin() * centre[0] + th.cos() * centre[1] + dy,
            );
            assert!(
                (gx - ex).abs() <= 0.75 && (gy - ey).abs() <= 0.75,
                "{dx} {dy}: {short:?}"
            );
        }
    }

    #[test]
    fn registration_recovers_a_shift_rotation_and_height() {
        let part = |x: f64, y: f64| stepped_plate(x, y, |_, _| 10.0);
        let golden = image(200, 150, part);
        let moves: [(f64, f64, f64, f64); 2] = [(1.3, -0.7, 0.02, 0.05), (-3.6, 2.4, -0.015, -0.2)];
        let mut scan = golden.clone();
        for (dx, dy, th, dz) in moves {
            // The scan: the golden part moved; scan point p sits at R p + t on the golden part.
            scan = image(200, 150, |x, y| {
                let (c, s) = (th.cos(), th.sin());
                let (gx, gy) = (c * x - s * y + dx, s * x + c * y + dy);
                let z = part(gx, gy);
                if z > 0.0 { z + dz } else { 0.0 }
            });
            let reg = register(&scan, &golden, &RegisterParams::default()).expect("register");
            // The centre of rotation is the scan part's centroid: compare mapped points instead of raw parameters.
            for (x, y) in [(0.0, 0.0), (10.0, 5.0), (-10.0, -5.0)] {
                let (gx, gy) = reg.map(x, y);
                let (c, s) = (th.cos(), th.sin());
                let (ex, ey) = (c * x - s * y + dx, s * x + c * y + dy);
                assert!(
                    (gx - ex).abs() < 0.05 && (gy - ey).abs() < 0.05,
                    "{dx} {dy} {th}: {reg:?}"
                );
            }
            assert!((reg.dz_mm - dz).abs() < 0.01);
        }
        // Another product: a small block the scan's part cannot lie on.
        let other = image(200, 150, |x, y| {
            if x.abs() < 4.0 && y.abs() < 4.0 {
                10.0
            } else {
                0.0
            }
        });
        let e = register(&scan, &other, &RegisterParams::default()).expect_err("no overlap");
        assert!(e.to_string().contains("does not overlap"), "{e}");
    }
}
