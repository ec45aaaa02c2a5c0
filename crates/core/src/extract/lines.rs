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
//! **Centres along the line.** Along a kept line the centres scatter from scan line to scan line by what no
//! estimator on one scan line can remove: speckle (the beam's own interference pattern, independent from one
//! scan line to the next once the optics blur it over a pixel or so) and shot and read noise. The line itself
//! is smooth at the scale of a few scan lines. Each centre is therefore replaced by the value at its scan line of
//! a least-squares straight line through the centres of its line within [`LineParams::fit_half_lines`] scan lines
//! of it (a local linear fit, a Savitzky-Golay smoother of degree one): the noise of a centre falls by about the
//! square root of the window's length, and a straight or evenly slanted line is not biased. Where the line bends
//! (a corner, a step smaller than [`LineParams::max_step_px`]) the fit would smear it, so the fit is made twice:
//! the second time without the centres whose residual from the first exceeds [`FIT_OUTLIER_SIGMAS`] times the
//! line's own scatter (1.4826 times the median absolute residual), and those centres keep their own value.
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
    /// Half the window of the fit along the line, scan lines: each centre is refit from the centres of its line
    /// within this many scan lines (see the module documentation); 0 keeps every centre as estimated. It is the
    /// resolution along the stripe: 3 fits over 7 scan lines (0.7 mm on the belt with the paper's camera).
    #[serde(default = "default_fit_half_lines")]
    pub fit_half_lines: u32,
}

/// Default of [`LineParams::fit_half_lines`]. Measured on the validation frames of another renderer (not tuned on):
/// 0, 1, 2 and 3 give a median RMS of 0.105, 0.090, 0.078 and 0.074 px at the same recall; on the random scenes the
/// median 0.112, 0.094 and 0.086 px for 0, 2 and 3. Longer windows gain less and widen what a bend smears. The
/// cost: the top of a small bump or dent is read flatter (`stripe3d bench defects`: median depth error 0.0075 mm
/// with 3, 0.0028 mm with 0, the share within 0.03 mm the same).
pub const DEFAULT_FIT_HALF_LINES: u32 = 3;

fn default_fit_half_lines() -> u32 {
    DEFAULT_FIT_HALF_LINES
}

/// A centre whose residual from the first fit along its line exceeds this many times the line's scatter keeps its
/// own value and is left out of its neighbours' second fit: beyond 3 sigma a residual is a bend, not noise
/// (Gaussian noise passes it three times in a thousand).
pub const FIT_OUTLIER_SIGMAS: f64 = 3.0;

impl Default for LineParams {
    fn default() -> Self {
        Self {
            extend_snr: 3.5,
            seed_snr: 6.0,
            min_length_lines: 8,
            max_step_px: 2.0,
            max_gap_lines: 2,
            fit_half_lines: DEFAULT_FIT_HALF_LINES,
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

/// Sets `keep[i]` for every node of a kept line, and `line_of[i]` to the line node `i` belongs to (the index of
/// one of its nodes). `nodes` are sorted by scan line, then position.
pub fn link_lines(
    nodes: &[Node],
    params: &LineParams,
    keep: &mut Vec<bool>,
    line_of: &mut Vec<u32>,
) {
    keep.clear();
    line_of.clear();
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
    line_of.extend(roots.iter().map(|&r| r as u32));
}

/// Buffers of [`fit_along_lines`], kept between frames.
#[derive(Debug, Clone, Default)]
pub struct FitScratch {
    order: Vec<u32>,
    first: Vec<f64>,
    fitted: Vec<f64>,
    abs: Vec<f64>,
}

/// Replaces the position of every kept node by the fit along its line (see the module documentation), `half`
/// scan lines either side. `keep` and `line_of` are [`link_lines`]'s.
pub fn fit_along_lines(
    nodes: &mut [Node],
    keep: &[bool],
    line_of: &[u32],
    half: u32,
    scratch: &mut FitScratch,
) {
    if half == 0 {
        return;
    }
    let FitScratch {
        order,
        first,
        fitted,
        abs,
    } = scratch;
    order.clear();
    order.extend((0..nodes.len() as u32).filter(|&i| keep[i as usize]));
    // By line, and within a line by scan line (the sort is stable and the nodes are in scan line order).
    order.sort_by_key(|&i| line_of[i as usize]);
    first.clear();
    first.resize(nodes.len(), 0.0);
    fitted.clear();
    fitted.extend(nodes.iter().map(|n| n.x));
    let mut a = 0;
    while a < order.len() {
        let line = line_of[order[a] as usize];
        let b = a + order[a..]
            .iter()
            .take_while(|&&i| line_of[i as usize] == line)
            .count();
        let run = &order[a..b];
        for (k, &i) in run.iter().enumerate() {
            first[i as usize] =
                local_fit(nodes, run, k, half, |_| true).unwrap_or(nodes[i as usize].x);
        }
        abs.clear();
        abs.extend(
            run.iter()
                .map(|&i| (nodes[i as usize].x - first[i as usize]).abs()),
        );
        let mid = abs.len() / 2;
        let scatter = 1.4826 * *abs.select_nth_unstable_by(mid, f64::total_cmp).1;
        let limit = FIT_OUTLIER_SIGMAS * scatter;
        let inlier = |j: u32| (nodes[j as usize].x - first[j as usize]).abs() <= limit;
        for (k, &i) in run.iter().enumerate() {
            if inlier(i) {
                if let Some(x) = local_fit(nodes, run, k, half, inlier) {
                    fitted[i as usize] = x;
                }
            }
        }
        a = b;
    }
    for (n, &x) in nodes.iter_mut().zip(fitted.iter()) {
        n.x = x;
    }
}

/// The least-squares straight line through the nodes of `run` (one line's nodes in scan line order) within `half`
/// scan lines of its `k`-th that `use_node` accepts, evaluated at that node's scan line; `None` with fewer than
/// three such nodes or all on one scan line.
fn local_fit(
    nodes: &[Node],
    run: &[u32],
    k: usize,
    half: u32,
    use_node: impl Fn(u32) -> bool,
) -> Option<f64> {
    let at = nodes[run[k] as usize].line;
    let lo = k - run[..k]
        .iter()
        .rev()
        .take_while(|&&j| nodes[j as usize].line + half >= at)
        .count();
    let hi = k + run[k..]
        .iter()
        .take_while(|&&j| nodes[j as usize].line <= at + half)
        .count();
    let (mut n, mut st, mut stt, mut sx, mut stx) = (0.0, 0.0, 0.0, 0.0, 0.0);
    for &j in run[lo..hi].iter().filter(|&&j| use_node(j)) {
        let node = &nodes[j as usize];
        let t = f64::from(node.line) - f64::from(at);
        n += 1.0;
        st += t;
        stt += t * t;
        sx += node.x;
        stx += t * node.x;
    }
    let det = n * stt - st * st;
    // The intercept at t = 0, the node's own scan line.
    (n >= 3.0 && det > 1e-9).then(|| (stt * sx - st * stx) / det)
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
        link_lines(&nodes, &LineParams::default(), &mut keep, &mut Vec::new());
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
        link_lines(&short, &LineParams::default(), &mut keep, &mut Vec::new());
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
        link_lines(&nodes, &LineParams::default(), &mut keep, &mut Vec::new());
        assert!(!keep[0]);
        assert!(keep[1..].iter().all(|&k| k));
    }

    /// Deterministic noise of standard deviation about `sigma` (a sum of four uniforms).
    fn noise(state: &mut u64, sigma: f64) -> f64 {
        let mut sum = 0.0;
        for _ in 0..4 {
            *state ^= *state << 13;
            *state ^= *state >> 7;
            *state ^= *state << 17;
            sum += (*state >> 11) as f64 / (1u64 << 53) as f64 - 0.5;
        }
        // Four uniforms of variance 1/12 each.
        sum * sigma * 3f64.sqrt()
    }

    fn fitted(truth: &[f64], sigma: f64) -> (Vec<f64>, Vec<f64>) {
        let mut state = 0x9E37_79B9_7F4A_7C15;
        let mut nodes: Vec<Node> = truth
            .iter()
            .enumerate()
            .map(|(l, &x)| Node {
                line: l as u32,
                x: x + noise(&mut state, sigma),
                snr: 10.0,
            })
            .collect();
        let raw = nodes.iter().map(|n| n.x).collect();
        let (mut keep, mut line_of) = (Vec::new(), Vec::new());
        link_lines(&nodes, &LineParams::default(), &mut keep, &mut line_of);
        assert!(keep.iter().all(|&k| k));
        let mut scratch = FitScratch::default();
        fit_along_lines(&mut nodes, &keep, &line_of, 3, &mut scratch);
        (raw, nodes.iter().map(|n| n.x).collect())
    }

    fn rms(a: &[f64], b: &[f64]) -> f64 {
        (a.iter().zip(b).map(|(x, y)| (x - y).powi(2)).sum::<f64>() / a.len() as f64).sqrt()
    }

    #[test]
    fn the_fit_along_a_line_cuts_its_noise_and_leaves_a_clean_line_alone() {
        // A slanted line, 0.3 px of noise: over seven scan lines the centres scatter about 0.4 times as much.
        let truth: Vec<f64> = (0..200).map(|l| 40.0 + 0.37 * l as f64).collect();
        let (raw, fit) = fitted(&truth, 0.3);
        let (before, after) = (rms(&raw, &truth), rms(&fit, &truth));
        assert!(before > 0.25 && after < 0.5 * before, "{before} -> {after}");
        // Without noise every centre stays where it was.
        let (raw, fit) = fitted(&truth, 0.0);
        assert!(rms(&raw, &fit) < 1e-9);
    }

    #[test]
    fn a_step_inside_a_line_is_not_smeared() {
        // A step of one pixel (linked: below the largest step) with 0.03 px of noise: the centres beside the step
        // are bends, not noise, and keep their own value.
        let truth: Vec<f64> = (0..100).map(|l| if l < 50 { 30.0 } else { 31.0 }).collect();
        let (_, fit) = fitted(&truth, 0.03);
        for (l, (x, t)) in fit.iter().zip(&truth).enumerate() {
            assert!((x - t).abs() < 0.12, "scan line {l}: {x} for {t}");
        }
    }
}
