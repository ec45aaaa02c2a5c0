//! `stripe3d bench robustness --scenes N --seed S`: extraction on random simulator scenes drawn over what production
//! lines show (`stripe3d_sim::random`), scored with the validation set's rule, and the distribution of the figures.

use crate::extract::run_frame;
use anyhow::{Context, Result, bail};
use indicatif::{ProgressBar, ProgressStyle};
use rayon::prelude::*;
use std::fmt::Write as _;
use std::path::Path;
use stripe3d_core::Image;
use stripe3d_core::extract::{ExtractParams, Extraction, Extractor};
use stripe3d_io::images::{FrameData, write_grey_png};
use stripe3d_sim::evaluate::RowScore;
use stripe3d_sim::random::RandomScene;

/// Worst scenes listed per figure.
const WORST_LISTED: usize = 5;

/// One scene's outcome.
#[derive(Debug, Clone)]
pub struct SceneFigures {
    /// The scene seed.
    pub seed: u64,
    /// The draws in words.
    pub description: String,
    /// The score.
    pub score: RowScore,
    /// The score away from the edges of the visible surface (no wall, laser-shadow boundary or albedo edge within
    /// `stripe3d_sim::render::EDGE_REACH_PX`): where a stripe's light falls across one, its intensity centre is
    /// off the sheet's, whatever the extractor.
    pub clean: RowScore,
}

/// The frame as the camera delivers it: 8-bit when the camera has 8 bits.
fn frame_data(image: Image<u16>, bits: u8) -> Result<FrameData> {
    if bits > 8 {
        return Ok(FrameData::U16(image));
    }
    let (w, h) = (image.width(), image.height());
    let bytes = image.data().iter().map(|&v| v.min(255) as u8).collect();
    Ok(FrameData::U8(Image::from_vec(w, h, bytes)?))
}

/// Renders scene `seed`, extracts with `params` and scores; with `save`, writes the frame and its truth there in
/// the validation set's layout (`extract/random_SEED.png`, `.truth.csv`).
pub fn score_scene(seed: u64, params: &ExtractParams, save: Option<&Path>) -> Result<SceneFigures> {
    let mut scene = RandomScene::draw(seed);
    let frame = scene
        .render()
        .with_context(|| format!("random scene {seed}"))?;
    let bits = scene.sensor.camera.bits;
    if let Some(dir) = save {
        let folder = dir.join("extract");
        std::fs::create_dir_all(&folder)
            .with_context(|| format!("creating {}", folder.display()))?;
        let name = format!("random_{seed:06}");
        write_grey_png(&folder.join(format!("{name}.png")), &frame.image, bits)?;
        let mut csv = String::from("row,stripe,x\n");
        for t in &frame.truth {
            let _ = writeln!(csv, "{},{},{:.4}", t.row, t.stripe, t.u);
        }
        let path = folder.join(format!("{name}.truth.csv"));
        std::fs::write(&path, csv).with_context(|| format!("writing {}", path.display()))?;
    }
    let truth: Vec<(u32, f64)> = frame.truth.iter().map(|t| (t.row, t.u)).collect();
    let data = frame_data(frame.image, bits)?;
    let mut ex = Extractor::new(params.clone())?;
    let mut out = Extraction::default();
    run_frame(&mut ex, &data, &mut out);
    let reported: Vec<(u32, f64)> = out.points.iter().map(|p| (p.row, p.x)).collect();
    let edges = scene
        .edge_map()
        .with_context(|| format!("random scene {seed}"))?;
    let away = |v: &[(u32, f64)]| -> Vec<(u32, f64)> {
        v.iter()
            .copied()
            .filter(|&(r, x)| !edges.near(r, x))
            .collect()
    };
    Ok(SceneFigures {
        seed,
        description: scene.describe(),
        score: RowScore::of(&truth, &reported),
        clean: RowScore::of(&away(&truth), &away(&reported)),
    })
}

/// The `q` quantile (0 to 1) of `v` by the nearest rank.
pub(crate) fn quantile(v: &[f64], q: f64) -> f64 {
    let mut s: Vec<f64> = v.iter().copied().filter(|x| !x.is_nan()).collect();
    if s.is_empty() {
        return f64::NAN;
    }
    s.sort_by(f64::total_cmp);
    let i = ((q * (s.len() - 1) as f64).round() as usize).min(s.len() - 1);
    s[i]
}

/// Runs `stripe3d bench robustness`.
pub fn bench_robustness(
    scenes: usize,
    seed: u64,
    params: &ExtractParams,
    save: Option<&Path>,
) -> Result<()> {
    if scenes == 0 {
        bail!("--scenes must be at least 1");
    }
    let bar = ProgressBar::new(scenes as u64);
    bar.set_style(
        ProgressStyle::with_template("{prefix} [{bar:30}] {pos}/{len} scenes, {eta} left")
            .unwrap_or_else(|_| ProgressStyle::default_bar()),
    );
    bar.set_prefix("rendering and extracting");
    let mut figures = (0..scenes as u64)
        .into_par_iter()
        .map(|i| {
            let r = score_scene(seed.wrapping_add(i), params, save);
            bar.inc(1);
            r
        })
        .collect::<Result<Vec<_>>>()?;
    bar.finish_and_clear();
    figures.sort_by_key(|f| f.seed);
    let recall: Vec<f64> = figures.iter().map(|f| f.score.recall()).collect();
    let false_rate: Vec<f64> = figures.iter().map(|f| f.score.false_rate()).collect();
    let rms: Vec<f64> = figures.iter().map(|f| f.score.rms()).collect();
    let clean_recall: Vec<f64> = figures.iter().map(|f| f.clean.recall()).collect();
    let clean_false: Vec<f64> = figures.iter().map(|f| f.clean.false_rate()).collect();
    let clean_rms: Vec<f64> = figures.iter().map(|f| f.clean.rms()).collect();
    say!(
        "robustness: {scenes} random scenes (seeds {seed} to {}), extraction ({}), scored as the validation README says:",
        seed.wrapping_add(scenes as u64 - 1),
        params.method.name()
    );
    say!("| figure | median | 5 % of scenes worse than | worst |");
    say!("|---|---:|---:|---:|");
    say!(
        "| recall within 0.5 px | {:.4} | {:.4} | {:.4} |",
        quantile(&recall, 0.5),
        quantile(&recall, 0.05),
        quantile(&recall, 0.0)
    );
    say!(
        "| false | {:.4} | {:.4} | {:.4} |",
        quantile(&false_rate, 0.5),
        quantile(&false_rate, 0.95),
        quantile(&false_rate, 1.0)
    );
    say!(
        "| RMS px | {:.3} | {:.3} | {:.3} |",
        quantile(&rms, 0.5),
        quantile(&rms, 0.95),
        quantile(&rms, 1.0)
    );
    say!(
        "| away from edges: recall | {:.4} | {:.4} | {:.4} |",
        quantile(&clean_recall, 0.5),
        quantile(&clean_recall, 0.05),
        quantile(&clean_recall, 0.0)
    );
    say!(
        "| away from edges: false | {:.4} | {:.4} | {:.4} |",
        quantile(&clean_false, 0.5),
        quantile(&clean_false, 0.95),
        quantile(&clean_false, 1.0)
    );
    say!(
        "| away from edges: RMS px | {:.3} | {:.3} | {:.3} |",
        quantile(&clean_rms, 0.5),
        quantile(&clean_rms, 0.95),
        quantile(&clean_rms, 1.0)
    );
    let list = |title: &str, key: &dyn Fn(&SceneFigures) -> f64| {
        let mut order: Vec<&SceneFigures> = figures.iter().collect();
        order.sort_by(|a, b| key(b).total_cmp(&key(a)));
        say!("{title}:");
        for f in order.iter().take(WORST_LISTED.min(order.len())) {
            say!(
                "  seed {}: recall {:.4}, false {:.4}, RMS {:.3} px, {} true centres (away from edges {:.4}, {:.4}, \
                 {:.3} px, {}); {}",
                f.seed,
                f.score.recall(),
                f.score.false_rate(),
                f.score.rms(),
                f.score.truth,
                f.clean.recall(),
                f.clean.false_rate(),
                f.clean.rms(),
                f.clean.truth,
                f.description
            );
        }
    };
    list("lowest recall", &|f| -f.score.recall());
    list("most false points", &|f| f.score.false_rate());
    say!(
        "summary: robustness over {scenes} scenes: recall median {:.4}, 5th percentile {:.4}; false median {:.4}, \
         95th percentile {:.4}; RMS median {:.3} px; away from edges: recall 5th percentile {:.4}, false 95th \
         percentile {:.4}",
        quantile(&recall, 0.5),
        quantile(&recall, 0.05),
        quantile(&false_rate, 0.5),
        quantile(&false_rate, 0.95),
        quantile(&rms, 0.5),
        quantile(&clean_recall, 0.05),
        quantile(&clean_false, 0.95)
    );
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn quantiles_by_nearest_rank() {
        let v = [3.0, 1.0, 2.0, f64::NAN, 5.0, 4.0];
        assert_eq!(quantile(&v, 0.0), 1.0);
        assert_eq!(quantile(&v, 0.5), 3.0);
        assert_eq!(quantile(&v, 1.0), 5.0);
        assert!(quantile(&[], 0.5).is_nan());
    }
}
