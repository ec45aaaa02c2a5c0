//! Defect detection: regions of the characterization maps that deviate, gaps in the data, and material missing
//! from the part's outline, classified by the paper's surface rules (`rules/surface.fll`, through the fuzzy engine)
//! and measured.
//!
//! 1. **The part** is the largest 8-connected set of cells above the belt; specks elsewhere are not the part.
//! 2. **Deviating regions**: seeds where the 3 x 3 smoothed deviation exceeds [`DetectParams::seed_mm`] (not within
//!    [`DetectParams::edge_band_mm`] of the part's edge, where half-lit stripes bias heights), grown over cells of
//!    the same sign above [`DetectParams::grow_mm`] (hysteresis).
//! 3. **Gaps**: regions without part data enclosed by the part, where the reference expects surface.
//! 4. **Edge chips**: cells inside the expected outline (the convex hull of the part, cut to where the reference
//!    expects surface) that are not the part and are open to the outside.
//! 5. Each candidate's evidence (largest |mean curvature|, direction uniformity, gap size, height similarity across
//!    the gap, elongation, notch depth) goes through the rule base; the most certain output names the kind, its
//!    certainty is the confidence; below 0.5 the kind is `anomaly`.
//! 6. **Measurement**: bumps and dents are fitted with a smooth bell (raised cosine, least squares with an offset,
//!    Levenberg-Marquardt), which gives the footprint (area), centre and height free of the detection threshold; the
//!    volume sums the measured deviation over the footprint. Holes, chips and scratches are measured from their
//!    cells; a hole's depth is down to the belt when its bottom is not seen (the part lies on the belt).

use crate::CoreError;
use crate::accumulate::RangeImage;
use crate::characterize::{
    CellClass, CharacterizeParams, PreparedGolden, ReferenceInfo, ReferenceSource, SurfaceMaps,
    cell_xy, geometry_at, median, reference_heights, remove_outliers, surface_maps,
};
use crate::error::InspectionError;
use crate::rules::RuleBase;
use stripe3d_fuzzy::Engine;

mod classify;
mod measure;
mod morphology;
#[cfg(test)]
mod tests;

pub use classify::*;
pub use measure::*;
pub use morphology::*;

/// Regions of part cells (`on_part`) whose smoothed deviation reaches `thresholds[1]` (mm) with one sign, kept when
/// one of their cells reaches `thresholds[0]` where `seeds_allowed` (hysteresis: strong cells seed a region, weaker
/// ones extend it), raised regions first, then sunken ones, each in raster order of its first cell; with their
/// sign (+1 raised, −1 sunken).
fn deviating_regions(
    w: usize,
    h: usize,
    on_part: &[bool],
    smoothed_mm: &[f32],
    [seed_mm, grow_mm]: [f64; 2],
    seeds_allowed: impl Fn(usize) -> bool,
) -> Vec<(Vec<usize>, f64)> {
    let mut out = Vec::new();
    for sign in [1.0f32, -1.0] {
        let grow = |k: usize| on_part[k] && smoothed_mm[k] * sign >= grow_mm as f32;
        let (label, sizes) = components(w, h, grow, true);
        let mut seeded = vec![false; sizes.len()];
        for k in 0..w * h {
            if label[k] != 0 && smoothed_mm[k] * sign >= seed_mm as f32 && seeds_allowed(k) {
                seeded[label[k] as usize] = true;
            }
        }
        let mut cells: Vec<Vec<usize>> = vec![Vec::new(); sizes.len()];
        for k in 0..w * h {
            if label[k] != 0 && seeded[label[k] as usize] {
                cells[label[k] as usize].push(k);
            }
        }
        out.extend(
            cells
                .into_iter()
                .filter(|c| !c.is_empty())
                .map(|c| (c, f64::from(sign))),
        );
    }
    out
}

/// The sides of the grid the part (`on_part`, a `w` x `h` grid) touches: only its two outermost rows and columns
/// can.
fn border_sides(w: usize, h: usize, on_part: &[bool]) -> Vec<&'static str> {
    let band_rows = (0..h.min(2)).chain(h.saturating_sub(2).max(2)..h);
    let band_cols = (0..w.min(2)).chain(w.saturating_sub(2).max(2)..w);
    let row_hit = |j: usize| (0..w).any(|i| on_part[j * w + i]);
    let col_hit = |i: usize| (0..h).any(|j| on_part[j * w + i]);
    let mut touches = Vec::new();
    for j in band_rows {
        let side = if j <= 1 { "top (+y)" } else { "bottom (−y)" };
        if !touches.contains(&side) && row_hit(j) {
            touches.push(side);
        }
    }
    for i in band_cols {
        let side = if i <= 1 {
            "start of the scan (−x)"
        } else {
            "end of the scan (+x)"
        };
        if !touches.contains(&side) && col_hit(i) {
            touches.push(side);
        }
    }
    touches
}

/// The bounding box (x0, y0, x1, y1), mm, of the part's cells (`on_part`) including their own extent.
fn part_bbox(range: &RangeImage, on_part: &[bool]) -> [f64; 4] {
    let (w, h) = (range.width, range.height);
    let extremes = row_extremes(w, h, on_part);
    extremes.iter().enumerate().fold(
        [
            f64::INFINITY,
            f64::INFINITY,
            f64::NEG_INFINITY,
            f64::NEG_INFINITY,
        ],
        |b, (j, e)| {
            let Some((i0, i1)) = *e else { return b };
            let (x0, y) = cell_xy(range, i0, j);
            let (x1, _) = cell_xy(range, i1, j);
            let (hx, hy) = (range.spacing_mm[0] / 2.0, range.spacing_mm[1] / 2.0);
            [
                b[0].min(x0 - hx),
                b[1].min(y - hy),
                b[2].max(x1 + hx),
                b[3].max(y + hy),
            ]
        },
    )
}

/// The part's expected outline: the cells of its convex hull (of `on_part`, a `w` x `h` grid) where the reference
/// expects surface (`reference_mm` finite).
fn expected_outline(w: usize, h: usize, on_part: &[bool], reference_mm: &[f32]) -> Vec<bool> {
    let rows = hull_rows(w, h, on_part);
    let mut expected_mask = vec![false; w * h];
    for (j, row) in rows.iter().enumerate() {
        let Some((a, b)) = *row else { continue };
        let lo = (a - 1e-9).ceil().max(0.0) as usize;
        let hi = ((b + 1e-9).floor() as usize).min(w - 1);
        if lo <= hi {
            let span = j * w + lo..=j * w + hi;
            for (e, r) in expected_mask[span.clone()]
                .iter_mut()
                .zip(&reference_mm[span])
            {
                *e = r.is_finite();
            }
        }
    }
    expected_mask
}

/// Stage 2's regions (with their signs) weighed by the rules: bumps and dents measured with the bell fit, or turned
/// into unmeasured areas (too narrow along the travel for the samples to resolve; nameless outlier heights).
fn weigh_regions(
    candidates: &[(Vec<usize>, f64)],
    range: &RangeImage,
    maps: &SurfaceMaps,
    grow_mm: f64,
    rules: &mut SurfaceRules,
    params: &DetectParams,
    out: &mut Detection,
) -> Result<(), CoreError> {
    let w = range.width;
    let cell_area = range.spacing_mm[0] * range.spacing_mm[1];
    for (cells, sign) in candidates {
        let s = shape(range, cells, |k| f64::from(maps.deviation_mm[k]).abs());
        let (mut sum, mut sum_abs, mut curv) = (0.0, 0.0, 0.0f64);
        let mut peak = 0.0f64;
        let mut with_curvature = 0usize;
        for &k in cells {
            let d = f64::from(maps.deviation_mm[k]);
            if d.is_finite() {
                sum += d;
                sum_abs += d.abs();
                if d * sign > peak {
                    peak = d * sign;
                }
            }
            if let Some(g) = geometry_at(range, maps, k % w, k / w) {
                curv = curv.max(g.mean_curvature.abs());
                with_curvature += 1;
            }
        }
        if 2 * with_curvature < cells.len() {
            // Most of the region lies where the derivative window is incomplete (a narrow fragment between
            // gaps): bound its curvature from its height and size as a bell's top, pi² A / (2 r²).
            let r2 = cells.len() as f64 * cell_area / std::f64::consts::PI;
            curv = curv.max(std::f64::consts::PI.powi(2) * peak / (2.0 * r2));
        }
        let ev = Evidence {
            curvature_per_mm: curv,
            direction: if sum_abs > 0.0 { sum / sum_abs } else { 0.0 },
            gap_mm: 0.0,
            height_similarity_mm: 50.0,
            elongation: s.elongation,
            edge_notch_mm: 0.0,
            cells: cells.len(),
        };
        let area = cells.len() as f64 * cell_area;
        let (kind, confidence, reported) = weigh(
            out,
            CandidateSource::Surface,
            s.centroid,
            area,
            ev,
            rules,
            params,
        )?;
        if reported && matches!(kind, DefectKind::Bump | DefectKind::Dent) {
            if let Some(step) = params.travel_step_mm.filter(|s| s.is_finite() && *s > 0.0) {
                let width = half_peak_travel_width(range, cells, &maps.deviation_mm, *sign, peak);
                if width < params.min_region_travel_steps * step {
                    // Not a surface the samples resolve: out of the candidates (learning never sees it) and into
                    // the unmeasured.
                    out.candidates.pop();
                    out.unmeasured.push(Unmeasured {
                        centroid_mm: s.centroid,
                        area_mm2: area,
                        reason: format!(
                            "{peak:.2} mm off the reference, but only {width:.2} mm wide along the travel at half \
                             that: under {} travel steps of {step:.2} mm, as one frame's misplaced samples are (a \
                             bump or dent 2 mm across is 1 mm wide there)",
                            params.min_region_travel_steps
                        ),
                    });
                    continue;
                }
            }
        }
        if !reported {
            // Small, steep and nameless: heights a wrong stripe index or a glint put there, not a surface.
            out.unmeasured.push(Unmeasured {
                centroid_mm: s.centroid,
                area_mm2: area,
                reason: format!(
                    "{peak:.2} mm off the reference over {area:.2} mm² with a curvature of {curv:.1}/mm: outlier \
                     heights, not a surface the rules can name"
                ),
            });
            continue;
        }
        let mut d = Defect {
            kind,
            centroid_mm: s.centroid,
            bbox_mm: s.bbox,
            area_mm2: area,
            depth_mm: peak,
            volume_mm3: sum_abs * cell_area,
            confidence,
            bottom_seen: true,
            evidence: ev,
        };
        if matches!(kind, DefectKind::Bump | DefectKind::Dent) {
            measure_bell(range, maps, &s, *sign, peak, grow_mm, &mut d);
        }
        if let Some(c) = out.candidates.last_mut() {
            c.defect = Some(out.defects.len());
        }
        out.defects.push(d);
    }
    Ok(())
}

/// Stage 3's gaps weighed by the rules: holes measured (area, depth, volume), or turned into unmeasured areas (a
/// designed opening is skipped; a shadow, an edge or a seam of missing samples is not a hole).
#[allow(clippy::too_many_arguments)]
fn weigh_gaps(
    gaps: &[Vec<usize>],
    range: &RangeImage,
    maps: &SurfaceMaps,
    band: f32,
    on_part: &[bool],
    rules: &mut SurfaceRules,
    params: &DetectParams,
    out: &mut Detection,
) -> Result<(), CoreError> {
    let cell_area = range.spacing_mm[0] * range.spacing_mm[1];
    for cells in gaps {
        let area = cells.len() as f64 * cell_area;
        if area < params.min_gap_mm2 {
            continue;
        }
        let expected_share = cells
            .iter()
            .filter(|&&k| maps.reference_mm[k].is_finite())
            .count() as f64
            / cells.len() as f64;
        if expected_share < 0.5 {
            // The reference has no surface here either: a designed opening.
            continue;
        }
        let s = shape(range, cells, |_| 1.0);
        let similarity = height_similarity(range, maps, cells, &s, band, on_part);
        let ev = Evidence {
            curvature_per_mm: 0.0,
            direction: 0.0,
            gap_mm: 2.0 * (area / std::f64::consts::PI).sqrt(),
            height_similarity_mm: similarity,
            elongation: s.elongation,
            edge_notch_mm: 0.0,
            cells: cells.len(),
        };
        let (kind, confidence, reported) = weigh(
            out,
            CandidateSource::Gap,
            s.centroid,
            area,
            ev,
            rules,
            params,
        )?;
        if !reported {
            out.unmeasured.push(Unmeasured {
                centroid_mm: s.centroid,
                area_mm2: area,
                reason: if similarity >= 50.0 {
                    "no data and the surface around it is not measured on every side".into()
                } else if similarity > 0.5 {
                    format!("no data, with {similarity:.2} mm between the heights on either side (a shadow or an edge)")
                } else {
                    gap_reason(rules, &ev, confidence, params)
                },
            });
            continue;
        }
        let (refs, bottom_seen, floor, reference) =
            gap_depth(range, maps, cells, params.min_seen_share);
        // A gap whose cells mostly hold the surface's own heights is a seam of missing samples (measured strips too
        // thin for the part's mask between them), not a hole.
        if bottom_seen && reference - floor < params.seed_mm {
            out.unmeasured.push(Unmeasured {
                centroid_mm: s.centroid,
                area_mm2: area,
                reason: format!(
                    "no data in strips, the cells between them at the surface's own height ({:+.3} mm): not a hole",
                    floor - reference
                ),
            });
            continue;
        }
        if let Some(c) = out.candidates.last_mut() {
            c.defect = Some(out.defects.len());
        }
        let measured = hole_area(range, cells, params.travel_step_mm);
        out.defects.push(Defect {
            kind,
            centroid_mm: s.centroid,
            bbox_mm: s.bbox,
            area_mm2: measured,
            depth_mm: reference - floor,
            volume_mm3: refs.iter().map(|r| (r - floor).max(0.0)).sum::<f64>()
                * cell_area
                * (measured / area),
            confidence,
            bottom_seen,
            evidence: ev,
        });
    }
    Ok(())
}

/// Stage 4: edge chips (cells of the expected outline, not the part, open to the grid's border) weighed by the
/// rules; a notch without data where not even the belt is seen is unmeasured, not missing material.
#[allow(clippy::too_many_arguments)]
fn weigh_chips(
    range: &RangeImage,
    maps: &SurfaceMaps,
    on_part: &[bool],
    expected: &[bool],
    open_to_border: &[bool],
    rules: &mut SurfaceRules,
    params: &DetectParams,
    out: &mut Detection,
) -> Result<(), CoreError> {
    let (w, h) = (range.width, range.height);
    let cell_area = range.spacing_mm[0] * range.spacing_mm[1];
    let chip = |k: usize| !on_part[k] && expected[k] && open_to_border[k];
    let (clabel, csizes) = components(w, h, chip, false);
    if csizes.len() > 1 {
        let depth = distance_to(w, h, |k| !expected[k]);
        let mut cells: Vec<Vec<usize>> = vec![Vec::new(); csizes.len()];
        for k in 0..w * h {
            if clabel[k] != 0 {
                cells[clabel[k] as usize].push(k);
            }
        }
        for c in cells
            .iter()
            .filter(|c| c.len() as f64 * cell_area >= params.min_gap_mm2)
        {
            let notch = f64::from(c.iter().map(|&k| depth[k]).fold(0.0f32, f32::max))
                * range.spacing_mm[0].min(range.spacing_mm[1]);
            let s = shape(range, c, |_| 1.0);
            let ev = Evidence {
                curvature_per_mm: 0.0,
                direction: 0.0,
                gap_mm: 0.0,
                height_similarity_mm: 50.0,
                elongation: s.elongation,
                edge_notch_mm: notch,
                cells: c.len(),
            };
            let area = c.len() as f64 * cell_area;
            // Missing material shows the belt (or a lower surface) where the part should be; a notch of cells
            // without any data is missing measurement, not missing material.
            let seen = c
                .iter()
                .filter(|&&k| maps.class[k] == CellClass::Belt)
                .count();
            if (seen as f64) < params.min_seen_share * c.len() as f64 {
                if ev.edge_notch_mm >= params.edge_band_mm {
                    out.unmeasured.push(Unmeasured {
                        centroid_mm: s.centroid,
                        area_mm2: area,
                        reason: format!(
                            "no data {notch:.2} mm into the part's outline (the belt is not seen there either)"
                        ),
                    });
                }
                continue;
            }
            let (kind, confidence, reported) = weigh(
                out,
                CandidateSource::Edge,
                s.centroid,
                area,
                ev,
                rules,
                params,
            )?;
            if !reported {
                continue;
            }
            let mut refs: Vec<f64> = c
                .iter()
                .map(|&k| f64::from(maps.reference_mm[k]))
                .filter(|v| v.is_finite())
                .collect();
            let area = c.len() as f64 * cell_area;
            if let Some(c) = out.candidates.last_mut() {
                c.defect = Some(out.defects.len());
            }
            out.defects.push(Defect {
                kind,
                centroid_mm: s.centroid,
                bbox_mm: s.bbox,
                area_mm2: area,
                depth_mm: median(&mut refs),
                volume_mm3: refs.iter().sum::<f64>() * cell_area,
                confidence,
                bottom_seen: false,
                evidence: ev,
            });
        }
    }
    Ok(())
}

/// The kinds of defect.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum DefectKind {
    /// Material raised above the surface, smooth.
    Bump,
    /// Material pressed below the surface, smooth.
    Dent,
    /// A gap in the surface with similar heights around it.
    Hole,
    /// A long, narrow groove.
    Scratch,
    /// Material missing from the part's outline.
    EdgeChip,
    /// A deviation the rules could not name with certainty.
    Anomaly,
}

impl DefectKind {
    /// Every kind.
    pub const ALL: [DefectKind; 6] = [
        DefectKind::Bump,
        DefectKind::Dent,
        DefectKind::Hole,
        DefectKind::Scratch,
        DefectKind::EdgeChip,
        DefectKind::Anomaly,
    ];

    /// The name in reports: `bump`, `dent`, `hole`, `scratch`, `edge-chip`, `anomaly`.
    pub fn name(self) -> &'static str {
        match self {
            DefectKind::Bump => "bump",
            DefectKind::Dent => "dent",
            DefectKind::Hole => "hole",
            DefectKind::Scratch => "scratch",
            DefectKind::EdgeChip => "edge-chip",
            DefectKind::Anomaly => "anomaly",
        }
    }

    /// The kind of a report name.
    pub fn from_name(name: &str) -> Option<Self> {
        Self::ALL.into_iter().find(|k| k.name() == name)
    }
}

/// What the rules were told about a candidate.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct Evidence {
    /// Largest |mean curvature| in the region, 1/mm.
    pub curvature_per_mm: f64,
    /// Signed uniformity of the deviation: −1 all downward, +1 all upward.
    pub direction: f64,
    /// Equivalent diameter of a gap in the data, mm (0 for surface regions).
    pub gap_mm: f64,
    /// Height difference between the two sides of a gap, mm.
    pub height_similarity_mm: f64,
    /// Length over width (1 for round).
    pub elongation: f64,
    /// How far missing material reaches into the outline, mm.
    pub edge_notch_mm: f64,
    /// Cells of the region.
    pub cells: usize,
}

/// One defect, located and measured (part coordinates).
#[derive(Debug, Clone, PartialEq)]
pub struct Defect {
    /// What it is.
    pub kind: DefectKind,
    /// Centre, mm.
    pub centroid_mm: [f64; 2],
    /// Bounding box x0, y0, x1, y1, mm.
    pub bbox_mm: [f64; 4],
    /// Footprint area, mm².
    pub area_mm2: f64,
    /// Greatest height (bump) or depth (the others) relative to the reference, mm.
    pub depth_mm: f64,
    /// Material added or removed, mm³.
    pub volume_mm3: f64,
    /// Certainty of the kind, 0 to 1 (the rule base's output).
    pub confidence: f64,
    /// Whether a hole's bottom was seen (false: assumed through to the belt).
    pub bottom_seen: bool,
    /// The evidence the rules weighed.
    pub evidence: Evidence,
}

/// A region the scan could not measure and that is not a hole (a shadow, an occlusion): reported so that "no
/// defect" never silently covers unmeasured surface.
#[derive(Debug, Clone, PartialEq)]
pub struct Unmeasured {
    /// Centre, mm.
    pub centroid_mm: [f64; 2],
    /// Area, mm².
    pub area_mm2: f64,
    /// Why it is not a hole.
    pub reason: String,
}

/// Parameters of detection.
#[derive(Debug, Clone, PartialEq)]
pub struct DetectParams {
    /// Smoothed deviation that starts a region, mm. Half the smallest defect of interest (0.1 mm); 20 times the
    /// smoothed height noise of the default set-up (about 0.0025 mm), so clean plates stay clean.
    pub seed_mm: f64,
    /// Smoothed deviation a region grows over, mm.
    pub grow_mm: f64,
    /// Smallest region reported, mm².
    pub min_area_mm2: f64,
    /// Smallest gap considered, mm² (scattered empty cells are not holes).
    pub min_gap_mm2: f64,
    /// Band along the part's edges (and the rims of holes) where regions are not seeded, mm: half-lit stripes
    /// there are biased by up to 0.4 mm, and the grid carries the bias about one frame step (0.5 mm) inward
    /// (measured at hole rims on the defect benchmark).
    pub edge_band_mm: f64,
    /// Cells this far (mm) from the median of their 5 x 5 neighbourhood are outliers (see
    /// [`crate::characterize::remove_outliers`]): a stripe coded one index off lands 1.3 mm or more away, while the
    /// mixed cells on the rim of a hole (top and wall samples averaged) stay within 1 mm and keep holes their size
    /// (0.5 mm cost 6% of the holes their 15% area tolerance on the defect benchmark).
    pub outlier_mm: f64,
    /// Anomalies (regions the rules cannot name) smaller than this are reported as unmeasured outlier heights,
    /// mm²: a wrongly coded stripe fragment gives a few cells millimetres off.
    pub min_anomaly_mm2: f64,
    /// Least share of an edge notch's cells that must show the belt for it to be missing material.
    pub min_seen_share: f64,
    /// Certainty below which a candidate is an `anomaly`.
    pub min_confidence: f64,
    /// Most candidates evaluated (a guard against a wildly wrong reference).
    pub max_candidates: usize,
    /// Smallest hole, in conveyor travel steps across (equivalent diameter of its gap), when the step is known
    /// ([`DetectParams::travel_step_mm`]): a stripe's samples missing for two or three frames (coding dropped them as
    /// ambiguous) leave a gap with the surface's height on every side, as a hole does. Measured on the demo part
    /// scanned with seeds 1-7 against its golden scan: such gaps up to 1.55 mm (3.1 steps of 0.5 mm) across, four
    /// of which were reported as holes; the smallest holes of interest (2 mm) leave 1.93 mm or more (3.9 steps;
    /// `bench defects`). Smaller gaps are reported as unmeasured, with this reason.
    pub min_hole_travel_steps: f64,
    /// Narrowest bump or dent, in conveyor travel steps along x at half its peak deviation, when the step is known
    /// ([`DetectParams::travel_step_mm`]). One frame's samples misplaced (a stripe read 1.5-2 mm low on three rows
    /// of one frame of the demo part) deviate over about one step, the fill between the frames before and after;
    /// a raised-cosine bump or dent of diameter D is D / 2 wide there, a step per millimetre of diameter at 0.5 mm
    /// a frame. Measured: the demo part's false one-frame dent 0.22 mm wide (0.44 steps), the narrowest true bump
    /// or dent of `bench defects` (2 mm across) 0.88 mm (1.76 steps). Narrower regions are reported as unmeasured.
    pub min_region_travel_steps: f64,
    /// Conveyor travel between frames, mm (the sampling step along x), when known. The last sample before a hole
    /// lies anywhere up to a step short of its rim, and the first after it as far beyond: a hole's measured area
    /// is corrected by the expected excess on each side that ends on measured surface (`hole_area`).
    pub travel_step_mm: Option<f64>,
    /// Probability that the scan's own height noise starts a region anywhere on a clean part. The seed threshold is
    /// raised above [`DetectParams::seed_mm`] where the noise needs it (see [`Detectable`]); 0 keeps `seed_mm`
    /// whatever the noise.
    pub false_alarm: f64,
}

/// What a scan lets inspection see, from the scan's own height noise.
///
/// The noise is the robust standard deviation (1.4826 x the median absolute deviation from the median) of the
/// smoothed deviation over the part, away from its edges: defects cover a small share of a part, so they do not move
/// it. Over the part's independent samples (its cells over the 9 of the smoothing window), Gaussian noise of that
/// deviation exceeds `k` standard deviations somewhere with probability [`DetectParams::false_alarm`] when
/// `k = Φ⁻¹(1 − false_alarm / 2n)`; the seed threshold is the larger of the method's `seed_mm` and `k` times the
/// noise, and the growth threshold keeps its ratio to it.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct Detectable {
    /// Robust standard deviation of the smoothed deviation over the part, mm.
    pub noise_mm: f64,
    /// Standard deviations of that noise a seed must reach (0: no noise condition).
    pub sigmas: f64,
    /// The smoothed deviation that starts a region, mm: the smallest bump height or dent depth seen.
    pub threshold_mm: f64,
    /// Whether the noise raised the threshold above the method's.
    pub raised: bool,
    /// Smallest hole seen, mm across (from the smallest gap and, when the travel step is known, the fewest steps).
    pub hole_mm: f64,
}

/// The standard normal quantile `Φ⁻¹(p)`, 0 < p < 1 (P. J. Acklam's rational approximation, relative error below
/// 1.2e-9). Written out here rather than taken from a statistics crate: it is the one function inspection needs.
pub fn normal_quantile(p: f64) -> f64 {
    const A: [f64; 6] = [
        -3.969683028665376e1,
        2.209460984245205e2,
        -2.759285104469687e2,
        1.383_577_518_672_69e2,
        -3.066479806614716e1,
        2.506628277459239,
    ];
    const B: [f64; 5] = [
        -5.447609879822406e1,
        1.615858368580409e2,
        -1.556989798598866e2,
        6.680131188771972e1,
        -1.328068155288572e1,
    ];
    const C: [f64; 6] = [
        -7.784894002430293e-3,
        -3.223964580411365e-1,
        -2.400758277161838,
        -2.549732539343734,
        4.374664141464968,
        2.938163982698783,
    ];
    const D: [f64; 4] = [
        7.784695709041462e-3,
        3.224671290700398e-1,
        2.445134137142996,
        3.754408661907416,
    ];
    if p.is_nan() || p <= 0.0 {
        return f64::NEG_INFINITY;
    }
    if p >= 1.0 {
        return f64::INFINITY;
    }
    let tail = |q: f64| {
        (((((C[0] * q + C[1]) * q + C[2]) * q + C[3]) * q + C[4]) * q + C[5])
            / ((((D[0] * q + D[1]) * q + D[2]) * q + D[3]) * q + 1.0)
    };
    const LOW: f64 = 0.02425;
    if p < LOW {
        tail((-2.0 * p.ln()).sqrt())
    } else if p > 1.0 - LOW {
        -tail((-2.0 * (1.0 - p).ln()).sqrt())
    } else {
        let q = p - 0.5;
        let r = q * q;
        (((((A[0] * r + A[1]) * r + A[2]) * r + A[3]) * r + A[4]) * r + A[5]) * q
            / (((((B[0] * r + B[1]) * r + B[2]) * r + B[3]) * r + B[4]) * r + 1.0)
    }
}

/// The [`Detectable`] of a part whose smoothed deviations (away from its edges) are `smoothed`.
fn detectable(smoothed: &mut [f64], params: &DetectParams) -> Detectable {
    let hole_mm = {
        let gap = (4.0 * params.min_gap_mm2 / std::f64::consts::PI).sqrt();
        let steps = params
            .travel_step_mm
            .map_or(0.0, |s| s * params.min_hole_travel_steps);
        gap.max(steps)
    };
    let mut out = Detectable {
        threshold_mm: params.seed_mm,
        hole_mm,
        ..Detectable::default()
    };
    if smoothed.len() < 9 || params.false_alarm <= 0.0 {
        return out;
    }
    let centre = median(smoothed);
    let mut dev: Vec<f64> = smoothed.iter().map(|v| (v - centre).abs()).collect();
    out.noise_mm = 1.4826 * median(&mut dev);
    let samples = smoothed.len() as f64 / 9.0;
    out.sigmas = normal_quantile(1.0 - params.false_alarm / (2.0 * samples.max(1.0)));
    let needed = out.sigmas * out.noise_mm;
    if needed > params.seed_mm {
        out.threshold_mm = needed;
        out.raised = true;
    }
    out
}

impl Default for DetectParams {
    fn default() -> Self {
        Self {
            seed_mm: 0.05,
            grow_mm: 0.02,
            min_area_mm2: 0.5,
            min_gap_mm2: 0.8,
            edge_band_mm: 1.0,
            outlier_mm: 1.0,
            min_anomaly_mm2: 2.0,
            min_seen_share: 0.3,
            min_confidence: 0.5,
            max_candidates: 500,
            min_hole_travel_steps: 3.5,
            min_region_travel_steps: 1.5,
            travel_step_mm: None,
            false_alarm: 0.01,
        }
    }
}

/// What detection found.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct Detection {
    /// Defects, sorted by position (y descending, then x) for stable reports.
    pub defects: Vec<Defect>,
    /// Unmeasured regions that are not holes.
    pub unmeasured: Vec<Unmeasured>,
    /// Conditions that limit what the inspection can say (the part runs out of the view, little data).
    pub warnings: Vec<String>,
    /// Cells of the part.
    pub part_cells: usize,
    /// Share of the expected outline that holds data.
    pub coverage: f64,
    /// Bounding box of the part's measured surface x0, y0, x1, y1, mm (the product frame is centred on it).
    pub part_bbox_mm: [f64; 4],
    /// Every candidate the rules weighed, in the order found.
    pub candidates: Vec<Candidate>,
    /// What this scan let inspection see.
    pub detectable: Detectable,
}

/// Finds, classifies and measures the defects of a characterized range image.
pub fn detect(
    range: &RangeImage,
    maps: &SurfaceMaps,
    rules: &mut SurfaceRules,
    params: &DetectParams,
) -> Result<Detection, CoreError> {
    let (w, h) = (range.width, range.height);
    if maps.class.len() != w * h {
        return Err(CoreError::InvalidParameter {
            field: "maps",
            value: maps.class.len().to_string(),
            reason: format!("characterization maps of another grid (this one is {w}x{h})"),
        });
    }
    let cell_area = range.spacing_mm[0] * range.spacing_mm[1];
    let mut out = Detection::default();
    // 1. The part: the largest 8-connected set of part cells.
    // Seams of missing cells (between the bands of neighbouring stripes, along shadows) must not split the part:
    // components are taken on the part mask closed over two cells.
    let is_part: Vec<bool> = maps.class.iter().map(|c| *c == CellClass::Part).collect();
    let closed = closing(w, h, &is_part, 2);
    let (plabel, psizes) = components(w, h, |k| closed[k], true);
    let Some(&main_size) = psizes.iter().skip(1).max() else {
        return Err(CoreError::Inspection(InspectionError::NoPart));
    };
    // Every large piece is the part: a seam wider than the closing must not leave half the part uninspected.
    let min_piece = (main_size / 20)
        .max((MIN_PIECE_MM2 / cell_area) as usize)
        .min(main_size);
    let pieces: Vec<bool> = psizes.iter().map(|&n| n >= min_piece).collect();
    let in_part = |k: usize| plabel[k] != 0 && pieces[plabel[k] as usize];
    let piece_count = pieces.iter().skip(1).filter(|&&p| p).count();
    if piece_count > 1 {
        out.warnings.push(format!(
            "the part's surface falls into {piece_count} pieces separated by unmeasured strips: check the scan \
             (stripe coding, shadows)"
        ));
    }
    let main_part: Vec<bool> = (0..w * h).map(|k| in_part(k) && is_part[k]).collect();
    let opened = opening(w, h, &main_part);
    let on_part = |k: usize| opened[k];
    out.part_cells = opened.iter().filter(|&&p| p).count();
    if (main_size as f64) * cell_area < 4.0 {
        return Err(CoreError::Inspection(InspectionError::TooLittleSurface {
            area_mm2: main_size as f64 * cell_area,
        }));
    }
    // The part running out of the measured area.
    let touches = border_sides(w, h, &opened);
    if !touches.is_empty() {
        out.warnings.push(format!(
            "the part runs out of the measured area at the {}: what lies beyond was not inspected",
            touches.join(", ")
        ));
    }
    // Rows and columns, never cell indices divided by the width: the part is most of the grid.
    out.part_bbox_mm = part_bbox(range, &opened);
    // Expected outline: the hull of the part, where the reference expects surface.
    let expected_mask = expected_outline(w, h, &opened, &maps.reference_mm);
    let expected_cells = expected_mask.iter().filter(|&&e| e).count();
    out.coverage = opened
        .iter()
        .zip(&expected_mask)
        .filter(|(p, e)| **p && **e)
        .count() as f64
        / expected_cells.max(1) as f64;
    // Distance to the part's edges and the rims of its gaps; seams narrower than the closing (a missing column
    // between two stripes' bands) are not edges: the surface on both sides of them is whole.
    let edge_dist = distance_to(w, h, |k| !in_part(k) || !closed[k]);
    let band = (params.edge_band_mm / range.spacing_mm[0].min(range.spacing_mm[1])) as f32;
    // What the scan's noise lets it see (module docs of `Detectable`), over the part away from its edges.
    let mut away: Vec<f64> = (0..w * h)
        .filter(|&k| on_part(k) && edge_dist[k] > band)
        .map(|k| f64::from(maps.smoothed_mm[k]))
        .filter(|v| v.is_finite())
        .collect();
    out.detectable = detectable(&mut away, params);
    let seed_mm = out.detectable.threshold_mm;
    let grow_mm = params.grow_mm * seed_mm / params.seed_mm;
    if out.detectable.raised {
        out.warnings.push(format!(
            "the method looks for deviations from {:.3} mm, but this scan's height noise ({:.4} mm, smoothed) lets \
             it tell only {seed_mm:.3} mm and more from noise: smaller bumps and dents cannot be seen, and the \
             threshold was raised to {seed_mm:.3} mm (a scan with less noise: a finer frame step, more light, a \
             matte surface)",
            params.seed_mm, out.detectable.noise_mm
        ));
    }
    // 2. Deviating regions by hysteresis, one sign at a time.
    let mut candidates =
        deviating_regions(w, h, &opened, &maps.smoothed_mm, [seed_mm, grow_mm], |k| {
            edge_dist[k] > band
        });
    candidates.retain(|(c, _)| c.len() as f64 * cell_area >= params.min_area_mm2);
    if candidates.len() > params.max_candidates {
        out.warnings.push(format!(
            "{} deviating regions: more than the {} evaluated; the reference surface probably does not fit this part \
             (use a golden scan or the product's model)",
            candidates.len(),
            params.max_candidates
        ));
        candidates.truncate(params.max_candidates);
    }
    weigh_regions(&candidates, range, maps, grow_mm, rules, params, &mut out)?;
    // 3. Gaps: regions without part data that the outside cannot reach.
    let (gaps, open_to_border) = enclosed_gaps(w, h, &opened);
    weigh_gaps(&gaps, range, maps, band, &opened, rules, params, &mut out)?;
    // 4. Edge chips: expected cells, not the part, open to the outside.
    weigh_chips(
        range,
        maps,
        &opened,
        &expected_mask,
        &open_to_border,
        rules,
        params,
        &mut out,
    )?;
    if out.coverage < 0.9 {
        out.warnings.push(format!(
            "only {:.0}% of the part's outline holds data: unmeasured surface cannot be judged",
            100.0 * out.coverage
        ));
    }
    // A hole's wall: a steep region the rules cannot name ("anomaly") that lies within a found hole's box (plus a
    // margin) is the wall of that hole seen in perspective, not a defect of its own. Measured on the defect benchmark:
    // every false defect left after stripe coding settled its near ties was such a wall.
    let holes: Vec<[f64; 4]> = out
        .defects
        .iter()
        .filter(|d| d.kind == DefectKind::Hole)
        .map(|d| d.bbox_mm)
        .collect();
    let wall = |d: &Defect| {
        let [x, y] = d.centroid_mm;
        let m = HOLE_WALL_MARGIN_MM;
        d.kind == DefectKind::Anomaly
            && holes
                .iter()
                .any(|b| x >= b[0] - m && x <= b[2] + m && y >= b[1] - m && y <= b[3] + m)
    };
    // A piece of a bump or dent: a smaller one of the same kind whose centre lies within a larger one's fitted
    // footprint is part of it (a seam or a column of wrong heights split the region; the bell fit of the larger
    // piece already measures the whole). Traced on the demo: a 2.5 mm² "dent" 1.4 mm from the centre of the 5 mm
    // dent.
    let piece = |k: usize| {
        let d = &out.defects[k];
        matches!(d.kind, DefectKind::Bump | DefectKind::Dent)
            && out.defects.iter().enumerate().any(|(o, e)| {
                o != k
                    && e.kind == d.kind
                    && e.area_mm2 > d.area_mm2
                    && (e.centroid_mm[0] - d.centroid_mm[0])
                        .hypot(e.centroid_mm[1] - d.centroid_mm[1])
                        < (e.area_mm2 / std::f64::consts::PI).sqrt()
            })
    };
    let keep: Vec<bool> = (0..out.defects.len())
        .map(|k| !wall(&out.defects[k]) && !piece(k))
        .collect();
    // Stable report order (y descending, then x); candidates keep pointing at their defects.
    let mut order: Vec<usize> = (0..out.defects.len()).filter(|&k| keep[k]).collect();
    order.sort_by(|&a, &b| {
        let (a, b) = (&out.defects[a], &out.defects[b]);
        b.centroid_mm[1]
            .total_cmp(&a.centroid_mm[1])
            .then(a.centroid_mm[0].total_cmp(&b.centroid_mm[0]))
    });
    let mut new_index = vec![None; out.defects.len()];
    for (new, &old) in order.iter().enumerate() {
        new_index[old] = Some(new);
    }
    out.defects = order.iter().map(|&k| out.defects[k].clone()).collect();
    for c in &mut out.candidates {
        c.defect = c.defect.and_then(|k| new_index[k]);
        c.reported = c.defect.is_some();
    }
    Ok(out)
}

/// Everything inspection computes for one range image.
#[derive(Debug, Clone)]
pub struct Inspection {
    /// The reference used.
    pub reference: ReferenceInfo,
    /// Characterization maps.
    pub maps: SurfaceMaps,
    /// What was found.
    pub detection: Detection,
    /// Cells removed as outlier heights before characterization.
    pub outliers: usize,
}

/// Characterizes `range` against the reference from `source` and detects its defects.
pub fn inspect(
    range: &RangeImage,
    source: ReferenceSource<'_>,
    characterize: &CharacterizeParams,
    rules: &mut SurfaceRules,
    params: &DetectParams,
) -> Result<Inspection, CoreError> {
    if range.width == 0 || range.height == 0 || range.z.len() != range.width * range.height {
        return Err(CoreError::Inspection(InspectionError::InconsistentRange {
            width: range.width,
            height: range.height,
            values: range.z.len(),
        }));
    }
    if range.measured() == 0 {
        return Err(CoreError::Inspection(InspectionError::NoMeasurement));
    }
    let mut cleaned = range.clone();
    let outliers = remove_outliers(&mut cleaned, params.outlier_mm);
    // A golden scan is a scan too: its wrong-index fragments would stand in the reference as pits or spikes that
    // every part then "has". It is cleaned the same way (`PreparedGolden`; once for many parts when the caller
    // prepares it).
    let prepared = match source {
        ReferenceSource::Golden(golden) => Some(PreparedGolden::new(
            golden,
            params.outlier_mm,
            characterize.belt_level_mm,
            params.travel_step_mm,
        )),
        ReferenceSource::Prepared(p) => {
            p.check(
                params.outlier_mm,
                characterize.belt_level_mm,
                params.travel_step_mm,
            )?;
            None
        }
        ReferenceSource::Fit(_) => None,
    };
    let source = match &prepared {
        Some(p) => ReferenceSource::Prepared(p),
        None => source,
    };
    let (heights, reference) =
        reference_heights(&cleaned, source, characterize, params.travel_step_mm)?;
    let maps = surface_maps(&cleaned, heights, characterize)?;
    let detection = detect(&cleaned, &maps, rules, params)?;
    Ok(Inspection {
        reference,
        maps,
        detection,
        outliers,
    })
}
