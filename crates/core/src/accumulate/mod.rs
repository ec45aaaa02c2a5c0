//! Triangulated profiles, and their accumulation over a scan into a point cloud and a range image.
//!
//! A [`Profile`] is one frame's coded stripe points in millimetres, in part coordinates (belt coordinates with the
//! conveyor travel since frame 0 subtracted, `docs/design.md`). [`RangeGrid::accumulate`] resamples a scan's profiles
//! onto a regular x-y grid: every point lands in its cell, and between the points of one stripe on one image row
//! in consecutive frames (or with one frame missing between them; the same sheet sweeping the part) the surface is
//! interpolated (by the cubic through them and their neighbours along the track) when they are close (at most
//! [`RangeParams::max_fill_mm`] apart along x and [`RangeParams::max_fill_step_mm`] apart in height), so that a
//! grid finer than the travel per frame has no stripes of empty cells. Cells where nothing was measured are NaN.
//! [`RangeGrid::update`] takes back the tracks of points that moved and adds them again, for corrections that
//! move some points of a scan (`crate::curvature`).

use crate::CoreError;
use crate::code::Coding;
use crate::extract::StripePoint;
use crate::triangulate::{FullModel, LinearModel};
use rayon::prelude::*;

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
    /// Whether the position comes from the point's peak in time (see [`crate::spacetime`]) rather than from the
    /// stripe's centre in the frame: such a point carries no curvature or albedo bias and is not corrected for it.
    pub spacetime: bool,
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
            spacetime: false,
        });
    }
}

/// Samples of one stripe and row at most this many frames apart are joined (when close enough): a frame in which
/// coding dropped a whole stripe segment leaves no empty column behind.
const MAX_FILL_FRAMES: u32 = 2;

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
    /// The stripes' peak intensity (grey levels) in each cell that holds a height, row-major like `z` (NaN
    /// elsewhere): the mean of the samples in a cell, and between the samples of a stripe along x the straight line
    /// between theirs. `None` where the range image does not say (one from elsewhere). A laser profiler's intensity
    /// image, registered with the heights; inspection also reads partly lit sheets at a hole's rim from it
    /// ([`crate::detect`]).
    pub intensity: Option<Vec<f32>>,
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

/// A grid index as `f64`, through `i64`: the same value for any index a grid can have (below 2^53), and one
/// instruction on the baseline x86-64 target, where `usize as f64` takes a sequence for the unsigned case (the
/// per-cell and per-sample loops of accumulation and of the golden comparison convert an index or two each).
#[inline]
pub(crate) fn index_f64(i: usize) -> f64 {
    i as i64 as f64
}

/// The floor of a non-negative, finite fractional cell index below 2^63, as an index: truncation through `i64`
/// (for such values the same as `as usize`, which on the baseline x86-64 target takes a longer sequence for the
/// unsigned case).
#[inline]
pub(crate) fn floor_index(f: f64) -> usize {
    f as i64 as usize
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
    if !(i >= 0.0 && j >= 0.0 && i < index_f64(width) && j < index_f64(height)) {
        return None;
    }
    Some(floor_index(j) * width + floor_index(i))
}

/// Largest distance (mm) between the polynomial filled between two samples and their chord; beyond it, the chord.
/// A bump's top between samples 0.5 mm apart lies 0.03 mm above the chord at a curvature of 1/mm.
const MAX_BOW_MM: f64 = 0.1;

/// One sample of a track (a stripe and image row across frames). 32 bytes: a scan's samples are as many as its
/// points, and sorting them into tracks is a scattered write per point.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
struct Sample {
    /// Frame index (a scan of 2^32 frames does not fit in memory; saturated beyond).
    frame: u32,
    /// The peak intensity, as the profile point has it.
    intensity: f32,
    x: f64,
    y: f64,
    z: f64,
}

/// The polynomial through up to four nodes (distinct x) in Newton's form: its divided differences are worked out
/// once per interval, and each cell costs three multiplications.
#[derive(Debug, Clone, Copy)]
struct Newton {
    x: [f64; 4],
    c: [f64; 4],
    n: usize,
}

impl Newton {
    fn through(nodes: &[(f64, f64)]) -> Self {
        let n = nodes.len().min(4);
        let mut x = [0.0; 4];
        let mut c = [0.0; 4];
        for (k, &(xk, zk)) in nodes.iter().take(n).enumerate() {
            x[k] = xk;
            c[k] = zk;
        }
        // In place: c[k] becomes f[x0..xk].
        for order in 1..n {
            for k in (order..n).rev() {
                c[k] = (c[k] - c[k - 1]) / (x[k] - x[k - order]);
            }
        }
        Self { x, c, n }
    }

    #[inline]
    fn at(&self, t: f64) -> f64 {
        let mut z = 0.0;
        for k in (0..self.n).rev() {
            z = z * (t - self.x[k]) + self.c[k];
        }
        z
    }
}

/// The samples of every track (a stripe and image row) of a scan, in frame order: a counting sort by track.
#[derive(Debug, Clone, PartialEq)]
struct Tracks {
    /// Track k's samples are `samples[start[k]..start[k + 1]]`; track k is stripe `k / rows`, image row `k % rows`.
    start: Vec<usize>,
    samples: Vec<Sample>,
    rows: usize,
    /// Point j of profile i is sample `slot[first[i] + j]`.
    first: Vec<usize>,
    slot: Vec<u32>,
}

impl Tracks {
    fn of(profiles: &[Profile]) -> Self {
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
        let key = |p: &ProfilePoint| usize::from(p.stripe) * rows + p.row as usize;
        let mut start = vec![0usize; rows * stripes + 1];
        for p in profiles.iter().flat_map(|p| &p.points) {
            start[key(p) + 1] += 1;
        }
        for k in 1..start.len() {
            start[k] += start[k - 1];
        }
        let mut next = start.clone();
        let n = start[rows * stripes];
        let mut samples = vec![Sample::default(); n];
        let mut first = Vec::with_capacity(profiles.len() + 1);
        let mut slot = Vec::with_capacity(n);
        for prof in profiles {
            first.push(slot.len());
            for p in &prof.points {
                let k = key(p);
                samples[next[k]] = Sample::of(prof, p);
                // A scan of more than 4 billion points does not fit in memory before this.
                slot.push(next[k] as u32);
                next[k] += 1;
            }
        }
        first.push(slot.len());
        Self {
            start,
            samples,
            rows,
            first,
            slot,
        }
    }

    fn len(&self) -> usize {
        self.start.len() - 1
    }

    fn track(&self, k: usize) -> &[Sample] {
        &self.samples[self.start[k]..self.start[k + 1]]
    }

    /// Whether `profiles` have as many points each as the profiles these tracks were made of.
    fn counts_fit(&self, profiles: &[Profile]) -> bool {
        profiles.len() + 1 == self.first.len()
            && profiles
                .iter()
                .zip(self.first.windows(2))
                .all(|(p, w)| p.points.len() == w[1] - w[0])
    }

    /// Track, sample and new value of point `j` of profile `i` of `profiles` (of the same counts), when it is in
    /// the same track (stripe and row) and frame as these tracks have it.
    fn find(&self, profiles: &[Profile], i: usize, j: usize) -> Option<(usize, usize, Sample)> {
        let prof = profiles.get(i)?;
        let p = prof.points.get(j)?;
        let s = *self.slot.get(self.first.get(i)? + j)? as usize;
        let k = usize::from(p.stripe) * self.rows + p.row as usize;
        let new = Sample::of(prof, p);
        let fits = (p.row as usize) < self.rows
            && k < self.len()
            && (self.start[k]..self.start[k + 1]).contains(&s)
            && self.samples[s].frame == new.frame;
        fits.then_some((k, s, new))
    }
}

impl Sample {
    fn of(prof: &Profile, p: &ProfilePoint) -> Self {
        Self {
            frame: u32::try_from(prof.frame).unwrap_or(u32::MAX),
            intensity: p.intensity,
            x: p.x_mm,
            y: p.y_mm,
            z: p.z_mm,
        }
    }
}

/// Grid rows a band filled by one thread holds at least.
const MIN_BAND_ROWS: usize = 16;

/// What filling a grid reads: its geometry and the fill's limits (shared by the threads that fill bands of it).
#[derive(Debug, Clone, Copy)]
struct Layout {
    origin: [f64; 2],
    spacing: [f64; 2],
    width: usize,
    height: usize,
    max_fill_mm: f64,
    max_fill_step_mm: f64,
}

/// The sums of a run of whole grid rows, from cell `first` on: the whole grid, or one band of it; additions to
/// cells outside it are left to the band that holds them.
struct Cells<'a> {
    first: usize,
    sum: &'a mut [f64],
    intensity: &'a mut [f32],
    count: &'a mut [u32],
}

impl Cells<'_> {
    #[inline]
    fn add(&mut self, k: usize, z: f64, intensity: f64, sign: i32) {
        let Some(o) = k.checked_sub(self.first).filter(|&o| o < self.sum.len()) else {
            return;
        };
        self.sum[o] += f64::from(sign) * z;
        self.intensity[o] += (f64::from(sign) * intensity) as f32;
        self.count[o] = self.count[o].wrapping_add_signed(sign);
    }
}

impl Layout {
    /// The grid rows the cells of track `t` can lie in (first and last): one more on each side than its samples'
    /// own rows (the cells filled between two samples lie between theirs, up to the rounding of the position);
    /// `None` when no sample has a finite y (such a track adds nothing).
    fn rows_of(&self, t: &[Sample]) -> Option<(usize, usize)> {
        let (lo, hi) = t
            .iter()
            .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), s| {
                (lo.min(s.y), hi.max(s.y))
            });
        if !(lo.is_finite() && hi.is_finite()) {
            return None;
        }
        // Rows run along −y.
        let row = |y: f64| {
            floor_index(
                ((self.origin[1] - y) / self.spacing[1] + 0.5).clamp(0.0, index_f64(self.height)),
            )
        };
        Some((
            row(hi).saturating_sub(1),
            (row(lo) + 1).min(self.height.saturating_sub(1)),
        ))
    }

    #[inline]
    fn add(&self, cells: &mut Cells<'_>, x: f64, y: f64, z: f64, intensity: f64, sign: i32) {
        if let Some(k) = cell_index(self.origin, self.spacing, self.width, self.height, x, y) {
            cells.add(k, z, intensity, sign);
        }
    }

    /// Adds (`SIGN` 1) or takes back (−1) one track: its samples and the cells filled between them.
    fn add_track<const SIGN: i32>(&self, cells: &mut Cells<'_>, t: &[Sample]) {
        for (i, s) in t.iter().enumerate() {
            self.add(cells, s.x, s.y, s.z, f64::from(s.intensity), SIGN);
            self.add_interval::<SIGN>(cells, t, i);
        }
    }

    /// Adds or takes back samples `samples` of track `t` and the cells filled in its intervals `intervals`.
    fn add_part<const SIGN: i32>(
        &self,
        cells: &mut Cells<'_>,
        t: &[Sample],
        samples: &[usize],
        intervals: &[usize],
    ) {
        for &i in samples {
            let s = &t[i];
            self.add(cells, s.x, s.y, s.z, f64::from(s.intensity), SIGN);
        }
        for &i in intervals {
            self.add_interval::<SIGN>(cells, t, i);
        }
    }

    /// Adds or takes back the cells filled between samples `i` and `i + 1` of track `t` (none when they are not
    /// linked): they depend on samples `i − 1 ..= i + 2` alone.
    fn add_interval<const SIGN: i32>(&self, cells: &mut Cells<'_>, t: &[Sample], i: usize) {
        if i + 1 < t.len() && self.linked(&t[i], &t[i + 1]) {
            let before = (i > 0 && self.linked(&t[i - 1], &t[i])).then(|| &t[i - 1]);
            let after = t.get(i + 2).filter(|n| self.linked(&t[i + 1], n));
            self.fill(cells, &t[i], &t[i + 1], before, after, SIGN);
        }
    }

    /// Whether consecutive samples `a` and `b` of a track are joined.
    fn linked(&self, a: &Sample, b: &Sample) -> bool {
        b.frame > a.frame
            && b.frame - a.frame <= MAX_FILL_FRAMES
            && (b.x - a.x).abs() <= self.max_fill_mm
            && (b.z - a.z).abs() <= self.max_fill_step_mm
    }

    /// Fills the cells strictly between `a` and `b` along x, by the polynomial through them and the linked samples
    /// around them (x strictly monotonic along the samples used; otherwise fewer of them).
    fn fill(
        &self,
        cells: &mut Cells<'_>,
        a: &Sample,
        b: &Sample,
        before: Option<&Sample>,
        after: Option<&Sample>,
        sign: i32,
    ) {
        let dx = self.spacing[0];
        let rising = b.x > a.x;
        let ordered = |p: &Sample, q: &Sample| if rising { q.x > p.x } else { q.x < p.x };
        // Neighbours much closer to the interval than its own length make a wild polynomial: left out.
        let span = (b.x - a.x).abs();
        let before = before.filter(|p| ordered(p, a) && (a.x - p.x).abs() >= 0.5 * span);
        let after = after.filter(|q| ordered(b, q) && (q.x - b.x).abs() >= 0.5 * span);
        let mut nodes = [(0.0, 0.0); 4];
        let mut n = 0;
        for s in [before, Some(a), Some(b), after].into_iter().flatten() {
            nodes[n] = (s.x, s.z);
            n += 1;
        }
        let poly = Newton::through(&nodes[..n]);
        let (xa, xb) = (a.x.min(b.x), a.x.max(b.x));
        // The columns strictly between the samples, from a cell or two more on each side (truncation, not a
        // library `floor`; the test below keeps exactly those strictly between). A column's centre is on the grid,
        // so its cell is known without the division `cell_index` makes; only the row is worked out, by the same
        // rounding. One division per interval, none per cell.
        let first = ((xa - self.origin[0]) / dx) as i64;
        let last = ((xb - self.origin[0]) / dx) as i64 + 1;
        let inv_span = 1.0 / (b.x - a.x);
        let dy = self.spacing[1];
        let (width, height) = (index_f64(self.width), index_f64(self.height));
        for c in first.max(0)..=last {
            let x = self.origin[0] + c as f64 * dx;
            if x <= xa || x >= xb {
                continue;
            }
            if c as f64 >= width {
                break;
            }
            let t = (x - a.x) * inv_span;
            let chord = a.z + t * (b.z - a.z);
            // The curve may leave the chord by what a smooth surface does between samples, no more (a noisy or
            // kinked neighbour must not swing it).
            let z = poly.at(x);
            let z = if (z - chord).abs() <= MAX_BOW_MM {
                z
            } else {
                chord
            };
            let y = a.y + t * (b.y - a.y);
            // As in `cell_index`; NaN fails the comparisons too.
            let j = (self.origin[1] - y) / dy + 0.5;
            if !(j >= 0.0 && j < height) {
                continue;
            }
            let (ia, ib) = (f64::from(a.intensity), f64::from(b.intensity));
            let intensity = ia + t * (ib - ia);
            cells.add(floor_index(j) * self.width + c as usize, z, intensity, sign);
        }
    }
}

/// The grid a scan is accumulated on.
#[derive(Debug, Clone, PartialEq)]
pub struct RangeGrid {
    params: RangeParams,
    origin: [f64; 2],
    width: usize,
    height: usize,
    sum: Vec<f64>,
    /// Sums of the samples' intensities, like `sum` (single precision: grey levels need no more, and a cell costs
    /// 16 bytes instead of 20).
    intensity: Vec<f32>,
    count: Vec<u32>,
    /// The tracks the grid holds when one scan was accumulated on it (for [`RangeGrid::update`]).
    held: Option<Tracks>,
    /// Whether anything was accumulated.
    used: bool,
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
            intensity: vec![0.0; width * height],
            count: vec![0; width * height],
            held: None,
            used: false,
        })
    }

    /// What filling the grid reads.
    fn layout(&self) -> Layout {
        Layout {
            origin: self.origin,
            spacing: self.params.spacing_mm,
            width: self.width,
            height: self.height,
            max_fill_mm: self.params.max_fill_mm,
            max_fill_step_mm: self.params.max_fill_step_mm,
        }
    }

    /// All the grid's cells, to add to.
    fn cells(&mut self) -> Cells<'_> {
        Cells {
            first: 0,
            sum: &mut self.sum,
            intensity: &mut self.intensity,
            count: &mut self.count,
        }
    }

    /// Adds every track of `tracks`, in bands of grid rows filled in parallel ([`Layout::rows_of`]): each band takes
    /// the tracks that can reach it, in track order, and keeps only its own cells, so every cell receives the same
    /// additions in the same order as one pass over the tracks would make: the sums are the same to the bit, with
    /// any number of threads.
    fn add_tracks(&mut self, tracks: &Tracks) {
        let layout = self.layout();
        let threads = rayon::current_num_threads();
        let bands = (4 * threads).min(self.height / MIN_BAND_ROWS);
        if threads < 2 || bands < 2 {
            let mut cells = self.cells();
            for k in 0..tracks.len() {
                layout.add_track::<1>(&mut cells, tracks.track(k));
            }
            return;
        }
        let reach: Vec<Option<(usize, usize)>> = (0..tracks.len())
            .map(|k| layout.rows_of(tracks.track(k)))
            .collect();
        let band = self.height.div_ceil(bands) * self.width;
        self.sum
            .par_chunks_mut(band)
            .zip(self.intensity.par_chunks_mut(band))
            .zip(self.count.par_chunks_mut(band))
            .enumerate()
            .for_each(|(b, ((sum, intensity), count))| {
                let (j0, j1) = (
                    b * band / layout.width,
                    (b * band + sum.len()) / layout.width,
                );
                let mut cells = Cells {
                    first: b * band,
                    sum,
                    intensity,
                    count,
                };
                for (k, r) in reach.iter().enumerate() {
                    if r.is_some_and(|(lo, hi)| hi >= j0 && lo < j1) {
                        layout.add_track::<1>(&mut cells, tracks.track(k));
                    }
                }
            });
    }

    /// Adds the profiles of a scan, in frame order. Each stripe and image row is a track of samples along x (one a
    /// frame); between two consecutive samples of a track that are close enough (at most `MAX_FILL_FRAMES`
    /// frames, `max_fill_mm` and `max_fill_step_mm` apart) the cells strictly between them are filled by the cubic
    /// through those two samples and one more on each side (in x), or the quadratic or straight line through those
    /// of them that are linked the same way. A straight chord cuts the top of a bump: with samples h apart it lies
    /// `f'' t (h − t) / 2` below a surface of curvature f'' at t from a sample, on average `f'' h² / 12` (0.019 mm
    /// on a 2 mm bump's top at 0.5 mm a frame); the cubic's error is of fourth order. A neighbour less than half the
    /// interval away is left out, and where the curve would leave the chord by more than `MAX_BOW_MM` (more than
    /// a smooth surface bends between samples) the chord is used.
    pub fn accumulate(&mut self, profiles: &[Profile]) {
        let tracks = Tracks::of(profiles);
        self.add_tracks(&tracks);
        self.held = None;
        self.used = true;
    }

    /// [`RangeGrid::accumulate`], keeping the scan's tracks (the samples again, about a third of the profiles'
    /// memory) so that [`RangeGrid::update`] can change some of its points at the cost of their tracks alone.
    pub fn accumulate_to_update(&mut self, profiles: &[Profile]) {
        let tracks = Tracks::of(profiles);
        self.add_tracks(&tracks);
        // A second scan on the same grid: what it holds is no longer one scan's tracks.
        self.held = (!self.used).then_some(tracks);
        self.used = true;
    }

    /// Makes the grid hold `profiles`, the scan accumulated on it by [`RangeGrid::accumulate_to_update`] with the
    /// points `moved` (profile and point indices) changed in height or place: only what they touch is taken back and
    /// added again — each moved sample, and the cells filled between the samples of its track whose polynomial it is
    /// a node of (two intervals before it to one after) — so the cost follows the points moved, not the scan or
    /// their tracks' length (the sums may differ from a fresh accumulation in their last bits). Points not listed
    /// must be as they were accumulated. When `profiles` are not the same points (other counts, a moved point in
    /// another stripe, row or frame) or the grid does not hold one scan's tracks, it is emptied and `profiles`
    /// accumulated.
    pub fn update(
        &mut self,
        profiles: &[Profile],
        moved: impl IntoIterator<Item = (usize, usize)>,
    ) {
        let Some(mut held) = self.held.take().filter(|h| h.counts_fit(profiles)) else {
            return self.refill(profiles);
        };
        // (track, sample, new value), in sample order: by track, and along each track.
        let mut news = Vec::new();
        for (i, j) in moved {
            let Some(found) = held.find(profiles, i, j) else {
                return self.refill(profiles);
            };
            news.push(found);
        }
        news.sort_unstable_by_key(|&(_, s, _)| s);
        news.dedup_by_key(|&mut (_, s, _)| s);
        // Per touched track: its moved samples and the intervals they are nodes of (positions in the track).
        let mut parts: Vec<(usize, Vec<usize>, Vec<usize>)> = Vec::new();
        for &(k, s, _) in &news {
            let (first, len) = (held.start[k], held.start[k + 1] - held.start[k]);
            if parts.last().is_none_or(|(t, _, _)| *t != k) {
                parts.push((k, Vec::new(), Vec::new()));
            }
            let Some((_, samples, intervals)) = parts.last_mut() else {
                continue;
            };
            let p = s - first;
            samples.push(p);
            // Interval i (samples i and i + 1) has nodes i − 1 ..= i + 2; the track's last is len − 2.
            if len >= 2 {
                let lo = p
                    .saturating_sub(2)
                    .max(intervals.last().map_or(0, |&i| i + 1));
                let hi = (p + 1).min(len - 2);
                if lo <= hi {
                    intervals.extend(lo..=hi);
                }
            }
        }
        let work: usize = parts.iter().map(|(_, s, i)| s.len() + i.len()).sum();
        // Taking a part back costs what adding it does: past half the samples, adding all afresh is cheaper.
        let afresh = 2 * work > held.samples.len();
        let layout = self.layout();
        if !afresh {
            let mut cells = self.cells();
            for (k, samples, intervals) in &parts {
                layout.add_part::<{ -1 }>(&mut cells, held.track(*k), samples, intervals);
            }
        }
        for &(_, s, new) in &news {
            held.samples[s] = new;
        }
        if afresh {
            self.sum.fill(0.0);
            self.intensity.fill(0.0);
            self.count.fill(0);
            self.add_tracks(&held);
        } else {
            let mut cells = self.cells();
            for (k, samples, intervals) in &parts {
                layout.add_part::<1>(&mut cells, held.track(*k), samples, intervals);
            }
        }
        self.held = Some(held);
    }

    /// Empties the grid and accumulates `profiles`, keeping their tracks.
    fn refill(&mut self, profiles: &[Profile]) {
        self.sum.fill(0.0);
        self.intensity.fill(0.0);
        self.count.fill(0);
        self.used = false;
        self.accumulate_to_update(profiles);
    }

    /// The range image: the mean height and intensity of each cell.
    pub fn image(&self) -> RangeImage {
        fn mean(sums: impl Iterator<Item = f64>, count: &[u32]) -> Vec<f32> {
            sums.zip(count)
                .map(|(s, &c)| {
                    if c == 0 {
                        f32::NAN
                    } else {
                        (s / f64::from(c)) as f32
                    }
                })
                .collect()
        }
        RangeImage {
            origin_mm: self.origin,
            spacing_mm: self.params.spacing_mm,
            width: self.width,
            height: self.height,
            z: mean(self.sum.iter().copied(), &self.count),
            intensity: Some(mean(
                self.intensity.iter().map(|&i| f64::from(i)),
                &self.count,
            )),
        }
    }
}

#[cfg(test)]
mod tests;
