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
//! point is the edge whatever the blur's width, so the rule has no parameter.
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
}
