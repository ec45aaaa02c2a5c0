//! A golden scan registered to a part's scan: rigid in x-y and height, a coarse search over shifts and small
//! rotations refined by halving steps, minimising the mean clipped height difference; on the golden part's walls any height
//! within the span the golden part shows around a point is taken as the reference, since neither scan pins down where
//! the wall is.

use super::*;

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
    pub(super) fn mapper(&self) -> impl Fn(f64, f64) -> (f64, f64) + use<> {
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
    pub(super) fn grid_mapper(
        &self,
        golden: &RangeImage,
    ) -> impl Fn(f64, f64) -> (f64, f64) + use<> {
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
    pub(super) fn heights_with(
        &self,
        scan: &RangeImage,
        golden: &RangeImage,
        spans: &SpanMap,
    ) -> Vec<f32> {
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
pub(super) fn local_span(
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
pub(super) fn sliding(
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
pub(super) struct SpanMap {
    pub(super) lo: Vec<f32>,
    pub(super) hi: Vec<f32>,
    pub(super) floor_mm: f64,
    pub(super) reach: usize,
}

impl SpanMap {
    pub(super) fn new(range: &RangeImage, floor_mm: f64, reach: usize) -> Self {
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
    pub(super) fn at(&self, range: &RangeImage, fi: f64, fj: f64) -> Option<(f64, f64)> {
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
pub(super) fn grid_coords(range: &RangeImage, x: f64, y: f64) -> (f64, f64) {
    (
        (x - range.origin_mm[0]) / range.spacing_mm[0],
        (range.origin_mm[1] - y) / range.spacing_mm[1],
    )
}

/// [`bilinear_above`] at fractional cell indices.
#[inline]
pub(super) fn bilinear_cell(range: &RangeImage, fi: f64, fj: f64, floor_mm: f64) -> Option<f64> {
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
pub(super) const COARSE_SHORTLIST: usize = 8;

/// Robust cost of a registration over sample points (u, v, z), (u, v) mm from the registration's centre: the mean
/// absolute height difference after the median offset, each clipped at 1 mm, with points off the golden part counted
/// as 1 mm off. Returns (cost, dz, overlap).
pub(super) fn registration_cost(
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
pub(super) fn coarse_search(
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
    pub(super) fn part_cells(
        r: &RangeImage,
        belt: f64,
    ) -> impl Iterator<Item = (usize, usize, f64)> + '_ {
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
        return Err(CoreError::Inspection(
            InspectionError::TooFewCellsToRegister {
                scan_cells: count,
                golden_cells: golden_part,
            },
        ));
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
        return Err(CoreError::Inspection(InspectionError::NoOverlap {
            overlap,
            dx_mm: best.dx_mm,
            dy_mm: best.dy_mm,
            needed: params.min_overlap,
        }));
    }
    Ok(best)
}
