//! Temporal reconciliation of a scan's coding across frames (see [`reconcile`]).

use super::*;
use rayon::prelude::*;

/// Parameters of [`reconcile`].
#[derive(Debug, Clone, PartialEq)]
pub struct TemporalParams {
    /// Largest column change (px) between a point and the same stripe on the same row one frame later: the part
    /// moves one frame step (0.5 mm in the paper's set-up) and a smooth surface moves the stripe by a fraction of a
    /// pixel, a sheet sliding down a flank by one or two; a step of the surface (tens of pixels) ends the track.
    pub link_px: f64,
    /// Fewest coded points of a track that must agree on its label.
    pub min_votes: usize,
    /// Least share of the track's coded points that must agree.
    pub min_share: f64,
    /// Fewest agreeing points, in frames before and after (or on the one side there is, where the track starts or
    /// ends), for a track to overrule a label the point's own row settled (0: never), or to relabel a point at
    /// the track's end (or start) that only the segment vote coded. A single frame can be misread with confidence as a whole (a sheet's dim tail read as one
    /// more stripe shifts its row by one index) while the frames around it read the same stripes right.
    pub overrule_votes: usize,
    /// Fewest agreeing labels the segment vote gave the track's points (each label a row settled for the track
    /// counting two), in frames before and after or on the one side there is, for the track to overrule a label the
    /// point's own row settled when no other frame's row settled another (0: never). A band of rows can be read one
    /// stripe over with confidence in one frame while the frames around it, ambiguous row by row, were coded right by
    /// their segments.
    pub overrule_segment_votes: usize,
}

impl Default for TemporalParams {
    fn default() -> Self {
        Self {
            // Measured on the demo's 22 frames (wrong stripe indices after reconciliation): 1 px -> 1,451, 1.5 ->
            // 1,448, 2 -> 1,298, 2.5 -> 1,298, 3 -> 1,497 (a sheet sliding over the step's edge moves 1.2-1.7 px a
            // frame; at 3 px tracks start to join other points).
            link_px: 2.0,
            min_votes: 3,
            min_share: 0.9,
            // Measured on the demo's 22 frames (wrong stripe indices 4,262 without): 3, 4 and 6 -> 3,030, 10 -> 3,052.
            overrule_votes: 6,
            // Twice `overrule_votes`: a segment's label is weaker evidence than a row's. Measured on the demo's 22
            // frames (wrong stripe indices after reconciliation, 1,298 without): 6 -> 1,112, 8 -> 1,118, 12 ->
            // 1,148, 24 (more than the scan's other frames) -> 1,298; every relabelling right at each.
            overrule_segment_votes: 12,
        }
    }
}

/// The links between the points of one image row in two consecutive frames (both rows in column order): point `i`
/// of `a` and point `j` of `b` are linked when each is the other's nearest and no other point of either row is within
/// `link_px` of the other one. That is the same as each being the only point of the other row within reach (then it
/// is also the nearest), which the rows' order lets one pass find: the points within reach of a point are a run, and
/// those of the next point start no earlier. (It was three scans of the rows per point, a twentieth of a 1,000-frame
/// scan's time; unit-tested against that definition.)
fn row_links(a: &[StripePoint], b: &[StripePoint], link_px: f64) -> Vec<(usize, usize)> {
    let within = |u: f64, v: f64| (u - v).abs() <= link_px;
    let mut links = Vec::new();
    let mut j = 0;
    for (i, p) in a.iter().enumerate() {
        while j < b.len() && b[j].x < p.x && !within(b[j].x, p.x) {
            j += 1;
        }
        let Some(o) = b.get(j).filter(|o| within(o.x, p.x)) else {
            continue;
        };
        let alone_in_b = b.get(j + 1).is_none_or(|n| !within(n.x, p.x));
        let alone_in_a =
            (i == 0 || !within(a[i - 1].x, o.x)) && a.get(i + 1).is_none_or(|n| !within(n.x, o.x));
        if alone_in_a && alone_in_b {
            links.push((i, j));
        }
    }
    links
}

/// The votes of a scan's tracks, by track root (a point index): (label, count, first frame, last frame) per label,
/// few labels per track. A table by point index instead of a hash map: every coded point of a scan looks its track
/// up, and hashing them was a tenth of a 1,000-frame scan's time.
struct Votes {
    /// Per point index: where its list is in `lists`, if it is a root with votes.
    slot: Vec<u32>,
    lists: Vec<Vec<(u16, usize, usize, usize)>>,
}

impl Votes {
    fn new(points: usize) -> Self {
        Self {
            slot: vec![u32::MAX; points],
            lists: Vec::new(),
        }
    }

    /// The list of track `root` (a point index below the count given to [`Votes::new`]), made empty if new.
    fn entry(&mut self, root: usize) -> &mut Vec<(u16, usize, usize, usize)> {
        let n = self.lists.len();
        let slot = &mut self.slot[root];
        if *slot == u32::MAX {
            // Fewer lists than points, and a scan of more than 4 billion points does not fit in memory before this.
            *slot = n as u32;
            self.lists.push(Vec::new());
        }
        let k = *slot as usize;
        &mut self.lists[k]
    }

    fn get(&self, root: usize) -> Option<&Vec<(u16, usize, usize, usize)>> {
        let k = *self.slot.get(root)?;
        self.lists.get(k as usize)
    }
}

/// Temporal reconciliation of a scan's coding (frames in travel order): a point is linked to the point of the next
/// frame on the same row when each is the other's only neighbour within [`TemporalParams::link_px`] — the same stripe
/// on the same surface, 0.5 mm further along — and linked points form tracks. A point the coder dropped as ambiguous
/// takes its track's label when the points of the track their own rows settled agree on it (at least `min_votes`, at
/// least `min_share` of them, in frames before and after) and the label is one its own row could nearly take — or,
/// when as many settled points as overrule a row ([`TemporalParams::overrule_votes`]) agree in frames before and
/// after, even a label its row would not take (its row was read one over with confidence: a sheet's leading fragment
/// on a part's edge read as one more stripe; the row's points no track supports then give way). So does a
/// point only the segment vote coded (its row could not settle it) whose track reads it otherwise: a segment that runs
/// the length of a plate can carry one frame's misreading down every row. At a track's end (a sheet sliding over an
/// edge, about to vanish) there is no frame after it: such a point follows the track when at least
/// [`TemporalParams::overrule_votes`] settled points of one side agree (a dropped point is still only interpolated).
/// Even a label the point's own row settled is overruled when at least [`TemporalParams::overrule_votes`] of the
/// track's settled points agree on another, in frames before and after it (or on the one side there is where the
/// track starts or ends: a sheet sliding over an edge is read one over with confidence in its last frame); points no
/// track supports are then dropped
/// where the overruled labels break the row's order (a sheet's dim tail read as a stripe), and if two supported labels
/// conflict nothing is overruled. Labels the segment vote gave count for less: at least
/// [`TemporalParams::overrule_segment_votes`] of them (a settled label of the track's counting two), before and
/// after or from the one side there is, overrule a settled label when no other frame's row settled another (a band
/// of rows misread with confidence in one frame, ambiguous in the others). Where the row's
/// order leaves a point one label alone (its labelled neighbours are that label less and more one), a weaker agreement
/// of its track is enough: its most agreed label, coded by at least `min_votes` settled points before and after the
/// frame, whatever their share (a track cut short by a bump's flank, or sharing a frame's misreading): a dropped point
/// takes it if its row could nearly take it, and a point that would otherwise give way to an overruling track takes it
/// instead of being dropped. A dropped point the row's order leaves one label takes it even when its track settled on
/// nothing, as long as the track reads no other label from `min_votes` settled points (every row of the track
/// ambiguous: a stripe beside a hidden one, or the scan's last frames); it still takes only a label its row could
/// nearly take. The row must stay ordered (labels growing with the column) with all its changes, or only the dropped
/// points that keep it ordered by themselves are recovered. Returns how many points were recovered, relabelled or
/// dropped.
///
/// Where a stripe falls into a hole, the rows it leaves are read as well one stripe over, and the coder drops the other
/// stripes' points there; the frames before and after saw the same stripes on the same surface and coded them.
pub fn reconcile(frames: &mut [CodedFrame], params: &TemporalParams) -> usize {
    fn find(parent: &mut [usize], mut a: usize) -> usize {
        while parent[a] != a {
            parent[a] = parent[parent[a]];
            a = parent[a];
        }
        a
    }
    let offsets: Vec<usize> = frames
        .iter()
        .scan(0usize, |acc, f| {
            let o = *acc;
            *acc += f.points.len();
            Some(o)
        })
        .collect();
    let total: usize = frames.iter().map(|f| f.points.len()).sum();
    let mut parent: Vec<usize> = (0..total).collect();
    // The row runs of a frame's points: (row, start, end).
    let rows_of = |f: &CodedFrame| -> Vec<(u32, usize, usize)> {
        let mut out = Vec::new();
        let mut i = 0;
        while i < f.points.len() {
            let r = f.points[i].row;
            let mut j = i + 1;
            while j < f.points.len() && f.points[j].row == r {
                j += 1;
            }
            out.push((r, i, j));
            i = j;
        }
        out
    };
    let sorted = |f: &CodedFrame| {
        f.points.len() == f.coding.stripes.len()
            && f.points
                .windows(2)
                .all(|w| w[0].row < w[1].row || (w[0].row == w[1].row && w[0].x <= w[1].x))
    };
    if !frames.iter().all(sorted) {
        return 0;
    }
    // The links between consecutive frames, found for every pair of frames in parallel (as global point indices),
    // then joined into tracks in frame order: the same tracks as one pass makes.
    let rows: Vec<Vec<(u32, usize, usize)>> = frames.par_iter().map(rows_of).collect();
    let links: Vec<Vec<(usize, usize)>> = (0..frames.len().saturating_sub(1))
        .into_par_iter()
        .map(|k| {
            let (a, b) = (&frames[k], &frames[k + 1]);
            let (ra, rb) = (&rows[k], &rows[k + 1]);
            let mut out = Vec::new();
            let mut q = 0;
            for &(row, s, e) in ra {
                while q < rb.len() && rb[q].0 < row {
                    q += 1;
                }
                if q >= rb.len() || rb[q].0 != row {
                    continue;
                }
                let (pa, pb) = (&a.points[s..e], &b.points[rb[q].1..rb[q].2]);
                out.extend(
                    row_links(pa, pb, params.link_px)
                        .into_iter()
                        .map(|(i, j)| (offsets[k] + s + i, offsets[k + 1] + rb[q].1 + j)),
                );
            }
            out
        })
        .collect();
    for (i, j) in links.into_iter().flatten() {
        let (x, y) = (find(&mut parent, i), find(&mut parent, j));
        if x != y {
            parent[x.max(y)] = x.min(y);
        }
    }
    // Every point's track (its root), points in parallel (reading the links only: the same roots).
    let roots: Vec<usize> = {
        let parent = &parent;
        (0..total)
            .into_par_iter()
            .map(|mut a| {
                while parent[a] != a {
                    a = parent[a];
                }
                a
            })
            .collect()
    };
    // Votes per track: (label, count, first frame, last frame), few labels per track; `votes` from the labels the
    // points' own rows settled, `segment_votes` from the labels only the segment vote gave (a consistent misreading
    // can spread through those, so they count for less, see [`TemporalParams::overrule_segment_votes`]).
    let (mut votes, mut segment_votes) = (Votes::new(total), Votes::new(total));
    for (k, f) in frames.iter().enumerate() {
        for (i, l) in f.coding.stripes.iter().enumerate() {
            let Some(l) = *l else { continue };
            let settled = f.coding.row_confident.get(i).copied().unwrap_or(false);
            let root = roots[offsets[k] + i];
            let into = if settled {
                &mut votes
            } else {
                &mut segment_votes
            };
            let v = into.entry(root);
            match v.iter_mut().find(|x| x.0 == l) {
                Some(x) => {
                    x.1 += 1;
                    x.2 = x.2.min(k);
                    x.3 = x.3.max(k);
                }
                None => v.push((l, 1, k, k)),
            }
        }
    }
    let (votes, segment_votes) = (&votes, &segment_votes);
    // Each frame's rows are decided from the tracks alone: frames in parallel.
    let recovered_in = |(k, f): (usize, &mut CodedFrame)| -> usize {
        let mut recovered = 0;
        let mut proposal: Vec<Option<u16>> = Vec::new();
        for &(_, s, e) in &rows[k] {
            // The track's label for every point of the row it may change: dropped points, and points only the
            // segment vote coded (their row could not settle them) that their track reads otherwise.
            proposal.clear();
            proposal.extend_from_slice(&f.coding.stripes[s..e]);
            let mut changed = false;
            let mut overruled = false;
            // The track's winning label with its votes and whether it codes frames on both sides of this one.
            let winner = |i: usize| -> Option<(u16, usize, bool)> {
                let root = roots[offsets[k] + i];
                let v = votes.get(root)?;
                let all: usize = v.iter().map(|x| x.1).sum();
                let &(w, c, first, last) = v.iter().max_by_key(|x| x.1)?;
                ((c as f64) >= params.min_share * all as f64).then_some((
                    w,
                    c,
                    first < k && last > k,
                ))
            };
            // The track's most agreed label, coded by at least `min_votes` settled points before and after this frame,
            // whatever its share.
            let majority = |i: usize| -> Option<u16> {
                let v = votes.get(roots[offsets[k] + i])?;
                let &(w, c, first, last) = v.iter().max_by_key(|x| x.1)?;
                (c >= params.min_votes && first < k && last > k).then_some(w)
            };
            // The label the segment vote gave the track's points, when their weight reaches
            // `overrule_segment_votes` — each segment-given label counting one and each label a row settled for it
            // two (a settled label is worth two of its segment's: `overrule_segment_votes` is twice
            // `overrule_votes`) — 90% of its segment-given labels agree, and no other frame's row settled another
            // label; in frames before and after this one, or from the one side there is where the track starts or
            // ends (as settled labels overrule: in frame 15 of the demo, stripe 2 about to vanish over the step's
            // edge was read as 1 with confidence in its last frame, its track coded 2 by the segments and by a few
            // settled rows in the frames before).
            let segment_winner = |i: usize| -> Option<u16> {
                let root = roots[offsets[k] + i];
                let v = segment_votes.get(root)?;
                let &(w, c, first, last) = v.iter().max_by_key(|x| x.1)?;
                let all: usize = v.iter().map(|x| x.1).sum();
                let settled = |same: bool| -> usize {
                    votes.get(root).map_or(0, |sv| {
                        sv.iter().filter(|x| (x.0 == w) == same).map(|x| x.1).sum()
                    })
                };
                (params.overrule_segment_votes > 0
                    && c + 2 * settled(true) >= params.overrule_segment_votes
                    && (first < k || last > k)
                    && (c as f64) >= params.min_share * all as f64
                    && settled(false) <= 1)
                    .then_some(w)
            };
            // The one label the row's order leaves point j (between its labelled neighbours in `labels`).
            let left_by_order = |labels: &[Option<u16>], j: usize| -> Option<u16> {
                let lo = *labels[..j].iter().rev().flatten().next()?;
                let hi = *labels[j + 1..].iter().flatten().next()?;
                let w = lo.checked_add(1)?;
                (hi.checked_sub(1) == Some(w)).then_some(w)
            };
            // That label, when the track's majority (point `i`'s) is that label.
            let sandwiched = |labels: &[Option<u16>], j: usize, i: usize| -> Option<u16> {
                left_by_order(labels, j).filter(|&w| majority(i) == Some(w))
            };
            // That label, when the track reads no other (no settled points, or too few for any other label).
            let unopposed = |labels: &[Option<u16>], j: usize, i: usize| -> Option<u16> {
                left_by_order(labels, j).filter(|&w| {
                    !votes
                        .get(roots[offsets[k] + i])
                        .is_some_and(|v| v.iter().any(|x| x.0 != w && x.1 >= params.min_votes))
                })
            };
            for i in s..e {
                let current = f.coding.stripes[i];
                if current.is_some() && f.coding.row_confident.get(i).copied().unwrap_or(false) {
                    // Before and after this frame, or from the one side there is where the track starts or ends
                    // (at the scan's ends, or mid-scan where a sheet slides over an edge and vanishes): as many
                    // settled points either way. (Mid-scan it once dropped points into a false 0.8 mm² "hole"
                    // beside the demo's dent; inspection now reports gaps that small as unmeasured,
                    // `DetectParams::min_hole_travel_steps`.)
                    if params.overrule_votes > 0
                        && let Some((w, c, _around)) = winner(i)
                        && c >= params.overrule_votes
                        && current != Some(w)
                    {
                        proposal[i - s] = Some(w);
                        changed = true;
                        overruled = true;
                    } else if let Some(w) = segment_winner(i)
                        && current != Some(w)
                    {
                        proposal[i - s] = Some(w);
                        changed = true;
                        overruled = true;
                    }
                    continue;
                }
                let near = f.coding.near.get(i).copied().unwrap_or([NO_LABEL; 3]);
                if near[0] == NO_LABEL {
                    continue;
                }
                let Some((w, c, around)) = winner(i) else {
                    continue;
                };
                // Interpolation: the track codes the label before and after this frame. At a track's end (or
                // start), a label the segment vote gave gives way to as many settled points as overrule a row.
                let extends =
                    current.is_some() && params.overrule_votes > 0 && c >= params.overrule_votes;
                // A dropped point whose track settled the label in frames before and after as firmly as overrules a
                // row takes it even when its own row would not nearly take it: the row's confident reading that
                // dropped it was one over (a sheet's leading fragment on a part's edge read as one more stripe).
                // It counts as an overrule: the row's points no track supports give way where the order breaks.
                let firm = current.is_none()
                    && around
                    && params.overrule_votes > 0
                    && c >= params.overrule_votes;
                if c < params.min_votes
                    || !(near.contains(&w) || firm)
                    || !(around || extends)
                    || current == Some(w)
                {
                    continue;
                }
                proposal[i - s] = Some(w);
                changed = true;
                if !near.contains(&w) {
                    overruled = true;
                }
            }
            // A dropped point the row's order leaves one label alone (between its labelled neighbours) takes it when
            // its track agrees, by a majority too small for the rule above.
            for j in 0..e - s {
                let near = f.coding.near.get(s + j).copied().unwrap_or([NO_LABEL; 3]);
                if f.coding.stripes[s + j].is_none()
                    && proposal[j].is_none()
                    && near[0] != NO_LABEL
                    && let Some(w) =
                        sandwiched(&proposal, j, s + j).or_else(|| unopposed(&proposal, j, s + j))
                    && near.contains(&w)
                {
                    proposal[j] = Some(w);
                    changed = true;
                }
            }
            if !changed {
                continue;
            }
            // The row must stay ordered with every change made; otherwise only the dropped points whose label keeps
            // the row ordered by itself are recovered (a relabelling that breaks the order is not trusted).
            let ordered = |labels: &[Option<u16>]| {
                labels
                    .iter()
                    .flatten()
                    .zip(labels.iter().flatten().skip(1))
                    .all(|(a, b)| a < b)
            };
            if overruled && !ordered(&proposal) {
                // The proposal without the overrules.
                let plain: Vec<Option<u16>> = (s..e)
                    .map(|i| {
                        let settled = f.coding.row_confident.get(i).copied().unwrap_or(false);
                        match f.coding.stripes[i] {
                            Some(l) if settled => Some(l),
                            _ => proposal[i - s],
                        }
                    })
                    .collect();
                // Points whose label no track supports give way to the overruling tracks: dropped where they
                // break the row's order. If two supported labels conflict, nothing is overruled.
                let supported = |i: usize, l: u16| {
                    winner(i).is_some_and(|(w, c, _)| w == l && c >= params.min_votes)
                };
                loop {
                    let labelled: Vec<usize> =
                        (0..e - s).filter(|&j| proposal[j].is_some()).collect();
                    let Some(bad) = labelled
                        .windows(2)
                        .find(|w| proposal[w[0]] >= proposal[w[1]])
                    else {
                        break;
                    };
                    // An unsupported point gives way: it takes the one label the order leaves it if its track
                    // agrees, or is dropped.
                    let (a, b) = (bad[0], bad[1]);
                    if !supported(s + b, proposal[b].unwrap_or(NO_LABEL)) {
                        proposal[b] = None;
                        proposal[b] = sandwiched(&proposal, b, s + b);
                    } else if !supported(s + a, proposal[a].unwrap_or(NO_LABEL)) {
                        proposal[a] = None;
                        proposal[a] = sandwiched(&proposal, a, s + a);
                    } else {
                        // Undo the overrules and the drops; the usual rules apply.
                        proposal.copy_from_slice(&plain);
                        break;
                    }
                }
            }
            if ordered(&proposal) {
                for (i, p) in (s..e).zip(&proposal) {
                    if f.coding.stripes[i] != *p {
                        if f.coding.stripes[i].is_none() {
                            f.coding.stats.coded += 1;
                            f.coding.stats.ambiguous = f.coding.stats.ambiguous.saturating_sub(1);
                        } else if p.is_none() {
                            f.coding.stats.coded -= 1;
                            f.coding.stats.ambiguous += 1;
                        }
                        f.coding.stripes[i] = *p;
                        recovered += 1;
                    }
                }
                continue;
            }
            for i in s..e {
                let (None, Some(w)) = (f.coding.stripes[i], proposal[i - s]) else {
                    continue;
                };
                let before = f.coding.stripes[s..i].iter().rev().flatten().next();
                let after = f.coding.stripes[i + 1..e].iter().flatten().next();
                if before.is_some_and(|&b| b >= w) || after.is_some_and(|&a| a <= w) {
                    continue;
                }
                f.coding.stripes[i] = Some(w);
                f.coding.stats.coded += 1;
                f.coding.stats.ambiguous = f.coding.stats.ambiguous.saturating_sub(1);
                recovered += 1;
            }
        }
        recovered
    };
    frames.par_iter_mut().enumerate().map(recovered_in).sum()
}

#[cfg(test)]
mod tests;
