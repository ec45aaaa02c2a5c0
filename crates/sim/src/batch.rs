//! Simulated production batches for the knowledge base: plates from a process with a seeded fault, idealised range
//! images of them, and the scoring of found defects against the truth (the "operator" of the learning tests).
//!
//! [`ideal_range`] samples the scene's exact height field on the range grid and adds the scan's measured height
//! noise, skipping the optical chain (rendering, extraction, coding): a batch of a hundred parts takes seconds
//! instead of minutes. It is for what sits downstream of the range image (classification, reasoning, learning);
//! the measuring chain itself is scored through [`crate::pipeline::scan_scene`].

use crate::scene::{Feature, Scene};
use crate::{DefectTruth, SimError};
use rand::{Rng, SeedableRng};
use rand_distr::{Distribution, Normal};
use stripe3d_core::accumulate::RangeImage;
use stripe3d_core::detect::Defect;

/// Height noise of the default scan on a matte plate, mm (`stripe3d bench sensor`: 0.0054 mm; full-model height
/// RMS on the flat plate 0.0069 mm).
pub const SCAN_NOISE_MM: f64 = 0.007;

/// The designed through-holes of the batch plate (`cover-plate` in the shipped knowledge base): centre x, y and
/// diameter, mm, in the product frame (the plate's centre).
pub const DESIGNED_HOLES: [(f64, f64, f64); 2] = [(-28.0, 18.0, 6.0), (28.0, -18.0, 6.0)];

/// A fault of the process that made a batch, as it shows on the parts.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ProcessFault {
    /// A good process: a defect on one part in five, anywhere.
    Healthy,
    /// A particle stuck on the stamping die: a small sharp dent at the same place on every part.
    DieDebris,
    /// Parts knocked in handling: dents near the edges, anywhere along them.
    Handling,
    /// Gas porosity in a casting: clusters of small holes.
    Porosity,
    /// A chipped cutting tool: one or two short gouges (2-3.5 mm long, about 1 mm wide) per part, and a handling
    /// dent on every other part. The shipped surface rules call gouges this short dents (their elongation, 3 to 4.5,
    /// sits at the foot of the `long` term): the learning benchmark's batch.
    ToolMarks,
}

/// Where the die-debris dent sits on every part (product frame), mm.
pub const DEBRIS_AT_MM: (f64, f64) = (10.0, -6.0);

/// A cover plate (80 x 60 x 10 mm with the [`DESIGNED_HOLES`]) from a process with `fault`, part `part` of the
/// batch drawn from `seed`.
pub fn batch_plate(fault: ProcessFault, seed: u64, part: u64) -> Scene {
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed.wrapping_mul(1_000_003) ^ part);
    let mut scene = Scene::flat_plate();
    scene.name = format!("cover-plate-{seed}-{part}");
    for (x, y, d) in DESIGNED_HOLES {
        scene.features.push(Feature::Hole {
            x_mm: x,
            y_mm: y,
            diameter_mm: d,
            designed: true,
        });
    }
    let dent = |x: f64, y: f64, d: f64, depth: f64| Feature::Dent {
        x_mm: x,
        y_mm: y,
        diameter_mm: d,
        depth_mm: depth,
    };
    match fault {
        ProcessFault::Healthy => {
            if rng.random_bool(0.2) {
                let x = rng.random_range(-30.0..30.0);
                let y = rng.random_range(-8.0..8.0);
                scene.features.push(Feature::Bump {
                    x_mm: x,
                    y_mm: y,
                    diameter_mm: rng.random_range(4.0..8.0),
                    height_mm: rng.random_range(0.1..0.3),
                });
            }
        }
        ProcessFault::DieDebris => {
            // Debris is small and hard: 1.6-2.4 mm across, 0.12-0.2 mm deep.
            let (x, y) = DEBRIS_AT_MM;
            scene.features.push(dent(
                x + rng.random_range(-0.3..0.3),
                y + rng.random_range(-0.3..0.3),
                rng.random_range(1.6..2.4),
                rng.random_range(0.12..0.2),
            ));
        }
        ProcessFault::Handling => {
            // One or two knocks 3-5 mm inside an edge, 4-8 mm across.
            for _ in 0..rng.random_range(1..=2) {
                let d: f64 = rng.random_range(4.0..8.0);
                let inset = rng.random_range(3.0..5.0) + d / 2.0;
                let (x, y) = if rng.random_bool(0.5) {
                    let side = if rng.random_bool(0.5) { 1.0 } else { -1.0 };
                    (rng.random_range(-20.0..20.0), side * (30.0 - inset))
                } else {
                    let side = if rng.random_bool(0.5) { 1.0 } else { -1.0 };
                    (side * (40.0 - inset), rng.random_range(-10.0..10.0))
                };
                scene
                    .features
                    .push(dent(x, y, d, rng.random_range(0.15..0.4)));
            }
        }
        ProcessFault::Porosity => {
            let (cx, cy) = (rng.random_range(-15.0..15.0), rng.random_range(-5.0..5.0));
            for k in 0..3 {
                let a = k as f64 * 2.1 + rng.random_range(0.0..0.5);
                scene.features.push(Feature::Hole {
                    x_mm: cx + 5.0 * a.cos(),
                    y_mm: cy + 5.0 * a.sin(),
                    diameter_mm: rng.random_range(1.5..2.5),
                    designed: false,
                });
            }
        }
        ProcessFault::ToolMarks => {
            let mut placed: Vec<(f64, f64)> = Vec::new();
            for _ in 0..rng.random_range(1..=2) {
                let (x, y) = (rng.random_range(-30.0..30.0), rng.random_range(-8.0..8.0));
                if placed.iter().any(|p| (p.0 - x).hypot(p.1 - y) < 10.0) {
                    continue;
                }
                placed.push((x, y));
                let (l, a) = (
                    rng.random_range(2.0..3.5),
                    rng.random_range(0.0..std::f64::consts::PI),
                );
                let (dx, dy) = (0.5 * l * a.cos(), 0.5 * l * a.sin());
                scene.features.push(Feature::Scratch {
                    x0_mm: x - dx,
                    y0_mm: y - dy,
                    x1_mm: x + dx,
                    y1_mm: y + dy,
                    width_mm: rng.random_range(0.8..1.2),
                    depth_mm: rng.random_range(0.1..0.2),
                });
            }
            if rng.random_bool(0.5) {
                let x = rng.random_range(-30.0..30.0);
                let y = if rng.random_bool(0.5) { 20.0 } else { -20.0 };
                scene.features.push(dent(
                    x,
                    y,
                    rng.random_range(3.0..6.0),
                    rng.random_range(0.1..0.3),
                ));
            }
        }
    }
    scene
}

/// The scene's exact heights on a `spacing_mm` grid over its height field (the part and 2 mm of belt around it),
/// with Gaussian height noise of `noise_mm` from `seed`, and the truth of its defects.
pub fn ideal_range(
    scene: &Scene,
    spacing_mm: f64,
    noise_mm: f64,
    seed: u64,
) -> Result<(RangeImage, Vec<DefectTruth>), SimError> {
    if !(spacing_mm.is_finite() && spacing_mm >= 0.01 && noise_mm.is_finite() && noise_mm >= 0.0) {
        return Err(SimError::InvalidScene {
            field: "spacing_mm".into(),
            reason: format!(
                "grid {spacing_mm} mm, noise {noise_mm} mm: give a grid of at least 0.01 mm and a noise >= 0"
            ),
        });
    }
    let (field, truth) = scene.rasterize()?;
    let (x0, y0) = field.origin_mm();
    let (nx, ny) = field.size();
    let g = field.spacing_mm();
    let (x1, y1) = (x0 + (nx - 1) as f64 * g, y0 + (ny - 1) as f64 * g);
    let width = ((x1 - x0) / spacing_mm).floor() as usize + 1;
    let height = ((y1 - y0) / spacing_mm).floor() as usize + 1;
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
    let normal = Normal::new(0.0, noise_mm.max(1e-12)).map_err(|e| SimError::InvalidScene {
        field: "noise_mm".into(),
        reason: e.to_string(),
    })?;
    let mut z = Vec::with_capacity(width * height);
    for j in 0..height {
        // Row 0 is the top (+y).
        let y = y1 - j as f64 * spacing_mm;
        for i in 0..width {
            let x = x0 + i as f64 * spacing_mm;
            let n = if noise_mm > 0.0 {
                normal.sample(&mut rng)
            } else {
                0.0
            };
            z.push((field.height_at(x, y) + n) as f32);
        }
    }
    Ok((
        RangeImage {
            origin_mm: [x0, y1],
            spacing_mm: [spacing_mm, spacing_mm],
            width,
            height,
            z,
            intensity: None,
        },
        truth,
    ))
}

/// One truth defect and what was found for it.
#[derive(Debug, Clone)]
pub struct Match {
    /// The truth.
    pub truth: DefectTruth,
    /// The found defect matched to it.
    pub found: Option<Defect>,
}

/// The outcome on one part.
#[derive(Debug, Clone, Default)]
pub struct PartOutcome {
    /// Truth defects with their matches.
    pub matches: Vec<Match>,
    /// Found defects that match no truth.
    pub false_defects: Vec<Defect>,
    /// Inspection warnings.
    pub warnings: Vec<String>,
}

/// How far (mm) from a truth defect's centre a found defect may lie and still be it: its radius, at least 1 mm.
pub fn match_radius_mm(truth: &DefectTruth) -> f64 {
    (truth.diameter_mm / 2.0).max(1.0)
}

/// Matches found defects to the truth: nearest first, within [`match_radius_mm`], one to one.
pub fn match_defects(truth: &[DefectTruth], found: &[Defect]) -> PartOutcome {
    let mut pairs: Vec<(f64, usize, usize)> = Vec::new();
    for (ti, t) in truth.iter().enumerate() {
        for (fi, f) in found.iter().enumerate() {
            let d = (f.centroid_mm[0] - t.x_mm).hypot(f.centroid_mm[1] - t.y_mm);
            if d <= match_radius_mm(t) {
                pairs.push((d, ti, fi));
            }
        }
    }
    pairs.sort_by(|a, b| a.0.total_cmp(&b.0));
    let mut t_used = vec![None; truth.len()];
    let mut f_used = vec![false; found.len()];
    for (_, ti, fi) in pairs {
        if t_used[ti].is_none() && !f_used[fi] {
            t_used[ti] = Some(fi);
            f_used[fi] = true;
        }
    }
    PartOutcome {
        matches: truth
            .iter()
            .zip(&t_used)
            .map(|(t, f)| Match {
                truth: t.clone(),
                found: f.map(|k| found[k].clone()),
            })
            .collect(),
        false_defects: found
            .iter()
            .zip(&f_used)
            .filter(|(_, u)| !**u)
            .map(|(f, _)| f.clone())
            .collect(),
        warnings: Vec::new(),
    }
}

/// Defect-level F1 of a batch: a truth defect counts as found only when a defect of the same kind matches it; every
/// other found defect is false. Returns (F1, true, false, missed).
pub fn kind_f1(outcomes: &[PartOutcome]) -> (f64, usize, usize, usize) {
    let (mut tp, mut fp, mut fn_) = (0, 0, 0);
    for o in outcomes {
        fp += o.false_defects.len();
        for m in &o.matches {
            match &m.found {
                Some(f) if f.kind.name() == m.truth.kind => tp += 1,
                Some(_) => {
                    fp += 1;
                    fn_ += 1;
                }
                None => fn_ += 1,
            }
        }
    }
    let f1 = if tp == 0 {
        0.0
    } else {
        2.0 * tp as f64 / (2 * tp + fp + fn_) as f64
    };
    (f1, tp, fp, fn_)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ideal_range_holds_the_plate_and_the_belt() {
        let scene = batch_plate(ProcessFault::DieDebris, 1, 0);
        let (r, truth) = ideal_range(&scene, 0.5, 0.0, 1).expect("range");
        assert_eq!(truth.len(), 1, "one debris dent");
        assert!(truth[0].kind == "dent");
        let at = |x: f64, y: f64| {
            let i = ((x - r.origin_mm[0]) / r.spacing_mm[0]).round() as usize;
            let j = ((r.origin_mm[1] - y) / r.spacing_mm[1]).round() as usize;
            r.z[j * r.width + i]
        };
        assert!((at(0.0, 0.0) - 10.0).abs() < 1e-4, "plate top");
        assert!(at(-28.0, 18.0).abs() < 1e-4, "designed hole shows the belt");
        assert!(at(41.0, 0.0).abs() < 1e-4, "belt beyond the plate");
        assert!(ideal_range(&scene, 0.0, 0.0, 1).is_err());
    }

    #[test]
    fn kind_f1_counts_wrong_kinds_twice() {
        let t = |kind: &str, x: f64| DefectTruth {
            kind: kind.into(),
            x_mm: x,
            y_mm: 0.0,
            diameter_mm: 4.0,
            area_mm2: 12.0,
            depth_mm: 0.2,
            volume_mm3: 1.0,
        };
        let f = |kind, x: f64| Defect {
            kind,
            centroid_mm: [x, 0.0],
            bbox_mm: [0.0; 4],
            area_mm2: 12.0,
            depth_mm: 0.2,
            volume_mm3: 1.0,
            confidence: 0.9,
            bottom_seen: true,
            evidence: Default::default(),
        };
        use stripe3d_core::detect::DefectKind::*;
        let o = match_defects(
            &[t("dent", 0.0), t("bump", 10.0), t("hole", 20.0)],
            &[f(Dent, 0.1), f(Anomaly, 10.2), f(Dent, 30.0)],
        );
        let (f1, tp, fp, fn_) = kind_f1(&[o]);
        assert_eq!((tp, fp, fn_), (1, 2, 2));
        assert!((f1 - 2.0 / 6.0).abs() < 1e-12);
    }
}
