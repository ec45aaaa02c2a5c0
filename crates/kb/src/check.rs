//! Design assistance (`stripe3d kb check PRODUCT`): problems anticipated before production from the product, its
//! process and its inspection method — features and limits finer than the sensor resolves, tolerances tighter than
//! the process holds or than the measurement can tell, surfaces that need other exposure, and features the stripes
//! cannot light.

use crate::KbError;
use crate::model::{FeatureKind, KnowledgeBase, Measure};
use serde::Serialize;
use stripe3d_core::Sensor;

/// Height noise of one range cell in pixels of stripe displacement, as measured by `stripe3d bench sensor` on the
/// default set-up (0.0054 mm noise at 0.214 mm per pixel).
pub const DEPTH_NOISE_PX: f64 = 0.025;
/// A tolerance should be at least this many times the measurement uncertainty (precision-to-tolerance 1:4).
pub const TOLERANCE_TO_UNCERTAINTY: f64 = 4.0;
/// Expanded uncertainty of a height difference, in height-noise standard deviations.
pub const UNCERTAINTY_SIGMAS: f64 = 3.0;
/// Features narrower than this many range cells cannot be measured.
pub const MIN_FEATURE_CELLS: f64 = 5.0;

/// How bad a finding is.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum Severity {
    /// Worth knowing.
    Note,
    /// Likely trouble.
    Warning,
    /// The inspection cannot do what the knowledge base asks.
    Problem,
}

impl Severity {
    /// Name.
    pub fn name(self) -> &'static str {
        match self {
            Severity::Note => "note",
            Severity::Warning => "warning",
            Severity::Problem => "problem",
        }
    }
}

/// One anticipated problem.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Finding {
    /// Severity.
    pub severity: Severity,
    /// What it is about (`feature "mounting hole 1"`).
    pub subject: String,
    /// What and what to do.
    pub message: String,
}

/// What the method's sensor resolves on the product's top surface.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct SensorFigures {
    /// Pixel footprint across the travel, mm.
    pub lateral_across_mm: f64,
    /// Spacing of profiles along the travel (or the range grid, when coarser), mm.
    pub lateral_along_mm: f64,
    /// Height that moves a stripe by one pixel (least inclined sheet), mm.
    pub depth_per_px_mm: f64,
    /// Height noise of one cell, mm.
    pub depth_noise_mm: f64,
    /// Largest tangent of a sheet's angle from the vertical (shadows).
    pub max_tan_angle: f64,
    /// Width of the view across the travel at the product's top, mm.
    pub view_width_mm: f64,
}

/// The figures of `sensor` at height `z_mm` with range cells of `grid_mm` (default: one pixel).
pub fn sensor_figures(sensor: &Sensor, z_mm: f64, grid_mm: Option<f64>) -> SensorFigures {
    let c = &sensor.camera;
    let range = (c.height_mm - z_mm).max(1.0);
    let across = range / c.fy;
    let step = sensor
        .conveyor
        .as_ref()
        .map_or(across, |v| v.speed_mm_s / v.fps);
    let grid = grid_mm.unwrap_or(across);
    let tans: Vec<f64> = sensor
        .laser
        .planes()
        .iter()
        .map(|p| p.tan_angle().abs())
        .filter(|t| t.is_finite())
        .collect();
    let min_tan = tans.iter().copied().fold(f64::INFINITY, f64::min).max(1e-6);
    let max_tan = tans.iter().copied().fold(0.0, f64::max);
    let depth_per_px = range / (c.fx * min_tan);
    SensorFigures {
        lateral_across_mm: across.max(grid),
        lateral_along_mm: step.max(grid),
        depth_per_px_mm: depth_per_px,
        depth_noise_mm: DEPTH_NOISE_PX * depth_per_px,
        max_tan_angle: max_tan,
        view_width_mm: f64::from(c.height) * range / c.fy,
    }
}

/// Checks product `name` against its process and method.
pub fn check_product(
    kb: &KnowledgeBase,
    name: &str,
) -> Result<(SensorFigures, Vec<Finding>), KbError> {
    let (p, process, method) = kb.product_context(name)?;
    let sensor = method.sensor();
    let fig = sensor_figures(&sensor, p.geometry.thickness_mm, method.scan.grid_mm);
    let lateral = fig.lateral_across_mm.max(fig.lateral_along_mm);
    let uncertainty = UNCERTAINTY_SIGMAS * fig.depth_noise_mm;
    let threshold = method.surface.threshold_mm;
    let min_area = method.surface.detect_params().min_area_mm2;
    let mut out = Vec::new();
    fn add(out: &mut Vec<Finding>, severity: Severity, subject: String, message: String) {
        out.push(Finding {
            severity,
            subject,
            message,
        })
    }
    // The part in the view.
    if p.geometry.width_mm > fig.view_width_mm {
        add(
            &mut out,
            Severity::Problem,
            "geometry".into(),
            format!(
                "the part is {:.1} mm wide but the view is {:.1} mm across at its top: its sides are never scanned \
                 (raise the camera or use a wider lens)",
                p.geometry.width_mm, fig.view_width_mm
            ),
        );
    }
    // Tolerances: process capability and measurement uncertainty.
    let tol = &p.tolerances;
    for (what, t, cap) in [
        (
            "thickness",
            tol.thickness_mm,
            process.capability.thickness_mm,
        ),
        ("flatness", tol.flatness_mm, process.capability.flatness_mm),
    ] {
        let Some(t) = t else { continue };
        if let Some(c) = cap.filter(|c| t < *c) {
            add(
                &mut out,
                Severity::Problem,
                format!("tolerance {what}"),
                format!(
                    "{t} mm is tighter than process `{}` holds ({c} mm): expect a high reject rate, or choose a \
                     more capable process",
                    process.name
                ),
            );
        }
        if t < TOLERANCE_TO_UNCERTAINTY * uncertainty {
            add(
                &mut out,
                Severity::Warning,
                format!("tolerance {what}"),
                format!(
                    "{t} mm is less than {TOLERANCE_TO_UNCERTAINTY} x the measurement uncertainty ({uncertainty:.4} mm \
                     = {UNCERTAINTY_SIGMAS} x {:.4} mm noise): the verdict near the limit is a coin toss; average \
                     more profiles or use a finer set-up",
                    fig.depth_noise_mm
                ),
            );
        }
    }
    // Limits the detection cannot see.
    let limit = |out: &mut Vec<Finding>, subject: String, depth: Option<f64>, area: Option<f64>| {
        if let Some(d) = depth.filter(|d| *d < threshold) {
            out.push(Finding {
                severity: Severity::Problem,
                subject: subject.clone(),
                message: format!(
                    "depth limit {d} mm is below the detection threshold {threshold} mm of method `{}`: shallower \
                     defects are never found, so the limit is never enforced (lower surface.threshold_mm, if the \
                     noise allows: {:.4} mm)",
                    method.name, fig.depth_noise_mm
                ),
            });
        }
        if let Some(a) = area.filter(|a| *a < min_area) {
            out.push(Finding {
                severity: Severity::Problem,
                subject,
                message: format!(
                    "area limit {a} mm² is below the smallest region detection reports ({min_area} mm²)"
                ),
            });
        }
    };
    for z in &p.zones {
        limit(
            &mut out,
            format!("zone `{}`", z.name),
            z.max_depth_mm,
            z.max_area_mm2,
        );
    }
    for (i, s) in method.standards.iter().enumerate() {
        match (s.measure, s.above) {
            (Some(Measure::DepthMm), Some(a)) => limit(
                &mut out,
                format!("method `{}` standard[{i}]", method.name),
                Some(a),
                None,
            ),
            (Some(Measure::AreaMm2), Some(a)) => limit(
                &mut out,
                format!("method `{}` standard[{i}]", method.name),
                None,
                Some(a),
            ),
            _ => {}
        }
    }
    // Designed features: resolution, process, light.
    for f in &p.features {
        let subject = format!("feature `{}`", f.name);
        if f.diameter_mm < MIN_FEATURE_CELLS * lateral {
            add(
                &mut out,
                Severity::Warning,
                subject.clone(),
                format!(
                    "{} mm across is under {MIN_FEATURE_CELLS} range cells ({lateral:.3} mm each): its size cannot be \
                     measured reliably",
                    f.diameter_mm
                ),
            );
        }
        // A diameter from the hole's area is uncertain by about half a cell (rim cells are half in, half out).
        if let Some(t) = f.diameter_tolerance_mm.filter(|t| *t < lateral) {
            add(
                &mut out,
                if t < 0.5 * lateral {
                    Severity::Problem
                } else {
                    Severity::Warning
                },
                subject.clone(),
                format!(
                    "diameter tolerance ±{t} mm is finer than the coarser lateral resolution ({lateral:.3} mm; the \
                     diameter from the area is good to about half of it): the check is marginal; scan slower or \
                     with a finer grid"
                ),
            );
        }
        if let Some(s) = process
            .capability
            .smallest_feature_mm
            .filter(|s| f.diameter_mm < *s)
        {
            add(
                &mut out,
                Severity::Problem,
                subject.clone(),
                format!(
                    "{} mm is smaller than process `{}` makes reliably ({s} mm)",
                    f.diameter_mm, process.name
                ),
            );
        }
        let h = f.height_mm.unwrap_or(p.geometry.thickness_mm);
        let shadow = h * fig.max_tan_angle;
        match f.kind {
            FeatureKind::Hole if shadow >= f.diameter_mm => add(
                &mut out,
                Severity::Note,
                subject.clone(),
                format!(
                    "the stripes fall {shadow:.1} mm across its {h} mm depth, more than its {} mm diameter: its \
                     bottom is never lit, so it shows as a gap (depth assumed through)",
                    f.diameter_mm
                ),
            ),
            FeatureKind::Boss if shadow > 0.5 => add(
                &mut out,
                Severity::Note,
                subject.clone(),
                format!(
                    "its {h} mm height throws a {shadow:.1} mm shadow beside it: surface there is not measured"
                ),
            ),
            _ => {}
        }
    }
    // Material.
    let m = &p.material;
    if m.gloss > 0.3 {
        add(
            &mut out,
            Severity::Warning,
            "material".into(),
            format!(
                "gloss {} ({}): specular highlights saturate and mirrored stripes appear as ghosts; lower the \
                 exposure, use a polariser, or tilt the camera off the specular direction",
                m.gloss, m.name
            ),
        );
    }
    if m.reflectance < 0.15 {
        add(
            &mut out,
            Severity::Warning,
            "material".into(),
            format!(
                "reflectance {} ({}): stripes will be dim; raise the laser power or the exposure",
                m.reflectance, m.name
            ),
        );
    }
    // The process's typical defects against the sensor and the threshold.
    for d in &process.defects {
        let subject = format!("process `{}` {}", process.name, d.kind);
        if d.typical_diameter_mm[0] < MIN_FEATURE_CELLS * lateral {
            add(
                &mut out,
                Severity::Warning,
                subject.clone(),
                format!(
                    "its smallest typical {} defects ({} mm) span fewer than {MIN_FEATURE_CELLS} range cells: they \
                     may be missed or mis-sized",
                    d.kind, d.typical_diameter_mm[0]
                ),
            );
        }
        if d.kind != "hole" && d.kind != "edge-chip" && d.typical_depth_mm[0] < threshold {
            add(
                &mut out,
                Severity::Warning,
                subject,
                format!(
                    "its shallowest typical {} defects ({} mm) are below the detection threshold ({threshold} mm)",
                    d.kind, d.typical_depth_mm[0]
                ),
            );
        }
    }
    out.sort_by_key(|f| std::cmp::Reverse(f.severity));
    Ok((fig, out))
}
