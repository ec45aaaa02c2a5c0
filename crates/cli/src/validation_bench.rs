//! `stripe3d bench validation DIR`: extraction on a validation set laid out as `../shared/validation/`, scored
//! exactly as its README says (a true centre is found by the nearest point of its row within 0.5 px, each point used
//! once; a point farther than 1.5 px from every true centre of its row is false).

use crate::extract::run_frame;
use anyhow::{Context, Result, bail};
use std::path::Path;
use stripe3d_core::extract::{ExtractParams, Extraction, Extractor};
use stripe3d_io::images::read_frame_native;
use stripe3d_io::validation::{extract_cases, read_true_centres};
use stripe3d_sim::evaluate::RowScore;

/// Largest frame read, pixels.
const MAX_PIXELS: usize = 64 << 20;

/// One frame's figures.
#[derive(Debug, Clone)]
pub struct FrameFigures {
    /// The frame's name.
    pub name: String,
    /// Its score.
    pub score: RowScore,
}

/// Scores extraction with `params` on every frame of `dir/extract/`.
pub fn score_extraction(dir: &Path, params: &ExtractParams) -> Result<Vec<FrameFigures>> {
    let folder = dir.join("extract");
    if !folder.is_dir() {
        bail!(
            "{}: no extract/ folder (a validation set holds extract/, calib/ and scans/, as ../shared/validation/)",
            dir.display()
        );
    }
    let cases = extract_cases(&folder)?;
    if cases.is_empty() {
        bail!(
            "{}: no NAME.png with a NAME.truth.csv beside it",
            folder.display()
        );
    }
    let mut ex = Extractor::new(params.clone())?;
    let mut out = Extraction::default();
    let mut figures = Vec::new();
    for c in &cases {
        let frame = read_frame_native(&c.image, MAX_PIXELS)?;
        let truth: Vec<(u32, f64)> = read_true_centres(&c.truth)?
            .iter()
            .map(|t| (t.row, t.x))
            .collect();
        run_frame(&mut ex, &frame, &mut out);
        let reported: Vec<(u32, f64)> = out.points.iter().map(|p| (p.row, p.x)).collect();
        figures.push(FrameFigures {
            name: c.name.clone(),
            score: RowScore::of(&truth, &reported),
        });
    }
    Ok(figures)
}

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    match v.len() {
        0 => f64::NAN,
        n if n % 2 == 1 => v[n / 2],
        n => 0.5 * (v[n / 2 - 1] + v[n / 2]),
    }
}

/// Runs `stripe3d bench validation`.
pub fn bench_validation(dir: &Path, params: &ExtractParams) -> Result<()> {
    let figures = score_extraction(dir, params)
        .with_context(|| format!("validation set {}", dir.display()))?;
    say!(
        "extraction ({}), scored as the validation README says:",
        params.method.name()
    );
    say!("| frame | true centres | recall within 0.5 px | false | RMS px |");
    say!("|---|---:|---:|---:|---:|");
    for f in &figures {
        say!(
            "| {} | {} | {:.4} | {:.4} | {:.3} |",
            f.name,
            f.score.truth,
            f.score.recall(),
            f.score.false_rate(),
            f.score.rms()
        );
    }
    let recall = median(figures.iter().map(|f| f.score.recall()).collect());
    let false_rate = median(figures.iter().map(|f| f.score.false_rate()).collect());
    let rms = median(figures.iter().map(|f| f.score.rms()).collect());
    let worst = figures
        .iter()
        .map(|f| f.score.recall())
        .fold(f64::INFINITY, f64::min);
    say!(
        "summary: extraction over {} frames: median recall {recall:.4} (worst {worst:.4}), median false {false_rate:.4}, \
         median RMS {rms:.3} px",
        figures.len()
    );
    Ok(())
}
