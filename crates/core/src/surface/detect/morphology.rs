//! Binary masks on the range image's grid: connected components, distances, bit-packed morphology and the
//! part's outline (row extremes, convex hull rows).

/// Labels 4- or 8-connected components of cells where `member` holds; returns (labels, sizes); label 0 = none.
/// Components are numbered in raster order of their first cell.
///
/// Run-based two-pass labelling: the runs of member cells of each row are found once, runs that touch a run of the
/// row above are merged in a union-find, and the labels are written run by run. `member` is evaluated once per cell
/// (the breadth-first search it replaces looked at every cell up to nine times and took 5 ms on an 841 x 641 grid).
pub(super) fn components(
    w: usize,
    h: usize,
    member: impl Fn(usize) -> bool,
    eight: bool,
) -> (Vec<u32>, Vec<usize>) {
    pub(super) fn find(parent: &mut [usize], mut a: usize) -> usize {
        while parent[a] != a {
            parent[a] = parent[parent[a]];
            a = parent[a];
        }
        a
    }
    // Runs: (row, start, end exclusive); row_start[j] = index of the first run of row j.
    let mut runs: Vec<(usize, usize, usize)> = Vec::new();
    let mut row_start = vec![0usize; h + 1];
    for (j, start) in row_start.iter_mut().take(h).enumerate() {
        *start = runs.len();
        let mut i = 0;
        while i < w {
            if member(j * w + i) {
                let a = i;
                while i < w && member(j * w + i) {
                    i += 1;
                }
                runs.push((j, a, i));
            } else {
                i += 1;
            }
        }
    }
    row_start[h] = runs.len();
    let mut parent: Vec<usize> = (0..runs.len()).collect();
    let reach = usize::from(eight);
    for j in 1..h {
        let (mut p, p_end) = (row_start[j - 1], row_start[j]);
        for r in row_start[j]..row_start[j + 1] {
            let (_, a, b) = runs[r];
            // Runs above that end before this one starts (with the diagonal reach) cannot touch it or later ones.
            while p < p_end && runs[p].2 + reach <= a {
                p += 1;
            }
            let mut q = p;
            while q < p_end && runs[q].1 < b + reach {
                let (x, y) = (find(&mut parent, r), find(&mut parent, q));
                if x != y {
                    // The root is always the earlier run: labels follow raster order.
                    parent[x.max(y)] = x.min(y);
                }
                q += 1;
            }
        }
    }
    let mut label = vec![0u32; w * h];
    let mut sizes = vec![0usize];
    let mut id_of = vec![0u32; runs.len()];
    for r in 0..runs.len() {
        let root = find(&mut parent, r);
        if root == r {
            id_of[r] = sizes.len() as u32;
            sizes.push(0);
        }
        let id = id_of[root];
        let (j, a, b) = runs[r];
        label[j * w + a..j * w + b].fill(id);
        sizes[id as usize] += b - a;
    }
    (label, sizes)
}

/// Pieces of the part smaller than this (mm²), and smaller than a twentieth of the largest, are debris.
pub(super) const MIN_PIECE_MM2: f64 = 25.0;

/// How far outside a found hole's bounding box an unnamed steep region ("anomaly") is still taken for that hole's
/// wall, mm: the wall of a through-hole seen in perspective, and the half-lit stripes on its rim, lie within a
/// millimetre of the gap.
pub const HOLE_WALL_MARGIN_MM: f64 = 1.0;
/// Half-width (cells) of the thickest channel of missing data that cannot join a hole to the outside or to another
/// gap ([`super::detect`], step 3): 2 cells, so channels up to 4 cells (0.9 mm at the default grid, about two frames of
/// travel) wide.
pub const GAP_CHANNEL_CELLS: usize = 2;

/// Distance (cells, 3-4 chamfer: within 8% of Euclidean) of every cell to the nearest cell where `outside` holds.
pub(super) fn distance_to(w: usize, h: usize, outside: impl Fn(usize) -> bool) -> Vec<f32> {
    let big = 3 * (w + h) as u32;
    let mut d: Vec<u32> = (0..w * h)
        .map(|k| if outside(k) { 0 } else { big })
        .collect();
    for j in 0..h {
        for i in 0..w {
            let k = j * w + i;
            let mut v = d[k];
            if i > 0 {
                v = v.min(d[k - 1] + 3);
            }
            if j > 0 {
                v = v.min(d[k - w] + 3);
                if i > 0 {
                    v = v.min(d[k - w - 1] + 4);
                }
                if i + 1 < w {
                    v = v.min(d[k - w + 1] + 4);
                }
            }
            d[k] = v;
        }
    }
    for j in (0..h).rev() {
        for i in (0..w).rev() {
            let k = j * w + i;
            let mut v = d[k];
            if i + 1 < w {
                v = v.min(d[k + 1] + 3);
            }
            if j + 1 < h {
                v = v.min(d[k + w] + 3);
                if i + 1 < w {
                    v = v.min(d[k + w + 1] + 4);
                }
                if i > 0 {
                    v = v.min(d[k + w - 1] + 4);
                }
            }
            d[k] = v;
        }
    }
    d.into_iter().map(|v| v as f32 / 3.0).collect()
}

/// A mask packed 64 cells to a word, row by row (`words` per row); bits past the last column stay clear.
pub(super) struct Bits {
    pub(super) w: usize,
    pub(super) h: usize,
    pub(super) words: usize,
    pub(super) b: Vec<u64>,
}

impl Bits {
    pub(super) fn pack(w: usize, h: usize, mask: &[bool], value: bool) -> Self {
        let words = w.div_ceil(64);
        let mut b = vec![0u64; words * h];
        for j in 0..h {
            for (q, chunk) in mask[j * w..(j + 1) * w].chunks(64).enumerate() {
                let mut word = 0u64;
                for (t, &m) in chunk.iter().enumerate() {
                    word |= u64::from(m == value) << t;
                }
                b[j * words + q] = word;
            }
        }
        Self { w, h, words, b }
    }

    pub(super) fn unpack(&self, set: bool) -> Vec<bool> {
        let mut out = vec![!set; self.w * self.h];
        for j in 0..self.h {
            for (q, chunk) in out[j * self.w..(j + 1) * self.w].chunks_mut(64).enumerate() {
                let word = self.b[j * self.words + q];
                for (t, o) in chunk.iter_mut().enumerate() {
                    if (word >> t) & 1 == 1 {
                        *o = set;
                    }
                }
            }
        }
        out
    }

    /// The cells of the grid not in the set.
    pub(super) fn complement(&mut self) {
        let tail = self.w % 64;
        for j in 0..self.h {
            for q in 0..self.words {
                let k = j * self.words + q;
                self.b[k] = !self.b[k];
                if q + 1 == self.words && tail != 0 {
                    self.b[k] &= (1u64 << tail) - 1;
                }
            }
        }
    }

    /// Dilation by a (2r+1)² square (r < 64), clipped to the grid.
    pub(super) fn dilate(&self, r: usize) -> Self {
        let (words, h) = (self.words, self.h);
        let mut rows = vec![0u64; words * h];
        for j in 0..h {
            let line = &self.b[j * words..(j + 1) * words];
            for q in 0..words {
                let mut acc = line[q];
                for s in 1..=r {
                    // Towards higher columns (bit t moves to t + s) and towards lower ones.
                    acc |= line[q] << s;
                    if q > 0 {
                        acc |= line[q - 1] >> (64 - s);
                    }
                    acc |= line[q] >> s;
                    if q + 1 < words {
                        acc |= line[q + 1] << (64 - s);
                    }
                }
                rows[j * words + q] = acc;
            }
        }
        let tail = self.w % 64;
        let mut b = vec![0u64; words * h];
        for j in 0..h {
            for jj in j.saturating_sub(r)..(j + r + 1).min(h) {
                for q in 0..words {
                    b[j * words + q] |= rows[jj * words + q];
                }
            }
            if tail != 0 {
                b[j * words + words - 1] &= (1u64 << tail) - 1;
            }
        }
        Self {
            w: self.w,
            h,
            words,
            b,
        }
    }
}

/// Dilation (`grow`: a cell becomes `grow` when any cell of its (2r+1)² window is) or erosion (`!grow`: the same
/// for false cells), the window clipped to the grid; on bit-packed rows, 64 cells at a time. (Detection uses the
/// compositions [`closing`] and [`opening`], which stay packed in between.)
#[cfg(test)]
pub(super) fn morph(w: usize, h: usize, mask: &[bool], r: usize, grow: bool) -> Vec<bool> {
    Bits::pack(w, h, mask, grow).dilate(r).unpack(grow)
}

/// Morphological closing of a mask by a (2r+1)² square: fills gaps up to 2r cells wide.
pub(super) fn closing(w: usize, h: usize, mask: &[bool], r: usize) -> Vec<bool> {
    // Dilate the set, then erode it: dilate its complement within the grid and take the complement back.
    let mut d = Bits::pack(w, h, mask, true).dilate(r);
    d.complement();
    d.dilate(r).unpack(false)
}

/// Morphological opening (3 x 3) of a mask: removes structures one or two cells thin (the walls of a hole seen in
/// perspective land as such slivers inside it) and keeps everything broader unchanged.
pub(super) fn opening(w: usize, h: usize, mask: &[bool]) -> Vec<bool> {
    opening_by(w, h, mask, 1)
}

/// Morphological opening of a mask by a (2r+1)² square: removes structures up to 2r cells thin.
pub(super) fn opening_by(w: usize, h: usize, mask: &[bool], r: usize) -> Vec<bool> {
    // Erode (dilate the complement), then dilate what is left.
    let mut e = Bits::pack(w, h, mask, false).dilate(r);
    e.complement();
    e.dilate(r).unpack(true)
}

/// Per row, the first and last column where `mask` holds; None for empty rows.
pub(super) fn row_extremes(w: usize, h: usize, mask: &[bool]) -> Vec<Option<(usize, usize)>> {
    (0..h)
        .map(|j| {
            let line = &mask[j * w..(j + 1) * w];
            let a = line.iter().position(|&m| m)?;
            let b = line.iter().rposition(|&m| m)?;
            Some((a, b))
        })
        .collect()
}

/// Per row, the [first, last] column inside the convex hull of the cells where `mask` holds (cell coordinates);
/// None for empty rows.
pub(super) fn hull_rows(w: usize, h: usize, mask: &[bool]) -> Vec<Option<(f64, f64)>> {
    // Extreme cells per row are enough for the hull.
    let ext = row_extremes(w, h, mask);
    let mut pts: Vec<(f64, f64)> = Vec::new();
    for (j, e) in ext.iter().enumerate() {
        if let Some((a, b)) = *e {
            pts.push((a as f64, j as f64));
            pts.push((b as f64, j as f64));
        }
    }
    pts.sort_by(|p, q| p.0.total_cmp(&q.0).then(p.1.total_cmp(&q.1)));
    pts.dedup();
    let cross = |o: (f64, f64), a: (f64, f64), b: (f64, f64)| {
        (a.0 - o.0) * (b.1 - o.1) - (a.1 - o.1) * (b.0 - o.0)
    };
    let mut hull: Vec<(f64, f64)> = Vec::new();
    for pass in 0..2 {
        let start = hull.len();
        let iter: Box<dyn Iterator<Item = &(f64, f64)>> = if pass == 0 {
            Box::new(pts.iter())
        } else {
            Box::new(pts.iter().rev())
        };
        for &p in iter {
            while hull.len() >= start + 2
                && cross(hull[hull.len() - 2], hull[hull.len() - 1], p) <= 0.0
            {
                hull.pop();
            }
            hull.push(p);
        }
        hull.pop();
    }
    let mut rows = vec![None; h];
    if hull.len() < 3 {
        for (j, e) in ext.iter().enumerate() {
            rows[j] = e.map(|(a, b)| (a as f64, b as f64));
        }
        return rows;
    }
    for (j, row) in rows.iter_mut().enumerate() {
        let y = j as f64;
        let (mut lo, mut hi) = (f64::INFINITY, f64::NEG_INFINITY);
        for t in 0..hull.len() {
            let (a, b) = (hull[t], hull[(t + 1) % hull.len()]);
            if (a.1 - y) * (b.1 - y) > 0.0 {
                continue;
            }
            if a.1 == b.1 {
                lo = lo.min(a.0.min(b.0));
                hi = hi.max(a.0.max(b.0));
            } else {
                let x = a.0 + (y - a.1) / (b.1 - a.1) * (b.0 - a.0);
                lo = lo.min(x);
                hi = hi.max(x);
            }
        }
        if lo <= hi {
            *row = Some((lo, hi));
        }
    }
    rows
}

/// The regions without part data that the outside of the grid cannot reach (`on_part`: the part's cells of a `w` x
/// `h` grid), each a list of cell indices. A thin channel of missing data (a stripe coding dropped for a frame or
/// two: a column up to 2 * [`GAP_CHANNEL_CELLS`] cells wide) is not part of a hole it touches: each gap is opened by
/// a (2r+1)² square on a window around it, and every core left is a gap of its own, given back the gap's cells
/// within r of it (the rim slivers the opening took) but no more of the channel. A gap that is all channel stays
/// whole. Also returns, per cell, whether it is off the part and open to the grid's border.
pub(super) fn enclosed_gaps(w: usize, h: usize, on_part: &[bool]) -> (Vec<Vec<usize>>, Vec<bool>) {
    let (olabel, _) = components(w, h, |k| !on_part[k], false);
    let mut outside_ids = std::collections::HashSet::new();
    for i in 0..w {
        outside_ids.insert(olabel[i]);
        outside_ids.insert(olabel[(h - 1) * w + i]);
    }
    for j in 0..h {
        outside_ids.insert(olabel[j * w]);
        outside_ids.insert(olabel[j * w + w - 1]);
    }
    let mut whole_gaps: std::collections::BTreeMap<u32, Vec<usize>> =
        std::collections::BTreeMap::new();
    for (k, &l) in olabel.iter().enumerate() {
        if l != 0 && !outside_ids.contains(&l) {
            whole_gaps.entry(l).or_default().push(k);
        }
    }
    let mut gaps: Vec<Vec<usize>> = Vec::new();
    for cells in whole_gaps.into_values() {
        let (mut i0, mut i1, mut j0, mut j1) = (w, 0, h, 0);
        for &k in &cells {
            let (i, j) = (k % w, k / w);
            i0 = i0.min(i);
            i1 = i1.max(i);
            j0 = j0.min(j);
            j1 = j1.max(j);
        }
        // One cell of margin, which is never the gap's (the gap is enclosed, so not on the grid's border).
        let (i0, j0) = (i0 - 1, j0 - 1);
        let (sw, sh) = (i1 + 2 - i0, j1 + 2 - j0);
        let mut member = vec![false; sw * sh];
        for &k in &cells {
            member[(k / w - j0) * sw + (k % w - i0)] = true;
        }
        let cores = opening_by(sw, sh, &member, GAP_CHANNEL_CELLS);
        let (clabel, csizes) = components(sw, sh, |q| cores[q], false);
        // No core (all channel), or one core that is the whole gap: the gap as it is.
        if csizes.len() < 2 || (csizes.len() == 2 && cores == member) {
            gaps.push(cells);
            continue;
        }
        let mut pieces: Vec<Vec<usize>> = vec![Vec::new(); csizes.len()];
        let r = GAP_CHANNEL_CELLS as isize;
        for &k in &cells {
            let (si, sj) = ((k % w - i0) as isize, (k / w - j0) as isize);
            let mut best: Option<(isize, u32)> = None;
            for dj in -r..=r {
                for di in -r..=r {
                    let (ii, jj) = (si + di, sj + dj);
                    if ii < 0 || jj < 0 || ii >= sw as isize || jj >= sh as isize {
                        continue;
                    }
                    let l = clabel[jj as usize * sw + ii as usize];
                    let d = di.abs().max(dj.abs());
                    if l != 0 && best.is_none_or(|(bd, _)| d < bd) {
                        best = Some((d, l));
                    }
                }
            }
            if let Some((_, l)) = best {
                pieces[l as usize].push(k);
            }
        }
        gaps.extend(pieces.into_iter().filter(|p| !p.is_empty()));
    }
    let open = olabel
        .iter()
        .map(|l| *l != 0 && outside_ids.contains(l))
        .collect();
    (gaps, open)
}
