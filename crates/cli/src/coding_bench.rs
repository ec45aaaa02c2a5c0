//! `stripe3d bench coding`: stripe coding over a whole simulated scan, against the simulator's truth, frame by frame
//! and after temporal reconciliation, with what the wrong indices are (which stripe was read as which, where).

use anyhow::{Context, Result, bail};
use indicatif::{ProgressBar, ProgressStyle};
use std::collections::BTreeMap;
use stripe3d_core::Sensor;
use stripe3d_core::code::{CodedFrame, TemporalParams, reconcile};
use stripe3d_core::extract::StripePoint;
use stripe3d_sim::pipeline::{calibrate_sensor, frames_for_sweep, scanner};
use stripe3d_sim::{RenderOptions, Scene, Simulator, TruthPoint};

/// The target: share of coded points (matched to a truth point) with the right stripe index.
const TARGET_RIGHT: f64 = 0.999;

/// A coded point is checked against the truth point of its row nearest to it within this many pixels.
pub const MATCH_PX: f64 = 0.5;

/// Most frames one run codes.
const MAX_FRAMES: usize = 2_000;

/// Counts of one stage.
#[derive(Debug, Default, Clone, Copy, PartialEq, Eq)]
pub struct Tally {
    /// Extracted points.
    pub points: usize,
    /// Of those, given a stripe index.
    pub coded: usize,
    /// Coded and matched to a truth point with that stripe.
    pub right: usize,
    /// Coded and matched to a truth point of another stripe.
    pub wrong: usize,
    /// Coded with no truth point within [`MATCH_PX`] (a sheet's tail, a ghost, a centre biased by an edge).
    pub off_truth: usize,
}

impl Tally {
    /// Share of the matched coded points that are right.
    pub fn right_share(&self) -> f64 {
        self.right as f64 / (self.right + self.wrong).max(1) as f64
    }
}

/// Truth points of one frame by image row: (column, stripe), sorted by column.
struct TruthRows(Vec<Vec<(f64, u32)>>);

impl TruthRows {
    fn new(truth: &[TruthPoint]) -> Self {
        let rows = truth.iter().map(|t| t.row as usize + 1).max().unwrap_or(0);
        let mut by_row = vec![Vec::new(); rows];
        for t in truth {
            by_row[t.row as usize].push((t.u, t.stripe));
        }
        for r in &mut by_row {
            r.sort_by(|a, b| a.0.total_cmp(&b.0));
        }
        Self(by_row)
    }

    /// The stripe of the truth point of `p`'s row nearest to it within [`MATCH_PX`].
    fn stripe_of(&self, p: &StripePoint) -> Option<u32> {
        self.0
            .get(p.row as usize)?
            .iter()
            .map(|&(u, s)| ((u - p.x).abs(), s))
            .filter(|&(d, _)| d <= MATCH_PX)
            .min_by(|a, b| a.0.total_cmp(&b.0))
            .map(|(_, s)| s)
    }
}

/// Where one kind of wrong index lies: points, first and last image row, leftmost and rightmost column.
type Spread = (usize, [u32; 2], [f64; 2]);

/// What happened to one frame's points, against the truth.
#[derive(Debug, Default)]
struct FrameScore {
    tally: Tally,
    /// Wrong indices by (true stripe, label given): count, first and last image row, leftmost and rightmost column.
    confusions: BTreeMap<(u32, u16), Spread>,
}

fn score(coded: &CodedFrame, truth: &TruthRows) -> FrameScore {
    let mut s = FrameScore::default();
    s.tally.points = coded.points.len();
    for (p, l) in coded.points.iter().zip(&coded.coding.stripes) {
        let Some(l) = *l else { continue };
        s.tally.coded += 1;
        match truth.stripe_of(p) {
            Some(t) if t == u32::from(l) => s.tally.right += 1,
            Some(t) => {
                s.tally.wrong += 1;
                let e = s
                    .confusions
                    .entry((t, l))
                    .or_insert((0, [p.row, p.row], [p.x, p.x]));
                e.0 += 1;
                e.1 = [e.1[0].min(p.row), e.1[1].max(p.row)];
                e.2 = [e.2[0].min(p.x), e.2[1].max(p.x)];
            }
            None => s.tally.off_truth += 1,
        }
    }
    s
}

fn add(a: &mut Tally, b: &Tally) {
    a.points += b.points;
    a.coded += b.coded;
    a.right += b.right;
    a.wrong += b.wrong;
    a.off_truth += b.off_truth;
}

/// Runs `stripe3d bench coding`.
pub fn bench_coding(
    scene_name: Option<&str>,
    defect_plate: Option<u64>,
    frames: Option<usize>,
    seed: u64,
    verbose: bool,
) -> Result<()> {
    let scene = match (scene_name, defect_plate) {
        (Some(_), Some(_)) => bail!("give --scene or --defect-plate, not both"),
        (_, Some(s)) => Scene::defect_plate(s, 4),
        (name, None) => crate::simulate::load_scene(name.unwrap_or("demo"))?,
    };
    let sensor = Sensor::default();
    let frames = frames.unwrap_or_else(|| frames_for_sweep(&sensor, 2));
    if frames == 0 || frames > MAX_FRAMES {
        bail!("--frames {frames}: give 1 to {MAX_FRAMES} frames");
    }
    let conveyor = sensor.conveyor.clone().unwrap_or_default();
    println!("calibrating the simulated sensor (plates at 0-35 mm) ...");
    let cal = calibrate_sensor(&sensor, seed.wrapping_add(10_000))
        .context("calibrating the simulated sensor")?;
    let mut scanner = scanner(&cal)?;
    let sim = Simulator::new(
        &sensor,
        &scene,
        RenderOptions {
            seed,
            ..RenderOptions::default()
        },
    )
    .with_context(|| format!("scene {}", scene.name))?;
    let bar = ProgressBar::new(frames as u64).with_style(
        ProgressStyle::with_template("{msg} [{bar:40}] {pos}/{len} frames ({eta})")
            .unwrap_or_else(|_| ProgressStyle::default_bar())
            .progress_chars("=> "),
    );
    bar.set_message(format!("rendering and coding {}", scene.name));
    let mut coded = Vec::with_capacity(frames);
    let mut truth = Vec::with_capacity(frames);
    for k in 0..frames {
        let frame = sim.render(k, conveyor.travel_mm(k));
        let mut c = CodedFrame::default();
        scanner.code_into(frame.image.view(), &mut c);
        coded.push(c);
        truth.push(TruthRows::new(&frame.truth));
        bar.inc(1);
    }
    bar.finish_and_clear();
    let before: Vec<FrameScore> = coded.iter().zip(&truth).map(|(c, t)| score(c, t)).collect();
    let labels_before: Vec<Vec<Option<u16>>> =
        coded.iter().map(|c| c.coding.stripes.clone()).collect();
    let changed = reconcile(&mut coded, &TemporalParams::default());
    let after: Vec<FrameScore> = coded.iter().zip(&truth).map(|(c, t)| score(c, t)).collect();
    // What reconciliation did, point by point.
    let (mut recovered, mut relabelled, mut dropped) = (Tally::default(), Tally::default(), 0);
    for ((c, t), was) in coded.iter().zip(&truth).zip(&labels_before) {
        for ((p, l), w) in c.points.iter().zip(&c.coding.stripes).zip(was) {
            let into = match (l, w) {
                (Some(_), None) => &mut recovered,
                (Some(a), Some(b)) if a != b => &mut relabelled,
                (None, Some(_)) => {
                    dropped += 1;
                    continue;
                }
                _ => continue,
            };
            into.coded += 1;
            match (t.stripe_of(p), l) {
                (Some(s), Some(l)) if s == u32::from(*l) => into.right += 1,
                (Some(_), _) => into.wrong += 1,
                (None, _) => into.off_truth += 1,
            }
        }
    }
    let total = |s: &[FrameScore]| {
        let mut t = Tally::default();
        for f in s {
            add(&mut t, &f.tally);
        }
        t
    };
    let (b, a) = (total(&before), total(&after));
    println!(
        "\nscene {}: {frames} frames {:.2} mm apart (render seed {seed}), coded as `stripe3d scan` codes them; a coded \
         point is checked against the truth point of its row nearest to it within {MATCH_PX} px\n",
        scene.name,
        conveyor.step_mm()
    );
    println!(
        "| stage | points | coded | right | wrong | off the truth | right of matched | target >= 99.9% |"
    );
    println!("|---|---:|---:|---:|---:|---:|---:|---|");
    for (name, t) in [
        ("each frame alone", b),
        ("after temporal reconciliation", a),
    ] {
        println!(
            "| {name} | {} | {} ({:.1}%) | {} | {} | {} | {:.2}% | {} |",
            t.points,
            t.coded,
            100.0 * t.coded as f64 / t.points.max(1) as f64,
            t.right,
            t.wrong,
            t.off_truth,
            100.0 * t.right_share(),
            if t.right_share() >= TARGET_RIGHT {
                "met"
            } else {
                "NOT met"
            }
        );
    }
    println!(
        "\nreconciliation changed {changed} labels: {} points recovered ({} right, {} wrong, {} off the truth), {} \
         relabelled ({} right, {} wrong, {} off the truth), {dropped} dropped",
        recovered.coded,
        recovered.right,
        recovered.wrong,
        recovered.off_truth,
        relabelled.coded,
        relabelled.right,
        relabelled.wrong,
        relabelled.off_truth,
    );
    if verbose {
        println!(
            "\nwrong indices after reconciliation, frame by frame (true stripe -> label: points, where in the image):"
        );
        for (k, f) in after.iter().enumerate() {
            if f.tally.wrong == 0 {
                continue;
            }
            let list: Vec<String> = f
                .confusions
                .iter()
                .map(|((t, l), (n, r, c))| {
                    format!(
                        "{t}->{l}: {n} (rows {}-{}, columns {:.0}-{:.0})",
                        r[0], r[1], c[0], c[1]
                    )
                })
                .collect();
            println!(
                "  frame {k}: {} wrong of {} coded; {}",
                f.tally.wrong,
                f.tally.coded,
                list.join(", ")
            );
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use stripe3d_core::code::Coding;

    fn point(row: u32, x: f64) -> StripePoint {
        StripePoint {
            row,
            x,
            intensity: 100.0,
            width: 6.0,
            score: 0.5,
            cut: false,
        }
    }

    #[test]
    fn points_are_scored_against_the_nearest_truth_point_of_their_row() {
        let truth = TruthRows(vec![vec![(10.0, 0), (20.0, 1)], vec![(10.2, 0), (10.6, 1)]]);
        let coded = CodedFrame {
            points: vec![
                point(0, 10.3),
                point(0, 19.6),
                point(0, 30.0),
                point(1, 10.45),
                point(1, 10.0),
                point(5, 1.0),
            ],
            coding: Coding {
                stripes: vec![Some(0), Some(2), Some(3), Some(1), None, Some(0)],
                ..Coding::default()
            },
        };
        let s = score(&coded, &truth);
        assert_eq!(
            s.tally,
            Tally {
                points: 6,
                coded: 5,
                right: 2,
                wrong: 1,
                off_truth: 2,
            }
        );
        assert_eq!(s.confusions.get(&(1, 2)), Some(&(1, [0, 0], [19.6, 19.6])));
        assert!((s.tally.right_share() - 2.0 / 3.0).abs() < 1e-12);
        // Rows come from the truth points themselves.
        let frame_truth = [TruthPoint {
            row: 3,
            stripe: 4,
            u: 7.0,
            world: [0.0; 3],
            part: [0.0; 3],
        }];
        let rows = TruthRows::new(&frame_truth);
        assert_eq!(rows.stripe_of(&point(3, 7.4)), Some(4));
        assert_eq!(rows.stripe_of(&point(3, 7.6)), None);
        assert_eq!(rows.stripe_of(&point(2, 7.0)), None);
    }
}
