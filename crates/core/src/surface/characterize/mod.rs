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
use crate::error::InspectionError;
use nalgebra::{DMatrix, DVector};

mod register;
#[cfg(test)]
mod tests;

pub use register::*;

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
        return Err(CoreError::Inspection(InspectionError::TooFewPartCells {
            part_cells: part.len(),
            cells: range.z.len(),
            belt_level_mm: params.belt_level_mm,
        }));
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
        return Err(CoreError::Inspection(InspectionError::ReferenceDiverged));
    }
    Ok(r)
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
        let differs = |what: &'static str, prepared: String, asked: String| {
            CoreError::Inspection(InspectionError::GoldenPreparedOtherwise {
                what,
                prepared,
                asked,
            })
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
