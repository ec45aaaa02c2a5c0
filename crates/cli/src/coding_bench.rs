//! `stripe3d bench coding`: stripe coding over a whole simulated scan, against the simulator's truth, frame by frame
//! and after temporal reconciliation, with what the wrong indices are (which stripe was read as which, where).

use anyhow::{Context, Result, bail};
use indicatif::{ProgressBar, ProgressStyle};
use stripe3d_core::Sensor;
use stripe3d_core::code::{CodedFrame, TemporalParams, reconcile};
use stripe3d_sim::evaluate::{CodingScore, CodingTally, MATCH_RADIUS_PX, TruthRows, score_coding};
use stripe3d_sim::pipeline::{calibrate_sensor, frames_for_sweep, scanner};
use stripe3d_sim::{RenderOptions, Scene, Simulator};

/// The target: share of coded points (matched to a truth point) with the right stripe index.
const TARGET_RIGHT: f64 = 0.999;

/// Most frames one run codes.
const MAX_FRAMES: usize = 2_000;

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
    say!("calibrating the simulated sensor (plates at 0-35 mm) ...");
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
    let before: Vec<CodingScore> = coded
        .iter()
        .zip(&truth)
        .map(|(c, t)| score_coding(c, t))
        .collect();
    let labels_before: Vec<Vec<Option<u16>>> =
        coded.iter().map(|c| c.coding.stripes.clone()).collect();
    let changed = reconcile(&mut coded, &TemporalParams::default());
    let after: Vec<CodingScore> = coded
        .iter()
        .zip(&truth)
        .map(|(c, t)| score_coding(c, t))
        .collect();
    // What reconciliation did, point by point.
    let (mut recovered, mut relabelled, mut dropped) =
        (CodingTally::default(), CodingTally::default(), 0);
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
    let total = |s: &[CodingScore]| {
        let mut t = CodingTally::default();
        for f in s {
            t.add(&f.tally);
        }
        t
    };
    let (b, a) = (total(&before), total(&after));
    say!(
        "\nscene {}: {frames} frames {:.2} mm apart (render seed {seed}), coded as `stripe3d scan` codes them; a coded \
         point is checked against the truth point of its row nearest to it within {MATCH_RADIUS_PX} px\n",
        scene.name,
        conveyor.step_mm()
    );
    say!(
        "| stage | points | coded | right | wrong | off the truth | right of matched | target >= 99.9% |"
    );
    say!("|---|---:|---:|---:|---:|---:|---:|---|");
    for (name, t) in [
        ("each frame alone", b),
        ("after temporal reconciliation", a),
    ] {
        say!(
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
    say!(
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
        say!(
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
            say!(
                "  frame {k}: {} wrong of {} coded; {}",
                f.tally.wrong,
                f.tally.coded,
                list.join(", ")
            );
        }
    }
    Ok(())
}
