//! Measuring defects: the raised-cosine bell fit of bumps and dents, shapes of cell sets, holes' areas with their
//! partly lit rims, and why a gap is not a hole.

use super::*;

/// Raised cosine bell of unit height over radius `r0`: the smooth profile bumps and dents are measured with.
pub fn bell(d: f64, r0: f64) -> f64 {
    if d >= r0 {
        0.0
    } else {
        0.5 * (1.0 + (std::f64::consts::PI * d / r0).cos())
    }
}

/// A fitted bell: amplitude (signed), centre, radius, offset; and the RMS residual.
#[derive(Debug, Clone, Copy)]
pub(super) struct BellFit {
    pub(super) amplitude: f64,
    pub(super) centre: [f64; 2],
    pub(super) radius: f64,
    pub(super) offset: f64,
    pub(super) rms: f64,
}

/// Levenberg-Marquardt fit of `offset + amplitude * bell(|p − centre|, radius)` to samples (x, y, dev).
pub(super) fn fit_bell(samples: &[(f64, f64, f64)], init: BellFit) -> Option<BellFit> {
    use nalgebra::{Matrix5, Vector5};
    let residuals = |p: &BellFit| -> f64 {
        samples
            .iter()
            .map(|&(x, y, z)| {
                let d = ((x - p.centre[0]).powi(2) + (y - p.centre[1]).powi(2)).sqrt();
                (z - p.offset - p.amplitude * bell(d, p.radius)).powi(2)
            })
            .sum()
    };
    let mut p = init;
    let mut cost = residuals(&p);
    let mut lambda = 1e-3;
    let pi = std::f64::consts::PI;
    for _ in 0..60 {
        let mut jtj = Matrix5::<f64>::zeros();
        let mut jtr = Vector5::<f64>::zeros();
        for &(x, y, z) in samples {
            let (ux, uy) = (x - p.centre[0], y - p.centre[1]);
            let d = (ux * ux + uy * uy).sqrt();
            let b = bell(d, p.radius);
            let r = z - p.offset - p.amplitude * b;
            let mut jac = Vector5::new(b, 0.0, 0.0, 0.0, 1.0);
            if d < p.radius && d > 1e-9 {
                let s = 0.5 * (pi * d / p.radius).sin() * pi / p.radius;
                jac[1] = p.amplitude * s * ux / d;
                jac[2] = p.amplitude * s * uy / d;
                jac[3] = p.amplitude * s * d / p.radius;
            }
            jtj += jac * jac.transpose();
            jtr += jac * r;
        }
        let mut improved = false;
        for _ in 0..10 {
            let mut a = jtj;
            for t in 0..5 {
                a[(t, t)] *= 1.0 + lambda;
                a[(t, t)] += 1e-12;
            }
            let Some(step) = a.lu().solve(&jtr) else {
                lambda *= 10.0;
                continue;
            };
            let q = BellFit {
                amplitude: p.amplitude + step[0],
                centre: [p.centre[0] + step[1], p.centre[1] + step[2]],
                radius: (p.radius + step[3]).max(0.05),
                offset: p.offset + step[4],
                rms: 0.0,
            };
            let c = residuals(&q);
            if c < cost {
                let small = (cost - c) < 1e-10 * cost.max(1e-12);
                p = q;
                cost = c;
                lambda = (lambda * 0.3).max(1e-9);
                improved = !small;
                break;
            }
            lambda *= 10.0;
        }
        if !improved {
            break;
        }
    }
    p.rms = (cost / samples.len().max(1) as f64).sqrt();
    (p.amplitude.is_finite() && p.radius.is_finite()).then_some(p)
}

/// The dimensions of a region's cells: centroid weighted by `weight`, bounding box, and elongation.
pub(super) struct Shape {
    pub(super) centroid: [f64; 2],
    pub(super) bbox: [f64; 4],
    pub(super) elongation: f64,
}

pub(super) fn shape(range: &RangeImage, cells: &[usize], weight: impl Fn(usize) -> f64) -> Shape {
    let w = range.width;
    let (mut sw, mut sx, mut sy) = (0.0, 0.0, 0.0);
    let mut bbox = [
        f64::INFINITY,
        f64::INFINITY,
        f64::NEG_INFINITY,
        f64::NEG_INFINITY,
    ];
    let (hx, hy) = (range.spacing_mm[0] / 2.0, range.spacing_mm[1] / 2.0);
    for &k in cells {
        let (x, y) = cell_xy(range, k % w, k / w);
        let wt = weight(k).max(1e-12);
        sw += wt;
        sx += wt * x;
        sy += wt * y;
        bbox = [
            bbox[0].min(x - hx),
            bbox[1].min(y - hy),
            bbox[2].max(x + hx),
            bbox[3].max(y + hy),
        ];
    }
    let c = [sx / sw, sy / sw];
    // Unweighted second moments for the shape.
    let n = cells.len() as f64;
    let (mut mx, mut my) = (0.0, 0.0);
    for &k in cells {
        let (x, y) = cell_xy(range, k % w, k / w);
        mx += x;
        my += y;
    }
    let (mx, my) = (mx / n, my / n);
    let (mut cxx, mut cyy, mut cxy) = (0.0, 0.0, 0.0);
    for &k in cells {
        let (x, y) = cell_xy(range, k % w, k / w);
        cxx += (x - mx).powi(2);
        cyy += (y - my).powi(2);
        cxy += (x - mx) * (y - my);
    }
    // Each cell spreads over its own square: add its variance so single rows are not "infinitely thin".
    let cell_var = range.spacing_mm[0] * range.spacing_mm[1] / 12.0;
    let (cxx, cyy, cxy) = (cxx / n + cell_var, cyy / n + cell_var, cxy / n);
    let tr = cxx + cyy;
    let det = cxx * cyy - cxy * cxy;
    let disc = (tr * tr / 4.0 - det).max(0.0).sqrt();
    let (l1, l2) = (tr / 2.0 + disc, (tr / 2.0 - disc).max(1e-12));
    Shape {
        centroid: c,
        bbox,
        elongation: (l1 / l2).sqrt(),
    }
}

/// Why a gap with the same heights on either side was not called a hole: narrower than the scan's sampling can tell
/// from missing samples ([`DetectParams::min_hole_travel_steps`]), or as the rule base's terms say: too small, oblong
/// (a band of missing samples), too large, or a certainty below the threshold.
pub(super) fn gap_reason(
    rules: &SurfaceRules,
    ev: &Evidence,
    confidence: f64,
    params: &DetectParams,
) -> String {
    let is =
        |input: &str, term: &str, x: f64| rules.degree(input, term, x).is_some_and(|d| d >= 0.5);
    if let (true, Some(step)) = (below_sampling(ev, params), params.travel_step_mm) {
        format!(
            "no data over {:.1} mm, less than {} travel steps of {step:.2} mm: too small to tell a hole from samples \
             missing for a few frames",
            ev.gap_mm, params.min_hole_travel_steps
        )
    } else if is("gap", "none", ev.gap_mm) {
        format!(
            "no data over {:.1} mm: a few empty cells, not a hole",
            ev.gap_mm
        )
    } else if is("elongation", "oblong", ev.elongation) {
        format!(
            "no data over {:.1} mm, {:.1} times as long as wide: a band of missing samples, not a hole",
            ev.gap_mm, ev.elongation
        )
    } else if is("gap", "too_large", ev.gap_mm) {
        format!(
            "no data over {:.1} mm (too large a gap to call a hole)",
            ev.gap_mm
        )
    } else {
        format!(
            "no data over {:.1} mm: called a hole with certainty {confidence:.2} only (at least {:.2} needed)",
            ev.gap_mm, params.min_confidence
        )
    }
}

/// Cell index ranges (i0, j0, i1, j1) covering `bbox` plus `margin` cells, clamped to the grid.
pub(super) fn bbox_cells(
    range: &RangeImage,
    bbox: &[f64; 4],
    margin: usize,
) -> (usize, usize, usize, usize) {
    let ci = |x: f64| ((x - range.origin_mm[0]) / range.spacing_mm[0]).round();
    let cj = |y: f64| ((range.origin_mm[1] - y) / range.spacing_mm[1]).round();
    let clamp = |v: f64, n: usize| v.clamp(0.0, n as f64) as usize;
    let m = margin as f64;
    (
        clamp(ci(bbox[0]) - m, range.width),
        clamp(cj(bbox[3]) - m, range.height),
        clamp(ci(bbox[2]) + m + 1.0, range.width),
        clamp(cj(bbox[1]) + m + 1.0, range.height),
    )
}

/// Measures a bump or dent by fitting a bell to the deviation around it; keeps the region's figures when the fit
/// fails or is implausible.
pub(super) fn measure_bell(
    range: &RangeImage,
    maps: &SurfaceMaps,
    s: &Shape,
    sign: f64,
    peak: f64,
    grow_mm: f64,
    d: &mut Defect,
) {
    let w = range.width;
    let size = (s.bbox[2] - s.bbox[0]).max(s.bbox[3] - s.bbox[1]);
    let margin = ((size.max(2.0)) / range.spacing_mm[0].min(range.spacing_mm[1])).ceil() as usize;
    let (i0, j0, i1, j1) = bbox_cells(range, &s.bbox, margin);
    let mut samples = Vec::new();
    for j in j0..j1 {
        for i in i0..i1 {
            let v = f64::from(maps.deviation_mm[j * w + i]);
            if v.is_finite() {
                let (x, y) = cell_xy(range, i, j);
                samples.push((x, y, v));
            }
        }
    }
    if samples.len() < 12 || peak <= 0.0 {
        return;
    }
    // Initial radius from the region's size at the growth threshold: a bell is above t out to
    // r0 * acos(2 t / A − 1) / pi.
    let dt = (d.area_mm2 / std::f64::consts::PI).sqrt();
    let frac = (2.0 * grow_mm / peak - 1.0).clamp(-1.0, 1.0);
    let r0 = if frac < 0.999 {
        dt * std::f64::consts::PI / frac.acos()
    } else {
        dt
    };
    let init = BellFit {
        amplitude: sign * peak,
        centre: s.centroid,
        radius: r0.max(0.3),
        offset: 0.0,
        rms: 0.0,
    };
    let Some(f) = fit_bell(&samples, init) else {
        return;
    };
    let plausible = f.amplitude * sign > 0.0
        && f.radius > 0.3
        && f.radius < 3.0 * r0.max(1.0)
        && (f.centre[0] - s.centroid[0]).hypot(f.centre[1] - s.centroid[1]) < r0.max(1.0)
        && f.rms < 0.5 * f.amplitude.abs();
    if !plausible {
        return;
    }
    let cell_area = range.spacing_mm[0] * range.spacing_mm[1];
    let volume: f64 = samples
        .iter()
        .filter(|&&(x, y, _)| (x - f.centre[0]).hypot(y - f.centre[1]) < f.radius)
        .map(|&(_, _, v)| ((v - f.offset) * sign).max(0.0))
        .sum::<f64>()
        * cell_area;
    d.centroid_mm = f.centre;
    d.area_mm2 = std::f64::consts::PI * f.radius * f.radius;
    d.depth_mm = f.amplitude.abs();
    d.volume_mm3 = volume;
    d.bbox_mm = [
        f.centre[0] - f.radius,
        f.centre[1] - f.radius,
        f.centre[0] + f.radius,
        f.centre[1] + f.radius,
    ];
}

/// A measured cell beside a hole's gap holds a partly lit sheet when its intensity is below this fraction of the
/// intensity along its grid row beyond it ([`RIM_REFERENCE_MM`]; the same stripe on the same surface a few frames
/// away). A sheet (`laser.sigma_mm` wide) whose centre has passed the rim still lights the surface up to the rim:
/// the part of its profile left is dim, its sample sits at the rim, and the gap there is not a travel step's
/// sampling short of it. Its peak falls below half the whole sheet's once the centre lies more than 1.18 sigma
/// beyond the rim.
pub const RIM_PARTIAL_FRACTION: f32 = 0.5;
/// How far along its grid row, beyond a gap's end, the intensity a rim cell is compared with is taken (the median of
/// the measured cells there), mm: about four samples at 0.5 mm a frame.
pub const RIM_REFERENCE_MM: f64 = 2.0;

/// The area of a gap (cells of the range image), mm², corrected for the sampling along x when the travel step is
/// known: on each grid row, a run of gap cells that ends on measured surface ends on average half a step minus
/// half a cell outside the true edge (the last sample before the edge lies uniformly within one step of it, and a
/// sample's cell reaches half a cell beyond it), so the run is shortened by that much at each such end — unless the
/// range image's intensities show that end's cell to hold a partly lit sheet ([`RIM_PARTIAL_FRACTION`]), whose
/// sample sits at the rim itself: there the run is lengthened by half a cell instead (that cell reaches half a cell
/// into the hole). Measured on `stripe3d bench defects`: holes' median area error by diameter -6.3% to -2.3% with
/// every end shortened, -1.1% to +1.3% with partly lit ends told apart.
pub(super) fn hole_area(range: &RangeImage, cells: &[usize], travel_step_mm: Option<f64>) -> f64 {
    let cell_area = range.spacing_mm[0] * range.spacing_mm[1];
    let raw = cells.len() as f64 * cell_area;
    let Some(step) = travel_step_mm.filter(|s| s.is_finite() && *s > 0.0) else {
        return raw;
    };
    let dx = range.spacing_mm[0];
    let excess = (0.5 * (step - dx)).max(0.0) / dx; // cells at each measured end
    if excess == 0.0 || cells.is_empty() {
        return raw;
    }
    let w = range.width;
    let measured = |i: usize, j: usize| range.z[j * w + i].is_finite();
    let intensity = range
        .intensity
        .as_deref()
        .filter(|v| v.len() == range.z.len());
    let reach = (RIM_REFERENCE_MM / dx).round().max(1.0) as usize;
    let mut around = Vec::new();
    // Whether the measured cell (i, j), a gap's end, holds a partly lit sheet: dimmer than the cells beyond it along
    // the row (`dir` +1 or -1, away from the gap) by more than `RIM_PARTIAL_FRACTION`.
    let mut partial = |i: usize, j: usize, dir: isize| -> bool {
        let Some(v) = intensity else {
            return false;
        };
        let at = v[j * w + i];
        around.clear();
        let mut c = i as isize;
        for _ in 0..reach {
            c += dir;
            if c < 0 || c >= w as isize || !measured(c as usize, j) {
                break;
            }
            let x = v[j * w + c as usize];
            if x.is_finite() {
                around.push(x);
            }
        }
        if around.len() < reach / 2 || !at.is_finite() {
            return false;
        }
        let mid = around.len() / 2;
        let reference = *around.select_nth_unstable_by(mid, f32::total_cmp).1;
        at < RIM_PARTIAL_FRACTION * reference
    };
    let mut sorted = cells.to_vec();
    sorted.sort_unstable();
    let mut total = 0.0;
    let mut k = 0;
    while k < sorted.len() {
        // A run of consecutive cells on one grid row.
        let (j, i0) = (sorted[k] / w, sorted[k] % w);
        let mut i1 = i0;
        while k + 1 < sorted.len() && sorted[k + 1] == j * w + i1 + 1 && i1 + 1 < w {
            k += 1;
            i1 += 1;
        }
        k += 1;
        // Cells to take off at an end: the expected excess after a full sheet's sample; half a cell back on after a
        // partly lit one's (its sample sits at the rim, and its cell reaches half a cell into the hole).
        let mut end = |i: usize, dir: isize| -> f64 {
            if !measured(i, j) {
                0.0
            } else if partial(i, j, dir) {
                -0.5
            } else {
                excess
            }
        };
        let mut cut = 0.0;
        if i0 > 0 {
            cut += end(i0 - 1, -1);
        }
        if i1 + 1 < w {
            cut += end(i1 + 1, 1);
        }
        let len = (i1 - i0 + 1) as f64;
        total += (len - cut).max(0.0);
    }
    total * cell_area
}

/// How different the surface's heights are on opposite sides of a gap (`cells`, with shape `s`): the larger of the
/// left-right and top-bottom differences of the median deviation, over the part cells (`on_part`) of a ring beyond
/// the rim band (`band`, cells: half-lit stripes, walls seen in perspective), three cells deep; 50 mm when a side
/// has none (distances on a window around the gap only).
pub(super) fn height_similarity(
    range: &RangeImage,
    maps: &SurfaceMaps,
    cells: &[usize],
    s: &Shape,
    band: f32,
    on_part: &[bool],
) -> f64 {
    let w = range.width;
    // Ring: part cells beyond the rim band (half-lit stripes, walls seen in perspective), three cells deep;
    // distances on a window around the gap only.
    let ring_lo = band.max(1.0);
    let ring_hi = ring_lo + 3.0;
    let (bi0, bj0, bi1, bj1) = bbox_cells(range, &s.bbox, ring_hi.ceil() as usize + 1);
    let (ww, wh) = (bi1 - bi0, bj1 - bj0);
    let mut in_gap = vec![false; ww * wh];
    for &k in cells {
        let (i, j) = (k % w, k / w);
        if (bi0..bi1).contains(&i) && (bj0..bj1).contains(&j) {
            in_gap[(j - bj0) * ww + (i - bi0)] = true;
        }
    }
    let near = distance_to(ww, wh, |k| in_gap[k]);
    let (mut left, mut right, mut top, mut bottom) = (vec![], vec![], vec![], vec![]);
    let (ci, cj) = (
        (s.centroid[0] - range.origin_mm[0]) / range.spacing_mm[0],
        (range.origin_mm[1] - s.centroid[1]) / range.spacing_mm[1],
    );
    for j in bj0..bj1 {
        for i in bi0..bi1 {
            let k = j * w + i;
            let dist = near[(j - bj0) * ww + (i - bi0)];
            if dist < ring_lo || dist > ring_hi || !on_part[k] {
                continue;
            }
            let d = f64::from(maps.deviation_mm[k]);
            if !d.is_finite() {
                continue;
            }
            if (i as f64) < ci {
                left.push(d)
            } else {
                right.push(d)
            }
            if (j as f64) < cj {
                top.push(d)
            } else {
                bottom.push(d)
            }
        }
    }
    if left.is_empty() || right.is_empty() || top.is_empty() || bottom.is_empty() {
        50.0
    } else {
        (median(&mut left) - median(&mut right))
            .abs()
            .max((median(&mut top) - median(&mut bottom)).abs())
    }
}

/// What lies under a gap (`cells`): the reference heights over it, whether its bottom is seen (at least
/// `min_seen_share` of its cells hold heights: a few wall samples are not a bottom), the floor (the median seen
/// height, or the belt when the bottom is not seen) and the reference's median, mm; the depth is the reference over
/// the floor.
pub(super) fn gap_depth(
    range: &RangeImage,
    maps: &SurfaceMaps,
    cells: &[usize],
    min_seen_share: f64,
) -> (Vec<f64>, bool, f64, f64) {
    let mut refs: Vec<f64> = cells
        .iter()
        .map(|&k| f64::from(maps.reference_mm[k]))
        .filter(|v| v.is_finite())
        .collect();
    let seen: Vec<f64> = cells
        .iter()
        .map(|&k| f64::from(range.z[k]))
        .filter(|v| v.is_finite())
        .collect();
    let bottom_seen = seen.len() as f64 >= min_seen_share * cells.len() as f64;
    let floor = if bottom_seen {
        let mut seen = seen;
        median(&mut seen).max(0.0)
    } else {
        0.0
    };
    let reference = median(&mut refs);
    (refs, bottom_seen, floor, reference)
}
