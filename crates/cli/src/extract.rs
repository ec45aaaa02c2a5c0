//! `stripe3d extract`: stripe centres of camera frames, as CSV or JSON.

use anyhow::{Context, Result, bail};
use clap::{Args, ValueEnum};
use rayon::prelude::*;
use std::io::Write;
use std::path::PathBuf;
use stripe3d_core::extract::{
    Axis, DEFAULT_CUT_ASYMMETRY, ExtractParams, Extraction, Extractor, Method, Policy, Threshold,
};
use stripe3d_io::images::{
    FrameData, Laser, PointMark, points_picture, read_frame_native_as, write_rgb_png,
};

/// Scan line direction.
#[derive(Debug, Clone, Copy, ValueEnum)]
pub enum AxisArg {
    /// Along image rows (stripes roughly vertical).
    Rows,
    /// Along image columns (stripes roughly horizontal).
    Columns,
}

/// Output format.
#[derive(Debug, Clone, Copy, ValueEnum)]
pub enum FormatArg {
    /// `row,x,intensity,width,score` (with a leading `frame` column for several images).
    Csv,
    /// The same fields as JSON, with the scan lines where no stripe was found.
    Json,
}

/// Multi-peak policy.
#[derive(Debug, Clone, Copy, ValueEnum)]
pub enum PolicyArg {
    /// Every stripe on the scan line.
    All,
    /// The brightest.
    Brightest,
    /// The first along the scan line.
    First,
    /// The last along the scan line.
    Last,
    /// The one nearest to the previous scan line's.
    Continuity,
}

pub fn method_names() -> Vec<&'static str> {
    Method::ALL.iter().map(|m| m.name()).collect()
}

/// Arguments of `stripe3d extract`.
#[derive(Debug, Args)]
pub struct ExtractArgs {
    /// Images: PNG (8 or 16 bit), JPEG, PGM or TIFF, grey or colour (RGB, RGBA; see --laser).
    #[arg(required = true)]
    pub images: Vec<PathBuf>,
    /// Sub-pixel estimator.
    #[arg(long, default_value = "steger", value_parser = clap::builder::PossibleValuesParser::new(method_names()))]
    pub method: String,
    /// Peak prominence threshold in grey levels [default: from the local noise, see docs/extraction.md].
    #[arg(long)]
    pub threshold: Option<f64>,
    /// Derive the threshold from each scan line's own noise instead of the frame's.
    #[arg(long, conflicts_with = "threshold")]
    pub line_threshold: bool,
    /// Scan line direction; with `columns`, `row` is the column and `x` the sub-pixel row.
    #[arg(long, value_enum, default_value = "rows")]
    pub axis: AxisArg,
    /// Output format.
    #[arg(long, value_enum, default_value = "csv")]
    pub format: FormatArg,
    /// Which stripes to keep when a scan line has several.
    #[arg(long, value_enum, default_value = "all")]
    pub policy: PolicyArg,
    /// What the sensor sees of a colour frame: auto (the most saturated colour), red, green or blue (that colour's
    /// excess over the mean of the other two, C - (C1 + C2) / 2, shifted so that the frame's darkest thousandth is
    /// 0), luma, one channel (r, g, b), or weights
    /// WR,WG,WB (clamp(wr R + wg G + wb B)). Grey frames are read as they are.
    #[arg(long, default_value = "auto", value_parser = parse_laser)]
    pub laser: Laser,
    /// Largest image accepted, pixels.
    #[arg(long, default_value_t = 64 * 1024 * 1024)]
    pub max_pixels: usize,
    /// Drop points whose profile's flanks are more lopsided than this, 0 to 1 (a stripe cut by an edge, whose
    /// centre is off the sheet) [default: keep them].
    #[arg(long, value_name = "LIMIT", value_parser = parse_asymmetry)]
    pub max_asymmetry: Option<f64>,
    /// Mark points more lopsided than this as cut (the `cut` field of the JSON output; stripe coding lets the dim
    /// ones follow a stripe but not start one), 0 to 1, or `off` (stripes with a one-sided tail, e.g. light
    /// scattered inside a translucent part).
    #[arg(long, value_name = "LIMIT|off", default_value_t = DEFAULT_CUT_ASYMMETRY, value_parser = parse_asymmetry)]
    pub cut_asymmetry: f64,
    /// Also write a PNG of the first image as the sensor sees it (colour frames after --laser), shrunk to at most
    /// --picture-side pixels on a side, with its points drawn on it: green, orange where marked cut.
    #[arg(long, value_name = "FILE.png")]
    pub picture: Option<PathBuf>,
    /// Longest side of the --picture, pixels.
    #[arg(long, value_name = "PX", default_value_t = 1600, value_parser = clap::value_parser!(u32).range(16..=16384))]
    pub picture_side: u32,
}

/// Builds extraction parameters from the command line.
pub fn params(
    method: &str,
    threshold: Option<f64>,
    axis: AxisArg,
    policy: PolicyArg,
) -> Result<ExtractParams> {
    let method = Method::from_name(method).with_context(|| {
        format!(
            "--method {method}: unknown; use one of {}",
            method_names().join(", ")
        )
    })?;
    let threshold = match threshold {
        None => ExtractParams::default().threshold,
        Some(t) if t.is_finite() && t >= 0.0 => Threshold::Fixed(t),
        Some(t) => bail!("--threshold {t}: give a number of grey levels, 0 or more"),
    };
    Ok(ExtractParams {
        method,
        threshold,
        axis: match axis {
            AxisArg::Rows => Axis::Rows,
            AxisArg::Columns => Axis::Columns,
        },
        policy: match policy {
            PolicyArg::All => Policy::All,
            PolicyArg::Brightest => Policy::Brightest,
            PolicyArg::First => Policy::First,
            PolicyArg::Last => Policy::Last,
            PolicyArg::Continuity => Policy::Continuity,
        },
        ..ExtractParams::default()
    })
}

/// Parses `--laser`.
pub fn parse_laser(s: &str) -> Result<Laser, String> {
    Laser::parse(s)
}

/// Parses `--max-asymmetry` and `--cut-asymmetry`: a number from 0 to 1, or `off` (infinity).
pub fn parse_asymmetry(s: &str) -> Result<f64, String> {
    if s.eq_ignore_ascii_case("off") {
        return Ok(f64::INFINITY);
    }
    match s.parse::<f64>() {
        Ok(v) if (0.0..=1.0).contains(&v) => Ok(v),
        _ => Err(format!("`{s}`: give a lopsidedness from 0 to 1, or `off`")),
    }
}

/// Runs the extractor on a decoded frame.
pub fn run_frame(ex: &mut Extractor, frame: &FrameData, out: &mut Extraction) {
    match frame {
        FrameData::U8(img) => ex.extract_into(img.view(), out),
        FrameData::U16(img) => ex.extract_into(img.view(), out),
    }
}

/// Runs `stripe3d extract`.
pub fn extract(args: &ExtractArgs) -> Result<()> {
    let mut params = params(&args.method, args.threshold, args.axis, args.policy)?;
    params.max_asymmetry = args.max_asymmetry.unwrap_or(f64::INFINITY);
    params.cut_asymmetry = args.cut_asymmetry;
    if args.line_threshold {
        params.threshold = Threshold::Line;
    }
    Extractor::new(params.clone())?;
    // Decode and extract every frame before printing anything, so a bad file leaves no partial output.
    let results: Vec<Result<Extraction>> = args
        .images
        .par_iter()
        .map_init(
            || Extractor::new(params.clone()),
            |ex, path| {
                let frame = read_frame_native_as(path, args.max_pixels, Some(args.laser))?;
                let ex = ex.as_mut().map_err(|e| anyhow::anyhow!("{e}"))?;
                let mut out = Extraction::default();
                run_frame(ex, &frame, &mut out);
                Ok(out)
            },
        )
        .collect();
    let frames: Vec<Extraction> = results.into_iter().collect::<Result<_>>()?;
    if let (Some(picture), Some(first), Some(path)) =
        (&args.picture, frames.first(), args.images.first())
    {
        let frame = read_frame_native_as(path, args.max_pixels, Some(args.laser))?;
        let marks: Vec<PointMark> = first
            .points
            .iter()
            .map(|p| PointMark {
                line: p.row,
                x: p.x,
                cut: p.cut,
            })
            .collect();
        let rows_axis = matches!(args.axis, AxisArg::Rows);
        let (w, h, rgb) = points_picture(&frame, &marks, rows_axis, args.picture_side as usize);
        write_rgb_png(picture, w, h, &rgb)?;
    }
    let stdout = std::io::stdout();
    let mut w = std::io::BufWriter::new(stdout.lock());
    let several = frames.len() > 1;
    match args.format {
        FormatArg::Csv => {
            writeln!(
                w,
                "{}row,x,intensity,width,score",
                if several { "frame," } else { "" }
            )?;
            for (f, ex) in frames.iter().enumerate() {
                for p in &ex.points {
                    if several {
                        write!(w, "{f},")?;
                    }
                    writeln!(
                        w,
                        "{},{:.5},{},{},{:.4}",
                        p.row, p.x, p.intensity, p.width, p.score
                    )?;
                }
            }
        }
        FormatArg::Json => {
            let list: Vec<_> = frames
                .iter()
                .enumerate()
                .map(|(f, ex)| {
                    serde_json::json!({
                        "frame": f,
                        "file": args.images[f].display().to_string(),
                        "threshold": ex.threshold,
                        "lines": ex.lines,
                        "points": ex.points,
                        "empty_lines": ex.empty_lines(),
                    })
                })
                .collect();
            serde_json::to_writer_pretty(
                &mut w,
                &serde_json::json!({ "method": args.method, "frames": list }),
            )?;
            writeln!(w)?;
        }
    }
    w.flush()?;
    Ok(())
}
