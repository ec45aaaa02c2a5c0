//! `stripe3d calibrate` and `stripe3d scan`: from plate images to `calib.toml`, and from frames to the part's point
//! cloud and range image.

use anyhow::{Context, Result, bail};
use clap::{Args, ValueEnum};
use indicatif::{ProgressBar, ProgressStyle};
use rayon::prelude::*;
use serde_json::json;
use std::path::{Path, PathBuf};
use std::time::Instant;
use stripe3d_core::Sensor;
use stripe3d_core::accumulate::ModelKind;
use stripe3d_core::calibrate::{
    Calibration, CalibrationParams, PlaneImage, calibrate, check_camera,
};
use stripe3d_core::code::{CodedFrame, CodingParams};
use stripe3d_core::extract::{ExtractParams, Extraction, Extractor};
pub use stripe3d_core::scan::travel_step;
use stripe3d_core::scan::{ScanOptions, Scanner, finish_scan, spacetime_for};
use stripe3d_io::calib::{calibration_to_toml, read_calibration};
use stripe3d_io::cloud::{write_ply, write_range};
use stripe3d_io::files::prepare_dir;
use stripe3d_io::images::{FrameData, Laser, read_frame_native_as};
use stripe3d_io::{read_coding_params, read_sensor, write_atomic};

/// Largest frame accepted, pixels.
const MAX_FRAME_PIXELS: usize = 64 << 20;

/// Arguments of `stripe3d calibrate`.
#[derive(Debug, Args)]
pub struct CalibrateArgs {
    /// Sensor description (camera, nominal laser geometry).
    #[arg(long)]
    pub sensor: PathBuf,
    /// A plate image and the plate's height: HEIGHT_MM:IMAGE. Three heights at least; every stripe must be seen at
    /// three of them.
    #[arg(long = "plane", value_name = "HEIGHT_MM:IMAGE", required = true)]
    pub planes: Vec<String>,
    /// Where to write the calibration.
    #[arg(long)]
    pub out: PathBuf,
    /// Sub-pixel estimator for the plate images.
    #[arg(long, default_value = "steger", value_parser = clap::builder::PossibleValuesParser::new(crate::extract::method_names()))]
    pub method: String,
    /// What the sensor sees of colour frames (RGB, RGBA; PNG, JPEG, TIFF), as `stripe3d extract --laser`: auto (the
    /// most saturated colour), red, green, blue, luma, r, g, b or WR,WG,WB [default: auto]. Grey frames are read as
    /// they are.
    #[arg(long, value_parser = crate::extract::parse_laser)]
    pub laser: Option<Laser>,
}

/// Triangulation model.
#[derive(Debug, Clone, Copy, ValueEnum)]
pub enum ModelArg {
    /// Pinhole camera with distortion, one fitted plane per stripe.
    Full,
    /// The paper's linear model, height = k (u_belt - u).
    Linear,
}

/// Arguments of `stripe3d scan`.
#[derive(Debug, Args)]
pub struct ScanArgs {
    /// Sensor description.
    #[arg(long)]
    pub sensor: PathBuf,
    /// Calibration written by `stripe3d calibrate`.
    #[arg(long)]
    pub calib: PathBuf,
    /// Output folder: cloud.ply, range.tiff, range.json, range.png, range-colour.png, intensity.tiff, intensity.png.
    #[arg(long)]
    pub out: PathBuf,
    /// Frames in scan order: images (PNG, JPEG, PGM, TIFF) or folders of them (taken in name order, numbers by value:
    /// frame_2 before frame_10).
    #[arg(required = true, value_name = "FRAME")]
    pub frames: Vec<PathBuf>,
    /// Conveyor position of each frame in mm, one per line [default: speed and fps of sensor.toml].
    #[arg(long)]
    pub encoder: Option<PathBuf>,
    /// Range image cell size in mm: one number, or X,Y [default: one pixel on the belt, rounded to 0.01 mm].
    #[arg(long, value_name = "MM[,MM]")]
    pub grid_mm: Option<String>,
    /// Triangulation model.
    #[arg(long, value_enum, default_value = "full")]
    pub model: ModelArg,
    /// Sub-pixel estimator.
    #[arg(long, default_value = "steger", value_parser = clap::builder::PossibleValuesParser::new(crate::extract::method_names()))]
    pub method: String,
    /// Stripe coding: the measuring range and the coding parameters.
    #[command(flatten)]
    pub coding: CodingArgs,
    /// Stripe points whose profile's flanks are more lopsided than this, 0 to 1, are cut: coding lets the dim ones
    /// (a sheet's tail on a corner) follow a stripe but not start one. `off` treats every point alike.
    #[arg(long, value_name = "LIMIT|off", default_value_t = stripe3d_core::extract::DEFAULT_CUT_ASYMMETRY, value_parser = crate::extract::parse_asymmetry)]
    pub cut_asymmetry: f64,
    /// Keep the heights as triangulated: no correction of the curvature bias of the laser sheets' thickness
    /// (made for the `steger` estimator, from laser.sigma_mm and camera.psf_sigma_px of sensor.toml).
    #[arg(long)]
    pub no_curvature_correction: bool,
    /// Keep each frame's stripe centres: no spacetime analysis (which, when the frame step is at most the beam's
    /// width along the travel, places each point by the moment its surface point crosses the sheet, free of the
    /// bias printed texture, rims and curvature give the centre of a stripe).
    #[arg(long)]
    pub no_spacetime: bool,
    /// What the sensor sees of colour frames (RGB, RGBA; PNG, JPEG, TIFF), as `stripe3d extract --laser`: auto (the
    /// most saturated colour), red, green, blue, luma, r, g, b or WR,WG,WB [default: auto]. Grey frames are read as
    /// they are.
    #[arg(long, value_parser = crate::extract::parse_laser)]
    pub laser: Option<Laser>,
}

/// The stripe-coding options of the commands that scan frames (`stripe3d scan`, `stripe3d inspect`).
#[derive(Debug, Clone, Default, Args)]
pub struct CodingArgs {
    /// Measuring range MIN:MAX in mm that stripe coding allows [default: the calibrated heights, widened by a
    /// quarter of their span above and 1 mm below]. MIN may be negative (`--range -1:40`).
    #[arg(long, value_name = "MIN:MAX", allow_hyphen_values = true)]
    pub range: Option<String>,
    /// Stripe-coding parameters (TOML: any fields of `CodingParams`, e.g. `faint_intensity = 0.2`; the others keep
    /// their defaults, tuned on the simulator; the measuring range is --range's).
    #[arg(long, value_name = "FILE")]
    pub coding: Option<PathBuf>,
}

impl CodingArgs {
    /// The coding parameters these options give with calibration `cal` (the file's, else the defaults, with the
    /// measuring range set), and that range (MIN, MAX) in mm.
    pub fn resolve(&self, cal: &Calibration) -> Result<(CodingParams, (f64, f64))> {
        let range_mm = match &self.range {
            Some(r) => parse_range(r)?,
            None => cal.coding_range_mm(),
        };
        let coding = match &self.coding {
            Some(path) => read_coding_params(path)?,
            None => CodingParams::default(),
        };
        Ok((coding_with_range(coding, range_mm), range_mm))
    }

    /// The options given, by flag (for refusing them where nothing is coded).
    pub fn given(&self) -> Vec<&'static str> {
        [
            self.range.as_ref().map(|_| "--range"),
            self.coding.as_ref().map(|_| "--coding"),
        ]
        .into_iter()
        .flatten()
        .collect()
    }
}

/// `coding` with the measuring range `range_mm` (MIN, MAX) that stripe coding allows.
pub fn coding_with_range(coding: CodingParams, range_mm: (f64, f64)) -> CodingParams {
    CodingParams {
        min_height_mm: range_mm.0,
        max_height_mm: range_mm.1,
        ..coding
    }
}

/// The extraction of a scan with estimator `method`: every other setting at its default.
pub fn extract_params(method: &str) -> Result<ExtractParams> {
    use crate::extract::{AxisArg, PolicyArg, params};
    params(method, None, AxisArg::Rows, PolicyArg::All)
}

fn extractor(method: &str) -> Result<Extractor> {
    Ok(Extractor::new(extract_params(method)?)?)
}

fn extract_frame(ex: &mut Extractor, frame: &FrameData) -> Extraction {
    let mut out = Extraction::default();
    crate::extract::run_frame(ex, frame, &mut out);
    out
}

fn parse_plane(arg: &str) -> Result<(f64, PathBuf)> {
    let (h, path) = arg.split_once(':').with_context(|| {
        format!("--plane {arg}: write HEIGHT_MM:IMAGE, e.g. --plane 10:plate-10mm.png")
    })?;
    let h: f64 = h
        .trim()
        .parse()
        .ok()
        .filter(|h: &f64| h.is_finite())
        .with_context(|| format!("--plane {arg}: {h:?} is not a height in mm"))?;
    if path.is_empty() {
        bail!("--plane {arg}: no image after the colon");
    }
    Ok((h, PathBuf::from(path)))
}

/// Calibrates `sensor` from plate images (height mm, file), extracted with estimator `method`; writes nothing.
pub fn calibrate_plates(
    sensor: &Sensor,
    planes: &[(f64, PathBuf)],
    method: &str,
    laser: Laser,
) -> Result<Calibration> {
    extractor(method)?;
    let images: Vec<PlaneImage> = planes
        .par_iter()
        .map_init(
            || extractor(method),
            |ex, (h, path)| -> Result<PlaneImage> {
                let frame = read_frame_native_as(path, MAX_FRAME_PIXELS, Some(laser))?;
                let (w, hgt) = frame.size();
                if (w as u32, hgt as u32) != (sensor.camera.width, sensor.camera.height) {
                    bail!(
                        "{}: {w}x{hgt} pixels but sensor.toml says {}x{}",
                        path.display(),
                        sensor.camera.width,
                        sensor.camera.height
                    );
                }
                let ex = ex.as_mut().map_err(|e| anyhow::anyhow!("{e}"))?;
                Ok(PlaneImage {
                    name: path.display().to_string(),
                    height_mm: *h,
                    points: extract_frame(ex, &frame).points,
                })
            },
        )
        .collect::<Result<_>>()?;
    Ok(calibrate(sensor, &images, &CalibrationParams::default())?)
}

/// Runs `stripe3d calibrate`; returns the calibration it wrote.
pub fn run_calibrate(args: &CalibrateArgs) -> Result<Calibration> {
    let sensor = read_sensor(&args.sensor)?;
    let planes: Vec<(f64, PathBuf)> = args
        .planes
        .iter()
        .map(|p| parse_plane(p))
        .collect::<Result<_>>()?;
    let cal = calibrate_plates(
        &sensor,
        &planes,
        &args.method,
        args.laser.unwrap_or_default(),
    )?;
    say!(
        "calibrated {} stripes from {} plate images at {:?} mm",
        cal.stripes.len(),
        planes.len(),
        cal.heights_mm
    );
    say!("height residuals per stripe, mm (full model: fitted plane; linear: the paper's eq. 3):");
    say!("| stripe | heights seen (mm) | points | full RMS | full max | linear RMS | linear max |");
    say!("|---:|---|---:|---:|---:|---:|---:|");
    for r in &cal.stripes {
        let seen: Vec<String> = r.heights_mm.iter().map(|h| format!("{h}")).collect();
        let partial = if r.heights_mm.len() < cal.heights_mm.len() {
            " (leaves the view at the others)"
        } else {
            ""
        };
        say!(
            "| {} | {}{} | {} | {:.4} | {:.4} | {:.4} | {:.4} |",
            r.stripe,
            seen.join(", "),
            partial,
            r.points,
            r.full_rms_mm,
            r.full_max_mm,
            r.linear_rms_mm,
            r.linear_max_mm
        );
    }
    write_atomic(&args.out, calibration_to_toml(&cal).as_bytes())?;
    say!("wrote {}", args.out.display());
    Ok(cal)
}

/// Expands folders into their images in name order, numbers by value (`frame_2` before `frame_10`, see
/// [`stripe3d_io::files::natural_order`]).
pub fn frame_list(inputs: &[PathBuf]) -> Result<Vec<PathBuf>> {
    let mut out = Vec::new();
    for p in inputs {
        if p.is_dir() {
            let files = stripe3d_io::source::images_in(p)
                .with_context(|| format!("{}: cannot list the folder", p.display()))?;
            if files.is_empty() {
                bail!(
                    "{}: the folder holds no PNG, JPEG, PGM or TIFF frames",
                    p.display()
                );
            }
            out.extend(files);
        } else {
            out.push(p.clone());
        }
    }
    Ok(out)
}

fn parse_grid(s: &str) -> Result<[f64; 2]> {
    let parts: Vec<&str> = s.split(',').collect();
    let num = |t: &str| -> Result<f64> {
        t.trim()
            .parse::<f64>()
            .ok()
            .filter(|v| v.is_finite() && *v > 0.0)
            .with_context(|| format!("--grid-mm {s}: {t:?} is not a positive size in mm"))
    };
    match parts.as_slice() {
        [a] => {
            let a = num(a)?;
            Ok([a, a])
        }
        [a, b] => Ok([num(a)?, num(b)?]),
        _ => bail!("--grid-mm {s}: give one size, or X,Y"),
    }
}

fn parse_range(s: &str) -> Result<(f64, f64)> {
    let (a, b) = s
        .split_once(':')
        .with_context(|| format!("--range {s}: write MIN:MAX in mm, e.g. --range -1:40"))?;
    let num = |t: &str| -> Result<f64> {
        t.trim()
            .parse::<f64>()
            .ok()
            .filter(|v| v.is_finite())
            .with_context(|| format!("--range {s}: {t:?} is not a height in mm"))
    };
    let (lo, hi) = (num(a)?, num(b)?);
    if hi <= lo {
        bail!("--range {s}: MAX must be above MIN");
    }
    Ok((lo, hi))
}

/// Travel (mm since frame 0) of each of `n` frames.
pub fn travels(sensor: &Sensor, encoder: Option<&Path>, n: usize) -> Result<Vec<f64>> {
    if let Some(enc) = encoder {
        let t = stripe3d_io::encoder::read_encoder(enc, stripe3d_io::encoder::MAX_POSITIONS)?;
        if t.len() != n {
            bail!(
                "{}: {} positions for {n} frames; give one position per frame",
                enc.display(),
                t.len()
            );
        }
        return Ok(t);
    }
    let conveyor = sensor.conveyor.as_ref().with_context(|| {
        "sensor.toml has no [conveyor] (speed_mm_s, fps): add it, or give --encoder FILE with one position per frame"
    })?;
    if !(conveyor.speed_mm_s.is_finite() && conveyor.fps.is_finite() && conveyor.fps > 0.0) {
        bail!("sensor.toml: conveyor speed_mm_s and fps must be finite, fps above zero");
    }
    Ok((0..n).map(|k| conveyor.travel_mm(k)).collect())
}

/// What a scan produced: the chain's result and the time it took.
pub struct ScanResult {
    /// Profiles, range image, coding counts, corrections.
    pub scan: stripe3d_core::scan::ScanResult,
    /// Seconds from reading the first frame to the range image.
    pub seconds: f64,
}

impl std::ops::Deref for ScanResult {
    type Target = stripe3d_core::scan::ScanResult;
    fn deref(&self) -> &Self::Target {
        &self.scan
    }
}

/// Extracts, codes and triangulates frames, and accumulates them; writes nothing.
#[allow(clippy::too_many_arguments)]
pub fn scan_frames(
    sensor: &Sensor,
    cal: &Calibration,
    frames: &[PathBuf],
    travel: &[f64],
    extract: ExtractParams,
    model: ModelKind,
    coding_params: CodingParams,
    grid_mm: [f64; 2],
    curvature_correction: bool,
    spacetime: bool,
    laser: Laser,
) -> Result<ScanResult> {
    let method = extract.method;
    let options = ScanOptions {
        grid_mm,
        curvature_correction,
        spacetime,
    };
    let keep_frames = spacetime_for(sensor, cal, travel, &options).is_some();
    let (w, h) = (sensor.camera.width, sensor.camera.height);
    let scanner = Scanner::new(cal, extract, coding_params, model)?;
    let bar = ProgressBar::new(frames.len() as u64).with_style(
        ProgressStyle::with_template("{msg} [{bar:40}] {pos}/{len} frames ({eta})")
            .unwrap_or_else(|_| ProgressStyle::default_bar())
            .progress_chars("=> "),
    );
    bar.set_message("scanning");
    let started = Instant::now();
    // Extraction and coding in parallel; reconciliation across frames and triangulation after (deterministic).
    // The frames are kept for the spacetime analysis, which follows each point through its neighbours.
    let results: Vec<Result<(CodedFrame, Option<FrameData>)>> = frames
        .par_iter()
        .map_init(
            || scanner.clone(),
            |scanner, path| {
                let frame = read_frame_native_as(path, MAX_FRAME_PIXELS, Some(laser))?;
                let (fw, fh) = frame.size();
                if (fw as u32, fh as u32) != (w, h) {
                    bail!(
                        "{}: {fw}x{fh} pixels, but the sensor and its calibration are {w}x{h}; every frame of a scan \
                         must come from that camera",
                        path.display()
                    );
                }
                let mut c = CodedFrame::default();
                match &frame {
                    FrameData::U8(img) => scanner.code_into(img.view(), &mut c),
                    FrameData::U16(img) => scanner.code_into(img.view(), &mut c),
                }
                bar.inc(1);
                Ok((c, keep_frames.then_some(frame)))
            },
        )
        .collect();
    bar.finish_and_clear();
    let (mut coded, kept): (Vec<CodedFrame>, Vec<Option<FrameData>>) = results
        .into_iter()
        .collect::<Result<Vec<_>>>()?
        .into_iter()
        .unzip();
    let images: Vec<FrameData> = kept.into_iter().flatten().collect();
    let scan = finish_scan(
        &mut coded, &images, travel, sensor, cal, model, method, &options,
    )?;
    Ok(ScanResult {
        scan,
        seconds: started.elapsed().as_secs_f64(),
    })
}

/// The default grid: one pixel on the belt, rounded to 0.01 mm.
pub fn default_grid(sensor: &Sensor) -> [f64; 2] {
    let px = (sensor.camera.belt_pixel_mm() * 100.0).round().max(1.0) / 100.0;
    [px, px]
}

/// Runs `stripe3d scan`.
pub fn run_scan(args: &ScanArgs) -> Result<ScanResult> {
    let sensor = read_sensor(&args.sensor)?;
    let cal = read_calibration(&args.calib)?;
    check_camera(&cal.full.camera, &sensor.camera).with_context(|| {
        format!(
            "{} does not belong to {}",
            args.calib.display(),
            args.sensor.display()
        )
    })?;
    if cal.full.planes.len() != sensor.laser.stripes {
        bail!(
            "{} has {} stripes but {} has {}; calibrate this sensor",
            args.calib.display(),
            cal.full.planes.len(),
            args.sensor.display(),
            sensor.laser.stripes
        );
    }
    let frames = frame_list(&args.frames)?;
    let travel = travels(&sensor, args.encoder.as_deref(), frames.len())?;
    let grid = match &args.grid_mm {
        Some(g) => parse_grid(g)?,
        None => default_grid(&sensor),
    };
    let (coding, range_mm) = args.coding.resolve(&cal)?;
    let model = match args.model {
        ModelArg::Full => ModelKind::Full,
        ModelArg::Linear => ModelKind::Linear,
    };
    let extract = ExtractParams {
        cut_asymmetry: args.cut_asymmetry,
        ..extract_params(&args.method)?
    };
    let res = scan_frames(
        &sensor,
        &cal,
        &frames,
        &travel,
        extract,
        model,
        coding,
        grid,
        !args.no_curvature_correction,
        !args.no_spacetime,
        args.laser.unwrap_or_default(),
    )?;
    write_scan(&args.out, &res, &frames, &travel, model, range_mm)?;
    Ok(res)
}

/// Writes a scan's files into `out`.
pub fn write_scan(
    out: &Path,
    res: &ScanResult,
    frames: &[PathBuf],
    travel: &[f64],
    model: ModelKind,
    range_mm: (f64, f64),
) -> Result<()> {
    prepare_dir(out)?;
    let n = write_ply(&out.join("cloud.ply"), &res.profiles)?;
    let s = res.coding;
    write_range(
        out,
        &res.range,
        json!({
            "frames": frames.len(),
            "travel_mm": [travel.first().copied().unwrap_or(0.0), travel.last().copied().unwrap_or(0.0)],
            "frame_step_mm": travel_step(travel),
            "model": model.name(),
            "coding_range_mm": [range_mm.0, range_mm.1],
            "points": n,
            "coding": {"points": s.points, "coded": s.coded, "ambiguous": s.ambiguous, "noise": s.noise},
            "spacetime": res.spacetime.as_ref().map(|(st, done)| json!({
                "half_window_frames": st.half_window,
                "beam_sigma_travel_mm": st.sigma_travel_mm,
                "points": done.points,
                "placed_in_time": done.refined,
                "dropped": done.unsettled,
            })),
            "curvature_corrected": res.curvature_corrected,
            "warnings": res.warnings.iter().map(|w| w.to_string()).collect::<Vec<_>>(),
        }),
    )?;
    let pct = |a: usize| 100.0 * a as f64 / s.points.max(1) as f64;
    say!(
        "scanned {} frames in {:.2} s: {} stripe points, {} coded ({:.1}%), {} ambiguous ({:.1}%) and {} false ({:.1}%) \
         dropped",
        frames.len(),
        res.seconds,
        s.points,
        s.coded,
        pct(s.coded),
        s.ambiguous,
        pct(s.ambiguous),
        s.noise,
        pct(s.noise)
    );
    if let Some((st, done)) = &res.spacetime {
        say!(
            "{} of {} points ({:.1}%) placed by their peak in time, {} dropped as no whole peak in time (hidden part \
             of the time, or lit on two surfaces) (spacetime analysis over {} frames on each side; beam sigma {:.2} mm \
             along the travel; --no-spacetime to keep each frame's centres)",
            done.refined,
            done.points,
            100.0 * done.refined as f64 / done.points.max(1) as f64,
            done.unsettled,
            st.half_window,
            st.sigma_travel_mm
        );
    }
    if res.curvature_corrected > 0 {
        say!(
            "curvature bias of the sheets corrected on {} points ({:.1}%; --no-curvature-correction to keep the \
             triangulated heights)",
            res.curvature_corrected,
            100.0 * res.curvature_corrected as f64 / n.max(1) as f64
        );
    }
    for w in &res.warnings {
        eprintln!("warning: {w}");
    }
    let (lo, hi) = res.range.z_range().unwrap_or((0.0, 0.0));
    say!(
        "range image {}x{} cells of {}x{} mm, {} measured, heights {lo:.3} to {hi:.3} mm",
        res.range.width,
        res.range.height,
        res.range.spacing_mm[0],
        res.range.spacing_mm[1],
        res.range.measured()
    );
    say!(
        "wrote {}: cloud.ply ({n} points), range.tiff + range.json, range.png (16-bit, scale in range.json), range-colour.png{}",
        out.display(),
        if res.range.intensity.is_some() {
            ", intensity.tiff + intensity.png (the stripes' intensity, registered with the heights)"
        } else {
            ""
        }
    );
    Ok(())
}
