//! The per-frame stripe coder: the row labelling (dynamic programming over each row), segments down the image with
//! the fuzzy rules, the segment vote and the final ordering check.

use super::row::*;
use super::*;
use crate::triangulate::FullModel;

/// A reusable stripe coder for one calibrated sensor: bands, rule tables and buffers persist across frames.
#[derive(Debug, Clone)]
pub struct StripeCoder {
    model: FullModel,
    params: CodingParams,
    width: u32,
    height: u32,
    stripes: usize,
    bands: Vec<Band>,
    edges: EdgeSkips,
    tables: FuzzyTables,
    order: Vec<u32>,
    items: Vec<Item>,
    row_start: Vec<usize>,
    outlier_marginal: Vec<f32>,
    /// Transition costs, tabulated.
    transitions: Transitions,
    /// How far above the row's best labelling a min-marginal can still change a decision
    /// ([`CodingParams::margin`] + [`CodingParams::segment_override_cost`], and a little for rounding).
    window: f32,
    /// Per row: the items whose forward cost is within the window (`alive`), and of those the ones whose
    /// min-marginal is (`live`), with each point's range.
    alive: Vec<u32>,
    alive_start: Vec<usize>,
    live: Vec<u32>,
    live_start: Vec<usize>,
    /// Per row, the items with a finite backward cost, point by point (`back_range`), as the backward pass needs
    /// them.
    back: Vec<Back>,
    back_range: Vec<(usize, usize)>,
    state: Vec<PointState>,
    segments: Vec<SegmentState>,
    open: Vec<u32>,
    /// Undistorted normalised coordinates of every point of the frame (computed once, used for every label).
    normalized: Vec<(f64, f64)>,
    /// The points of the row being read (fragments left out), in column order.
    row_points: Vec<u32>,
    /// Per point of the frame: a fragment (see [`CodingParams::fragment_intensity`]).
    fragment: Vec<bool>,
    /// Peak intensities of the row's uncut points (for the fragment test).
    levels: Vec<f32>,
    /// Per point of the frame: the label its segment voted for where the point's own row reads another by more
    /// than the override cost (the point is dropped), [`NO_LABEL`] elsewhere. It still orders the row's points only
    /// their row labelled (see [`StripeCoder::order_by_overruled`]).
    overruled: Vec<u16>,
    /// Per point of the row being checked against overruled points (reused).
    scratch_labels: Vec<u16>,
}

impl StripeCoder {
    /// A coder for frames of `width` x `height` pixels seen through `model`, with the shipped rule base.
    pub fn new(
        model: &FullModel,
        width: u32,
        height: u32,
        params: CodingParams,
    ) -> Result<Self, CoreError> {
        Self::with_tables(model, width, height, params, FuzzyTables::shipped()?)
    }

    /// A coder with the stripe-coding rules of an edited rule base.
    pub fn with_tables(
        model: &FullModel,
        width: u32,
        height: u32,
        params: CodingParams,
        tables: FuzzyTables,
    ) -> Result<Self, CoreError> {
        params.validate()?;
        let stripes = model.planes.len();
        if stripes == 0 || stripes > MAX_STRIPES {
            return Err(CoreError::InvalidParameter {
                field: "stripes",
                value: stripes.to_string(),
                reason: format!("the model must have 1 to {MAX_STRIPES} stripe planes"),
            });
        }
        if width == 0 || height == 0 {
            return Err(CoreError::InvalidParameter {
                field: "image size",
                value: format!("{width}x{height}"),
                reason: "must not be empty".into(),
            });
        }
        let mut bands = Vec::with_capacity(height as usize * stripes);
        let (u_first, u_last) = (0.0, f64::from(width) - 1.0);
        // Where a stripe cannot show one end of the range, its band runs this far beyond the image.
        let (search_lo, search_hi) = (-f64::from(width), 2.0 * f64::from(width));
        for v in 0..height {
            let v = f64::from(v);
            for k in 0..stripes {
                let z_left = model.height(k, u_first, v).unwrap_or(f64::NAN);
                let z_right = model.height(k, u_last, v).unwrap_or(f64::NAN);
                // NaN heights (a ray missing the plane) count as leftward, the paper's geometry.
                let leftward = z_right.partial_cmp(&z_left) != Some(std::cmp::Ordering::Greater);
                let at = |z: f64| model.column_at_height(k, v, z);
                let (a, b) = (at(params.min_height_mm), at(params.max_height_mm));
                let (u_min, u_max) = match (a, b) {
                    (Some(a), Some(b)) => (
                        a.min(b).clamp(search_lo, search_hi),
                        a.max(b).clamp(search_lo, search_hi),
                    ),
                    // The stripe reaches only one end of the range inside the searched columns: the band runs to
                    // the searched edge on the side the other end lies.
                    (Some(a), None) => {
                        if leftward {
                            (search_lo, a)
                        } else {
                            (a, search_hi)
                        }
                    }
                    (None, Some(b)) => {
                        if leftward {
                            (b, search_hi)
                        } else {
                            (search_lo, b)
                        }
                    }
                    (None, None) => (f64::INFINITY, f64::NEG_INFINITY),
                };
                bands.push(Band {
                    u_min: u_min as f32,
                    u_max: u_max as f32,
                    z_left: z_left as f32,
                    z_right: z_right as f32,
                    leftward,
                });
            }
        }
        let transitions = Transitions::new(&params);
        let edges = EdgeSkips::new(&bands, stripes, &params);
        // Sums of row costs are rounded differently along different passes: a hundredth of a stripe's cost covers
        // that many times over.
        let window = (params.margin.abs() + params.segment_override_cost.abs()) as f32 + 0.01;
        Ok(Self {
            model: model.clone(),
            params,
            width,
            height,
            stripes,
            bands,
            edges,
            tables,
            order: Vec::new(),
            items: Vec::new(),
            row_start: Vec::new(),
            outlier_marginal: Vec::new(),
            transitions,
            window,
            alive: Vec::new(),
            alive_start: Vec::new(),
            live: Vec::new(),
            live_start: Vec::new(),
            back: Vec::new(),
            back_range: Vec::new(),
            state: Vec::new(),
            segments: Vec::new(),
            open: Vec::new(),
            normalized: Vec::new(),
            row_points: Vec::new(),
            fragment: Vec::new(),
            levels: Vec::new(),
            overruled: Vec::new(),
            scratch_labels: Vec::new(),
        })
    }

    /// The parameters.
    pub fn params(&self) -> &CodingParams {
        &self.params
    }

    /// The frame size the coder was built for, (width, height) in pixels.
    pub fn image_size(&self) -> (u32, u32) {
        (self.width, self.height)
    }

    /// The column band of stripe `stripe` on row `row` over the measuring range, `(min, max)`.
    pub fn band(&self, row: u32, stripe: usize) -> Option<(f64, f64)> {
        if row >= self.height || stripe >= self.stripes {
            return None;
        }
        let b = self.bands[row as usize * self.stripes + stripe];
        Some((f64::from(b.u_min), f64::from(b.u_max)))
    }

    /// Codes the points of one frame (extracted along rows, any order) into `out`.
    pub fn code_into(&mut self, points: &[StripePoint], out: &mut Coding) {
        out.stripes.clear();
        out.stripes.resize(points.len(), None);
        out.near.clear();
        out.near.resize(points.len(), [NO_LABEL; 3]);
        out.row_confident.clear();
        out.row_confident.resize(points.len(), false);
        out.stats = CodingStats {
            points: points.len(),
            ..CodingStats::default()
        };
        // Column order within rows; points on rows outside the image are dropped as noise.
        self.order.clear();
        self.order
            .extend((0..points.len() as u32).filter(|&i| points[i as usize].row < self.height));
        self.order.sort_by(|&a, &b| {
            let (pa, pb) = (&points[a as usize], &points[b as usize]);
            pa.row.cmp(&pb.row).then(pa.x.total_cmp(&pb.x))
        });
        self.state.clear();
        self.state.resize(
            points.len(),
            PointState {
                best: NO_LABEL,
                confident: false,
                alternatives: [(NO_LABEL, f32::INFINITY); 2],
                z: f32::NAN,
                segment: NO_SEGMENT,
            },
        );
        let camera = &self.model.camera;
        self.normalized.clear();
        self.normalized.extend(
            points
                .iter()
                .map(|p| camera.normalized(p.x, f64::from(p.row))),
        );
        self.fragment.clear();
        self.fragment.resize(points.len(), false);
        self.overruled.clear();
        self.overruled.resize(points.len(), NO_LABEL);
        // Pass 1: each row on its own.
        let mut start = 0;
        while start < self.order.len() {
            let row = points[self.order[start] as usize].row;
            let mut end = start + 1;
            while end < self.order.len() && points[self.order[end] as usize].row == row {
                end += 1;
            }
            // Fragments (cut points much dimmer than the row's stripes, and points much dimmer than the light beside
            // them: a sheet's tail on a corner, a glint) take no part in reading the row: they follow the segment they continue (pass 3). A cut point as bright as the
            // stripes is a stripe half hidden by an edge and is read with the others.
            self.row_points.clear();
            self.row_points.extend(
                self.order[start..end]
                    .iter()
                    .copied()
                    .filter(|&i| !points[i as usize].cut),
            );
            if self.row_points.len() < end - start || self.params.faint_intensity > 0.0 {
                self.levels.clear();
                self.levels.extend(
                    self.row_points
                        .iter()
                        .map(|&i| points[i as usize].intensity),
                );
                let reference = if self.levels.is_empty() {
                    0.0
                } else {
                    let mid = self.levels.len() / 2;
                    *self.levels.select_nth_unstable_by(mid, f32::total_cmp).1
                };
                let dim = self.params.fragment_intensity as f32 * reference;
                let faint = self.params.faint_intensity as f32;
                self.row_points.clear();
                let row = &self.order[start..end];
                for (n, &i) in row.iter().enumerate() {
                    let p = &points[i as usize];
                    let level = |m: Option<&u32>| m.map_or(0.0, |&j| points[j as usize].intensity);
                    let beside =
                        level(n.checked_sub(1).and_then(|m| row.get(m))).max(level(row.get(n + 1)));
                    let fragment = (p.cut && p.intensity < dim) || p.intensity < faint * beside;
                    self.fragment[i as usize] = fragment;
                    if !fragment {
                        self.row_points.push(i);
                    }
                }
            }
            if !self.row_points.is_empty() {
                self.label_row(points, row);
            }
            start = end;
        }
        // Pass 2: segments down the image.
        self.link_segments(points);
        // Pass 3: votes, then the final ordering check per row.
        self.decide(points, out);
    }

    #[inline]
    fn band_of(&self, row: u32, k: usize) -> &Band {
        &self.bands[row as usize * self.stripes + k]
    }

    /// Cost of stripes hidden beyond the end of a row on the projector's side by a rise from the belt to the
    /// first point there (height `z`): `None` when the point is too low for that.
    fn belt_rise_skip(&self, n: usize, z: f32) -> Option<f32> {
        (n > 0 && f64::from(z) >= self.params.rise_mm)
            .then_some((self.params.rise_skip_cost + n as f64 * self.params.edge_skip_cost) as f32)
    }

    /// Cost of stripes `0 .. label` missing left of the first labelled point (height `z`): each out of view at
    /// that height, or (projector on the left) all hidden by the rise from the belt to the point.
    fn left_skip(&self, row: u32, label: u16, z: f32) -> f32 {
        let rise = self.params.rise_mm as f32;
        let each: f32 = (0..usize::from(label))
            .map(|k| {
                let b = self.band_of(row, k);
                // Out of view at this height: the stripe shows heights above z_left only left of column 0.
                let gone = b.z_left.is_nan()
                    || if b.leftward {
                        z >= b.z_left - rise
                    } else {
                        z <= b.z_left + rise
                    };
                if gone {
                    self.params.edge_skip_cost as f32
                } else {
                    self.params.skip_cost as f32
                }
            })
            .sum();
        let projector_left = self.band_of(row, usize::from(label)).leftward;
        match self.belt_rise_skip(usize::from(label), z) {
            Some(c) if projector_left => each.min(c),
            _ => each,
        }
    }

    /// Cost of stripes after `label` missing right of the last labelled point (height `z`).
    fn right_skip(&self, row: u32, label: u16, z: f32) -> f32 {
        let rise = self.params.rise_mm as f32;
        let each: f32 = (usize::from(label) + 1..self.stripes)
            .map(|k| {
                let b = self.band_of(row, k);
                let gone = b.z_right.is_nan()
                    || if b.leftward {
                        z <= b.z_right + rise
                    } else {
                        z >= b.z_right - rise
                    };
                if gone {
                    self.params.edge_skip_cost as f32
                } else {
                    self.params.skip_cost as f32
                }
            })
            .sum();
        let projector_left = self.band_of(row, usize::from(label)).leftward;
        match self.belt_rise_skip(self.stripes - 1 - usize::from(label), z) {
            Some(c) if !projector_left => each.min(c),
            _ => each,
        }
    }

    /// Pass 1 over the points `row_points` of one row.
    ///
    /// Forward and backward passes of dynamic programming give each (point, label) item the cost of the best row
    /// labelling through it (its min-marginal). Only costs within [`StripeCoder::window`] of the row's best
    /// labelling ever change a decision (a label is kept by a margin, alternatives are offered within
    /// [`CodingParams::segment_override_cost`]), so the backward pass and the false-point pass visit only the
    /// items whose forward cost is within that window: every labelling through another item costs more, so the
    /// min-marginals within the window are exactly what the full passes give, and the ones beyond stay beyond.
    fn label_row(&mut self, points: &[StripePoint], row: u32) {
        let m = self.row_points.len();
        let q = self.params.outlier_cost as f32;
        let run = self.params.max_outlier_run;
        self.items.clear();
        self.row_start.clear();
        for j in 0..m {
            self.row_start.push(self.items.len());
            let idx = self.row_points[j] as usize;
            let u = points[idx].x;
            let (xn, yn) = self.normalized[idx];
            let mut cursor = EdgeCursor::START;
            for k in 0..self.stripes {
                let b = self.band_of(row, k);
                let uf = u as f32;
                if !(uf >= b.u_min && uf <= b.u_max) {
                    continue;
                }
                let sign = if b.leftward { 1.0 } else { -1.0 };
                if let Some(z) = self.model.height_normalized(k, xn, yn) {
                    let z = z as f32;
                    let (left, right) = self
                        .edges
                        .costs(&self.transitions, row, k as u16, z, &mut cursor)
                        .unwrap_or_else(|| {
                            (
                                self.left_skip(row, k as u16, z),
                                self.right_skip(row, k as u16, z),
                            )
                        });
                    self.items.push(Item {
                        j: j as u16,
                        label: k as u16,
                        z,
                        sign,
                        level: points[idx].intensity,
                        forward: f32::INFINITY,
                        backward: f32::INFINITY,
                        start: q * j as f32 + left,
                        end: q * (m - 1 - j) as f32 + right,
                    });
                }
            }
        }
        self.row_start.push(self.items.len());
        // The passes below visit pairs of items at most `run + 1` points apart with growing labels (items of one
        // point are in label order). A candidate whose cost before its transition already reaches the best found
        // cannot improve it (transition costs are never negative): its transition is not computed.
        let tr = &self.transitions;
        let (items, row_start) = (&mut self.items, &self.row_start);
        // Forward: best cost of the row's left part ending with this item labelled (nearest points first, whose
        // transitions skip no point and usually win).
        for bi in 0..items.len() {
            let b = items[bi];
            let jb = usize::from(b.j);
            let mut best = b.start;
            for ja in (jb.saturating_sub(run + 1)..jb).rev() {
                let gap = q * (jb - ja - 1) as f32;
                for a in &items[row_start[ja]..row_start[ja + 1]] {
                    if a.label > b.label {
                        break;
                    }
                    relax(&mut best, a.forward + gap, || {
                        tr.cost(a.label, b.label, a.z, b.z, b.sign, a.level, b.level)
                    });
                }
            }
            items[bi].forward = best;
        }
        // The row's best labelling (no point labelled at all: every stripe missing), and the items within the
        // window of it.
        let nothing = q * m as f32 + self.stripes as f32 * self.params.skip_cost as f32;
        let limit = items
            .iter()
            .fold(nothing, |g, it| g.min(it.forward + it.end))
            + self.window;
        self.alive.clear();
        self.alive_start.clear();
        for j in 0..m {
            self.alive_start.push(self.alive.len());
            self.alive.extend(
                (row_start[j]..row_start[j + 1])
                    .filter(|&i| items[i].forward <= limit)
                    .map(|i| i as u32),
            );
        }
        self.alive_start.push(self.alive.len());
        let (alive, alive_start) = (&self.alive, &self.alive_start);
        // Backward: best cost of the right part given this item labelled, where it keeps the item within the
        // window; beyond that only "beyond" matters (infinity), so candidates that cannot come below it are not
        // computed either. Points right to left; each point's items with a finite cost are then copied together
        // (`back`), the only ones the points before it need.
        self.back.clear();
        self.back_range.clear();
        self.back_range.resize(m, (0, 0));
        for ja in (0..m).rev() {
            let first = self.back.len();
            for &ai in alive[alive_start[ja]..alive_start[ja + 1]].iter() {
                let a = items[ai as usize];
                let cap = limit - a.forward;
                let mut best = a.end.min(cap);
                for jb in ja + 1..(ja + run + 2).min(m) {
                    let gap = q * (jb - ja - 1) as f32;
                    let (s, e) = self.back_range[jb];
                    for b in &self.back[s..e] {
                        if b.label < a.label {
                            continue;
                        }
                        relax(&mut best, b.backward + gap, || {
                            tr.cost(a.label, b.label, a.z, b.z, b.sign, a.level, b.level)
                        });
                    }
                }
                if best < cap {
                    items[ai as usize].backward = best;
                    self.back.push(Back {
                        label: a.label,
                        z: a.z,
                        sign: a.sign,
                        level: a.level,
                        backward: best,
                    });
                }
            }
            self.back_range[ja] = (first, self.back.len());
        }
        // Min-marginals of "point j is false".
        self.outlier_marginal.clear();
        self.outlier_marginal.resize(m, nothing);
        let mut prefix = f32::INFINITY; // best cost ending the labelling at a point left of j
        for j in 0..m {
            if j > 0 {
                for a in &items[row_start[j - 1]..row_start[j]] {
                    prefix = prefix.min(a.forward + a.end);
                }
            }
            self.outlier_marginal[j] = self.outlier_marginal[j].min(prefix);
        }
        let mut suffix = f32::INFINITY; // best cost starting the labelling at a point right of j
        for j in (0..m).rev() {
            if j + 1 < m {
                for b in &items[row_start[j + 1]..row_start[j + 2]] {
                    suffix = suffix.min(b.start + b.backward);
                }
            }
            self.outlier_marginal[j] = self.outlier_marginal[j].min(suffix);
        }
        // Labellings that declare the points strictly between two labelled ones false: only items whose own
        // min-marginal is within the window can be on such a labelling within it.
        self.live.clear();
        self.live_start.clear();
        for j in 0..m {
            self.live_start.push(self.live.len());
            self.live.extend(
                alive[alive_start[j]..alive_start[j + 1]]
                    .iter()
                    .copied()
                    .filter(|&i| {
                        let it = &items[i as usize];
                        it.forward + it.backward <= limit
                    }),
            );
        }
        self.live_start.push(self.live.len());
        let (live, live_start) = (&self.live, &self.live_start);
        for ja in 0..m {
            let before = &live[live_start[ja]..live_start[ja + 1]];
            if before.is_empty() {
                continue;
            }
            for jb in ja + 2..(ja + run + 2).min(m) {
                let gap = q * (jb - ja - 1) as f32;
                let after = &live[live_start[jb]..live_start[jb + 1]];
                // Only a labelling within the window counts; one whose cost without its transition already
                // reaches the best is not computed.
                let mut best = limit;
                for &ai in before {
                    let a = &items[ai as usize];
                    let base = a.forward + gap;
                    for &bi in after {
                        let b = &items[bi as usize];
                        if b.label < a.label || base + b.backward >= best {
                            continue;
                        }
                        let c = base
                            + tr.cost(a.label, b.label, a.z, b.z, b.sign, a.level, b.level)
                            + b.backward;
                        if c < best {
                            best = c;
                        }
                    }
                }
                if best < limit {
                    for o in &mut self.outlier_marginal[ja + 1..jb] {
                        *o = o.min(best);
                    }
                }
            }
        }
        // Decisions.
        let margin = self.params.margin as f32;
        for j in 0..m {
            let idx = self.row_points[j] as usize;
            let (mut best, mut best_label, mut best_z) = (f32::INFINITY, NO_LABEL, f32::NAN);
            // Runner-up (cost, label) pairs, cheapest first.
            let mut alt = [(f32::INFINITY, NO_LABEL); 2];
            for it in &self.items[self.row_start[j]..self.row_start[j + 1]] {
                let c = it.forward + it.backward;
                if c < best {
                    alt[1] = alt[0];
                    alt[0] = (best, best_label);
                    best = c;
                    best_label = it.label;
                    best_z = it.z;
                } else if c < alt[0].0 {
                    alt[1] = alt[0];
                    alt[0] = (c, it.label);
                } else if c < alt[1].0 {
                    alt[1] = (c, it.label);
                }
            }
            let second = alt[0].0;
            let outlier = self.outlier_marginal[j];
            let st = &mut self.state[idx];
            if best_label == NO_LABEL || outlier + margin <= best {
                st.best = NO_LABEL;
                st.confident = true;
            } else {
                st.best = best_label;
                st.z = best_z;
                st.confident = best + margin <= second.min(outlier);
                st.alternatives = alt.map(|(c, l)| (l, c - best));
            }
        }
    }

    /// Pass 2: links points of consecutive rows into segments with the fuzzy rules.
    fn link_segments(&mut self, points: &[StripePoint]) {
        self.segments.clear();
        self.open.clear();
        let max_gap = self.params.max_gap_rows;
        let mut i = 0;
        while i < self.order.len() {
            let row = points[self.order[i] as usize].row;
            // Close segments that can no longer be continued.
            self.open.retain(|&s| {
                let seg = &self.segments[s as usize];
                row - seg.last_row - 1 <= max_gap
            });
            while i < self.order.len() && points[self.order[i] as usize].row == row {
                let idx = self.order[i] as usize;
                i += 1;
                let st = self.state[idx];
                let p = &points[idx];
                let fragment = self.fragment[idx];
                if st.best == NO_LABEL && !fragment {
                    continue;
                }
                // The closest open segment that the rules let this point continue, and the point's height under
                // the segment's label.
                let mut chosen: Option<(u32, f64, f64)> = None;
                for &s in &self.open {
                    let seg = &self.segments[s as usize];
                    if seg.taken_row == row {
                        continue;
                    }
                    let gap = row - seg.last_row - 1;
                    let du = (p.x - seg.last_u).abs();
                    if du > self.params.link_px * (1.0 + f64::from(gap)) {
                        continue;
                    }
                    // Brightness: a stripe keeps it down one surface.
                    let (a, b) = (f64::from(p.intensity), f64::from(seg.last_intensity));
                    let ratio = self.params.link_intensity_ratio;
                    if a < ratio * b || ratio * a > b {
                        continue;
                    }
                    // Heights compared under the segment's label.
                    let (xn, yn) = self.normalized[idx];
                    let z = self
                        .model
                        .height_normalized(usize::from(seg.last_label), xn, yn)
                        .unwrap_or(f64::NAN);
                    let change = (z - f64::from(seg.last_z)).abs();
                    let ok = if gap == 0 {
                        self.tables.same_segment(z, change)
                    } else {
                        self.tables.same_segment(z, 0.0) && self.tables.bridge_gap(gap, change)
                    };
                    if ok && chosen.is_none_or(|(_, d, _)| du < d) {
                        chosen = Some((s, du, z));
                    }
                }
                if fragment {
                    // A fragment never starts a segment nor votes; it continues the one it lines up with.
                    if let Some((s, _, z)) = chosen {
                        let seg = &mut self.segments[s as usize];
                        seg.last_row = row;
                        seg.taken_row = row;
                        seg.last_u = p.x;
                        seg.last_intensity = p.intensity;
                        seg.last_z = z as f32;
                        self.state[idx].segment = s;
                    }
                    continue;
                }
                let (s, z_under_segment) = match chosen {
                    Some((s, _, z)) => (s, Some(z)),
                    None => {
                        // Rule 1: only points that are not very low start segments.
                        if !self.tables.same_segment(f64::from(st.z), 0.0) {
                            continue;
                        }
                        let s = self.segments.len() as u32;
                        self.segments.push(SegmentState::default());
                        self.open.push(s);
                        (s, None)
                    }
                };
                let seg = &mut self.segments[s as usize];
                seg.last_row = row;
                seg.taken_row = row;
                seg.last_u = p.x;
                seg.last_intensity = p.intensity;
                // Heights down the segment are compared under the label its last settled point had: a row read one
                // stripe over without confidence (a near tie) would otherwise carry that reading on, and under it a
                // 10 mm plate can look like a 3 mm one, low enough for rule 1 to end the segment there.
                match z_under_segment {
                    Some(z) if !st.confident => seg.last_z = z as f32,
                    _ => {
                        seg.last_label = st.best;
                        seg.last_z = st.z;
                    }
                }
                seg.length += 1;
                if st.confident {
                    seg.total_votes += 1;
                    if let Some(v) = seg.votes.iter_mut().find(|v| v.1 > 0 && v.0 == st.best) {
                        v.1 += 1;
                    } else if let Some(v) = seg.votes.iter_mut().find(|v| v.1 == 0) {
                        *v = (st.best, 1);
                    }
                }
                self.state[idx].segment = s;
            }
        }
    }

    /// Whether points `a` and `b` (left to right in `row`) are one sheet `label` seen twice by their row's own
    /// reading: both read as `label`, the right one lower by more than a jump.
    fn split(&self, row: u32, a: usize, b: usize, label: u16) -> bool {
        let (sa, sb) = (&self.state[a], &self.state[b]);
        let sign = if self.band_of(row, usize::from(label)).leftward {
            1.0
        } else {
            -1.0
        };
        sa.best == label
            && sb.best == label
            && self
                .transitions
                // One sheet twice: the peaks are not compared.
                .cost(label, label, sa.z, sb.z, sign, 0.0, 0.0)
                .is_finite()
    }

    /// The ordering check against overruled points (`self.order[start..end]`, one row): a point only its row
    /// labelled (on the belt, in no segment) that lies between overruled points of its row is dropped where its
    /// label breaks the order with the labels their segments voted for. Where a plate's height moves its stripes by
    /// one pitch, a row near the plate's edge can read the whole plate one stripe over with confidence: the
    /// segments running down the plate drop those readings, but the stripe that lands on its neighbour's belt
    /// column reads as belt, out of every segment, and kept its row's label. Only between overruled points: beyond
    /// the last of them the belt past a tall part may show the part's last sheets a second time.
    fn order_by_overruled(&mut self, start: usize, end: usize, out: &mut Coding) {
        let row = &self.order[start..end];
        if row
            .iter()
            .all(|&idx| self.overruled[idx as usize] == NO_LABEL)
        {
            return;
        }
        // Smallest overruled label to the right of each point (NO_LABEL: none).
        let mut right_min = std::mem::take(&mut self.scratch_labels);
        right_min.clear();
        right_min.resize(row.len(), NO_LABEL);
        let mut right = NO_LABEL;
        for (k, &idx) in row.iter().enumerate().rev() {
            right_min[k] = right;
            right = right.min(self.overruled[idx as usize]);
        }
        // Largest overruled label to the left.
        let mut left: Option<u16> = None;
        for (k, &idx) in row.iter().enumerate() {
            let idx = idx as usize;
            if let (Some(l), Some(lm)) = (out.stripes[idx], left)
                && self.state[idx].segment == NO_SEGMENT
                && right_min[k] != NO_LABEL
                && (lm >= l || right_min[k] <= l)
            {
                out.stripes[idx] = None;
            }
            let o = self.overruled[idx];
            if o != NO_LABEL {
                left = Some(left.map_or(o, |lm| lm.max(o)));
            }
        }
        self.scratch_labels = right_min;
    }

    /// Pass 3: segment votes, per-point decisions and the ordering check.
    fn decide(&mut self, points: &[StripePoint], out: &mut Coding) {
        let share = self.params.min_vote_share;
        for &idx in &self.order {
            let idx = idx as usize;
            let st = self.state[idx];
            let p = &points[idx];
            let fragment = self.fragment[idx];
            let label = if st.best == NO_LABEL && !(fragment && st.segment != NO_SEGMENT) {
                None
            } else if st.segment == NO_SEGMENT {
                // Belt points: their row's decision.
                st.confident.then_some(st.best)
            } else {
                let seg = &self.segments[st.segment as usize];
                if !self.tables.keep_segment(seg.length as usize) {
                    None
                } else {
                    let winner = seg.votes.iter().max_by_key(|v| v.1).copied();
                    match winner {
                        Some((w, c))
                            if c > 0
                                && f64::from(c) >= share * f64::from(seg.total_votes)
                                && f64::from(seg.total_votes)
                                    >= self.params.min_voting_share * f64::from(seg.length) =>
                        {
                            // A point the row labelling would label otherwise (even without confidence) is
                            // not relabelled: where a stripe on one surface lines up with its neighbour on
                            // another, segments link across the jump.
                            // Unless the winner is nearly as good for this row: a stripe missing from the
                            // middle of a row (it fell into a hole) lets the row be read one stripe over with a
                            // single height jump, cheaper than the missing stripe; the segment, running on
                            // above and below the hole, settles it.
                            let near = st.alternatives.iter().any(|&(l, d)| {
                                l == w && d <= self.params.segment_override_cost as f32
                            });
                            if !fragment && st.best != w && !near {
                                self.overruled[idx] = w;
                                None
                            } else {
                                let b = self.band_of(p.row, usize::from(w));
                                let uf = p.x as f32;
                                (uf >= b.u_min && uf <= b.u_max).then_some(w)
                            }
                        }
                        _ => None,
                    }
                }
            };
            out.stripes[idx] = label;
            let mut near = [NO_LABEL; 3];
            if st.best != NO_LABEL {
                near[0] = st.best;
                let mut n = 1;
                for &(l, d) in &st.alternatives {
                    if l != NO_LABEL && d <= self.params.segment_override_cost as f32 {
                        near[n] = l;
                        n += 1;
                    }
                }
            }
            out.near[idx] = near;
            out.row_confident[idx] = st.confident && st.best != NO_LABEL;
        }
        // Ordering: labels must grow with the column along every row (or repeat where the row's reading saw one
        // sheet twice, see `Transitions::cost`); drop both sides of a violation.
        let mut i = 0;
        while i < self.order.len() {
            let row = points[self.order[i] as usize].row;
            let mut end = i;
            while end < self.order.len() && points[self.order[end] as usize].row == row {
                end += 1;
            }
            let mut last: Option<(usize, u16)> = None;
            for &idx in &self.order[i..end] {
                let idx = idx as usize;
                if let Some(l) = out.stripes[idx] {
                    if let Some((prev, pl)) = last
                        && (pl > l || (pl == l && !self.split(row, prev, idx, l)))
                    {
                        out.stripes[prev] = None;
                        out.stripes[idx] = None;
                        last = None;
                        continue;
                    }
                    last = Some((idx, l));
                }
            }
            self.order_by_overruled(i, end, out);
            i = end;
        }
        for (idx, l) in out.stripes.iter().enumerate() {
            let st = &self.state[idx];
            match l {
                Some(_) => out.stats.coded += 1,
                None if st.best == NO_LABEL => out.stats.noise += 1,
                None if st.segment != NO_SEGMENT
                    && !self
                        .tables
                        .keep_segment(self.segments[st.segment as usize].length as usize) =>
                {
                    out.stats.noise += 1
                }
                None => out.stats.ambiguous += 1,
            }
        }
    }
}

#[cfg(test)]
mod tests;
