//! Stripe points kept because they make a line: candidates linked from scan line to scan line, with hysteresis.
//!
//! A laser stripe continues from one scan line to the next with a small step (its slope across the lines); noise
//! peaks and speckle blobs do not. Each candidate is linked to the nearest candidate of the nearest earlier scan
//! line (up to [`LineParams::max_gap_lines`] skipped) whose position differs by at most
//! [`LineParams::max_step_px`] per line crossed. A connected set of linked candidates is a *line*; it is kept when it
//! holds at least [`LineParams::min_length_lines`] candidates and at least one *seed*, a candidate whose
//! signal-to-noise ratio reaches [`LineParams::seed_snr`] (Canny's hysteresis: strong points start a line, weaker
//! ones, down to [`LineParams::extend_snr`], extend it).
//!
//! A line's end is where the lit surface ends (a part's edge, a hole, a shadow). The scan line the edge crosses is
//! lit over part of its width only, and its peak is dimmer in proportion; the point it gives belongs to the scan
//! line's centre only when the surface covers that centre, that is when at least half of the scan line is lit:
//! an end point whose signal-to-noise ratio is below half the mean of the next [`END_REFERENCE_LINES`] scan lines
//! of its line is dropped (the edge lies before the scan line's centre). With a symmetric blur the half-level
//! point is the edge whatever the blur's width, so the rule has no parameter. Where a step's two surfaces put their
//! stripes within a link's reach, one line runs over both, and the scan line holding the edge gives a blend of the
//! two surfaces' light: on the dimmer surface's side of the edge and off that surface's column by more than
//! [`BLEND_PX`], it is dropped too (see `drop_blends`).
//!
//! Why these numbers: with Gaussian noise a candidate's prominence over its valleys reaches 6 sigma by chance less
//! than once in 10^8 pixels, so a seed is light; at 3.5 sigma chance peaks occur about once per 10^3 pixels, a few
//! hundred per frame, scattered: eight of them lined up on consecutive scan lines, each within 2 px of the last,
//! happen by chance about (10^-3 * 4)^7 times per pixel, never in practice.

/// Parameters of line linking. Every length is in pixels or scan lines, every level in standard deviations of the
/// local noise ([`super::evidence::NoiseMap`]).
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct LineParams {
    /// Signal-to-noise ratio (prominence over the local noise, sigma) a candidate needs to be considered at all.
    pub extend_snr: f64,
    /// Signal-to-noise ratio at which a candidate seeds a line.
    pub seed_snr: f64,
    /// Fewest candidates a kept line holds (scan lines; about 2 mm of stripe with the paper's camera).
    pub min_length_lines: usize,
    /// Largest change of a line's position from one scan line to the next, pixels (a stripe crossing the scan lines
    /// at up to 63 degrees from their normal).
    pub max_step_px: f64,
    /// Scan lines a line may skip (a speckle dropout, a thin dark mark).
    pub max_gap_lines: u32,
}

impl Default for LineParams {
    fn default() -> Self {
        Self {
            extend_snr: 3.5,
            seed_snr: 6.0,
            min_length_lines: 8,
            max_step_px: 2.0,
            max_gap_lines: 2,
        }
    }
}

/// One candidate for linking: scan line, position, signal-to-noise ratio.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Node {
    /// Scan line.
    pub line: u32,
    /// Sub-pixel position along it.
    pub x: f64,
    /// Prominence over the local noise.
    pub snr: f64,
}

/// Scan lines next to a line's end whose mean level is the reference for its end point (see the module
/// documentation).
pub const END_REFERENCE_LINES: u32 = 3;

/// How far (px) a point on the dimmer side of an edge inside its scan line may lie from that surface's own column
/// and still measure it (see [`link_lines`]): half a pixel, the accuracy a found point is held to.
pub const BLEND_PX: f64 = 0.5;

fn find(parent: &mut [u32], mut i: u32) -> u32 {
    while parent[i as usize] != i {
        let p = parent[i as usize];
        parent[i as usize] = parent[p as usize];
        i = p;
    }
    i
}

/// Sets `keep[i]` for every node of a kept line. `nodes` are sorted by scan line, then position.
pub fn link_lines(nodes: &[Node], params: &LineParams, keep: &mut Vec<bool>) {
    keep.clear();
    keep.resize(nodes.len(), false);
    if nodes.is_empty() {
        return;
    }
    // Start of each scan line's run of nodes.
    let mut starts: Vec<(u32, usize)> = Vec::new();
    for (i, n) in nodes.iter().enumerate() {
        if starts.last().is_none_or(|&(l, _)| l != n.line) {
            starts.push((n.line, i));
        }
    }
    starts.push((u32::MAX, nodes.len()));
    let mut parent: Vec<u32> = (0..nodes.len() as u32).collect();
    // Each node's link to the line before (NO_NODE: none).
    let mut pred: Vec<u32> = vec![NO_NODE; nodes.len()];
    for s in 1..starts.len() - 1 {
        let (line, a) = starts[s];
        let b = starts[s + 1].1;
        for i in a..b {
            let x = nodes[i].x;
            // The nearest earlier line within the gap that has a node within reach.
            for back in 1..=s.min(params.max_gap_lines as usize + 1) {
                let (pl, pa) = starts[s - back];
                let dl = line - pl;
                if dl > params.max_gap_lines + 1 {
                    break;
                }
                let pb = starts[s - back + 1].1;
                let reach = params.max_step_px * f64::from(dl);
                let prev = &nodes[pa..pb];
                let j = prev.partition_point(|n| n.x < x);
                let best = [j.checked_sub(1), Some(j)]
                    .into_iter()
                    .flatten()
                    .filter(|&k| k < prev.len())
                    .map(|k| (k, (prev[k].x - x).abs()))
                    .filter(|&(_, d)| d <= reach)
                    .min_by(|p, q| p.1.total_cmp(&q.1));
                if let Some((k, _)) = best {
                    pred[i] = (pa + k) as u32;
                    let (ri, rk) = (
                        find(&mut parent, i as u32),
                        find(&mut parent, (pa + k) as u32),
                    );
                    if ri != rk {
                        parent[ri.max(rk) as usize] = ri.min(rk);
                    }
                    break;
                }
            }
        }
    }
    let mut size = vec![0usize; nodes.len()];
    let mut seeded = vec![false; nodes.len()];
    for (i, n) in nodes.iter().enumerate() {
        let r = find(&mut parent, i as u32) as usize;
        size[r] += 1;
        seeded[r] |= n.snr >= params.seed_snr;
    }
    let mut roots: Vec<usize> = Vec::with_capacity(nodes.len());
    for (i, k) in keep.iter_mut().enumerate() {
        let r = find(&mut parent, i as u32) as usize;
        *k = size[r] >= params.min_length_lines && seeded[r];
        roots.push(r);
    }
    drop_partial_ends(nodes, &roots, keep);
    drop_blends(nodes, &pred, keep);
}

/// A node index that is none.
const NO_NODE: u32 = u32::MAX;

/// Drops the points where a line passes from one surface to another inside a scan line (a step whose stripes lie
/// within a link's reach, so that one line runs over both) and the point lies on the dimmer surface's side of the
/// edge — its level below the mean of the levels of the [`END_REFERENCE_LINES`] scan lines before and after it — yet
/// more than [`BLEND_PX`] off that surface's own column (extrapolated from its two nearest points), where the two
/// surfaces' columns differ by more than twice that (a step, not a speckle's scatter): the scan line's
/// centre lies on the dimmer surface, and the point is a blend of both surfaces' light, a measurement of neither. A
/// printed edge on one surface leaves the column where it was, and its points stay. `pred[i]` is node `i`'s link
/// to the scan line before.
fn drop_blends(nodes: &[Node], pred: &[u32], keep: &mut [bool]) {
    let n = nodes.len();
    // Each node's unique successor (NO_NODE: none, or more than one).
    let mut succ = vec![NO_NODE; n];
    let mut claims = vec![0u8; n];
    for (i, &p) in pred.iter().enumerate() {
        if p != NO_NODE {
            let p = p as usize;
            claims[p] = claims[p].saturating_add(1);
            succ[p] = if claims[p] == 1 { i as u32 } else { NO_NODE };
        }
    }
    // Up to END_REFERENCE_LINES kept nodes along `next` from i.
    let walk = |i: usize, next: &[u32], out: &mut [usize; END_REFERENCE_LINES as usize]| -> usize {
        let (mut at, mut count) = (i, 0);
        while count < out.len() {
            let j = next[at];
            if j == NO_NODE || !keep[j as usize] {
                break;
            }
            at = j as usize;
            out[count] = at;
            count += 1;
        }
        count
    };
    let mut drop = Vec::new();
    let (mut before, mut after) = ([0usize; 3], [0usize; 3]);
    for i in 0..n {
        if !keep[i] {
            continue;
        }
        let (nb, na) = (walk(i, pred, &mut before), walk(i, &succ, &mut after));
        if nb < 2 || na < 2 {
            continue;
        }
        let mean =
            |side: &[usize]| side.iter().map(|&j| nodes[j].snr).sum::<f64>() / side.len() as f64;
        let (a, b) = (mean(&before[..nb]), mean(&after[..na]));
        if 2.0 * nodes[i].snr >= a + b {
            continue;
        }
        // Each side's own column at this scan line: a step lies between them when they differ by more than a
        // blend's tolerance on each side.
        let own = |side: &[usize]| {
            let (p, q) = (&nodes[side[0]], &nodes[side[1]]);
            let slope = (p.x - q.x) / (f64::from(p.line) - f64::from(q.line));
            p.x + slope * (f64::from(nodes[i].line) - f64::from(p.line))
        };
        let (ob, oa) = (own(&before[..nb]), own(&after[..na]));
        let dim = if a < b { ob } else { oa };
        if (ob - oa).abs() > 2.0 * BLEND_PX && (nodes[i].x - dim).abs() > BLEND_PX {
            drop.push(i);
        }
    }
    for i in drop {
        keep[i] = false;
    }
}

/// Drops the end points of kept lines that lie on a scan line the surface covers less than half of (see the module
/// documentation). `roots[i]` is node `i`'s line.
fn drop_partial_ends(nodes: &[Node], roots: &[usize], keep: &mut [bool]) {
    const NONE: u32 = u32::MAX;
    let n = nodes.len();
    // First and last scan line of every line.
    let (mut first, mut last) = (vec![NONE; n], vec![0u32; n]);
    for (i, node) in nodes.iter().enumerate() {
        if keep[i] {
            let r = roots[i];
            first[r] = first[r].min(node.line);
            last[r] = last[r].max(node.line);
        }
    }
    // Sums and counts of the levels next to each end.
    let (mut head, mut tail) = (vec![(0.0f64, 0u32); n], vec![(0.0f64, 0u32); n]);
    for (i, node) in nodes.iter().enumerate() {
        if !keep[i] {
            continue;
        }
        let r = roots[i];
        if node.line > first[r] && node.line <= first[r] + END_REFERENCE_LINES {
            head[r].0 += node.snr;
            head[r].1 += 1;
        }
        if node.line < last[r] && node.line + END_REFERENCE_LINES >= last[r] {
            tail[r].0 += node.snr;
            tail[r].1 += 1;
        }
    }
    let partial =
        |(sum, count): (f64, u32), snr: f64| count > 0 && 2.0 * snr * f64::from(count) < sum;
    for (i, node) in nodes.iter().enumerate() {
        let r = roots[i];
        if keep[i]
            && ((node.line == first[r] && partial(head[r], node.snr))
                || (node.line == last[r] && partial(tail[r], node.snr)))
        {
            keep[i] = false;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_seeded_line_is_kept_and_scattered_or_unseeded_points_are_not() {
        let mut nodes = Vec::new();
        for line in 0..20u32 {
            // A slanted line, seeded once; a dim parallel line never seeded; a point far off each line.
            nodes.push(Node {
                line,
                x: 10.0 + 0.8 * f64::from(line),
                snr: if line == 7 { 9.0 } else { 4.0 },
            });
            nodes.push(Node {
                line,
                x: 60.0,
                snr: 4.0,
            });
            nodes.push(Node {
                line,
                x: 100.0 + 7.0 * f64::from(line % 5),
                snr: 20.0,
            });
        }
        // A gap of two lines in the slanted line is bridged.
        nodes.retain(|n| !(n.x < 50.0 && (n.line == 12 || n.line == 13)));
        nodes.sort_by(|a, b| a.line.cmp(&b.line).then(a.x.total_cmp(&b.x)));
        let mut keep = Vec::new();
        link_lines(&nodes, &LineParams::default(), &mut keep);
        for (n, k) in nodes.iter().zip(&keep) {
            assert_eq!(*k, n.x < 50.0, "{n:?}");
        }
        // Too short: a seeded line of 7 is dropped.
        let short: Vec<Node> = (0..7)
            .map(|l| Node {
                line: l,
                x: 5.0,
                snr: 10.0,
            })
            .collect();
        link_lines(&short, &LineParams::default(), &mut keep);
        assert!(keep.iter().all(|k| !k));
    }

    #[test]
    fn a_line_end_on_a_scan_line_lit_less_than_half_is_dropped() {
        // A line whose first scan line is lit over a third of its width (an edge inside it) and whose last is lit
        // over two thirds: the first point is dropped, the last kept.
        let nodes: Vec<Node> = (0..20u32)
            .map(|line| Node {
                line,
                x: 30.0,
                snr: match line {
                    0 => 4.0,
                    19 => 8.0,
                    _ => 12.0,
                },
            })
            .collect();
        let mut keep = Vec::new();
        link_lines(&nodes, &LineParams::default(), &mut keep);
        assert!(!keep[0]);
        assert!(keep[1..].iter().all(|&k| k));
    }

    #[test]
    fn a_blend_of_two_surfaces_inside_a_scan_line_is_dropped_and_a_printed_edge_is_not() {
        // A dim stripe on a lower surface (lines 0-9, x = 30) steps onto a bright upper one (lines 11-20, x = 31.8);
        // scan line 10 holds both, mostly the dim one, its point a blend at x = 31. Then the same levels on one
        // surface (a printed edge): the column stays, and so does the point.
        let line = |step: bool| -> Vec<Node> {
            (0..21u32)
                .map(|line| Node {
                    line,
                    x: match (step, line) {
                        (false, _) => 30.0,
                        (true, 0..=9) => 30.0,
                        (true, 10) => 31.0,
                        (true, _) => 31.8,
                    },
                    snr: match line {
                        0..=9 => 4.0,
                        10 => 8.0,
                        _ => 20.0,
                    },
                })
                .collect()
        };
        let mut keep = Vec::new();
        link_lines(&line(true), &LineParams::default(), &mut keep);
        assert!(!keep[10], "the blend");
        assert_eq!(keep.iter().filter(|&&k| k).count(), 20);
        link_lines(&line(false), &LineParams::default(), &mut keep);
        assert!(keep.iter().all(|&k| k), "a printed edge");
    }
}
