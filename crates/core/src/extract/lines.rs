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
    for (i, k) in keep.iter_mut().enumerate() {
        let r = find(&mut parent, i as u32) as usize;
        *k = size[r] >= params.min_length_lines && seeded[r];
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
}
