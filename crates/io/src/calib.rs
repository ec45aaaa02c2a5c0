//! `calib.toml`: what `stripe3d calibrate` fitted (stripe planes of the full model, the paper's linear model, the
//! residuals) and the camera it was fitted with, so that a calibration is never used with another sensor.

use crate::IoError;
use crate::files::read_text;
use serde::{Deserialize, Serialize};
use std::path::Path;
use stripe3d_core::Camera;
use stripe3d_core::calibrate::{Calibration, StripeReport};
use stripe3d_core::sensor::MAX_STRIPES;
use stripe3d_core::triangulate::{FullModel, LinearModel, LinearStripe, Plane};

/// The format name written at the top of every calibration file.
pub const CALIB_FORMAT: &str = "stripe3d-calib";
/// The version of the format this build reads and writes.
pub const CALIB_VERSION: u32 = 1;

#[derive(Debug, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct CalibFile {
    format: String,
    version: u32,
    heights_mm: Vec<f64>,
    camera: Camera,
    stripe: Vec<StripeEntry>,
}

#[derive(Debug, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct StripeEntry {
    index: usize,
    /// Unit normal of the stripe's plane (world frame).
    normal: [f64; 3],
    /// normal · p = offset_mm on the plane.
    offset_mm: f64,
    /// Linear model: height = A(r) - B(r) u, r = (v - cy) / fy.
    linear_a: [f64; 3],
    linear_b: [f64; 3],
    heights_mm: Vec<f64>,
    points: usize,
    full_rms_mm: f64,
    full_max_mm: f64,
    linear_rms_mm: f64,
    linear_max_mm: f64,
}

/// `calib.toml` text for a calibration.
pub fn calibration_to_toml(cal: &Calibration) -> String {
    let file = CalibFile {
        format: CALIB_FORMAT.into(),
        version: CALIB_VERSION,
        heights_mm: cal.heights_mm.clone(),
        camera: cal.full.camera.clone(),
        stripe: cal
            .stripes
            .iter()
            .zip(cal.full.planes.iter().zip(&cal.linear.stripes))
            .map(|(r, (p, l))| StripeEntry {
                index: r.stripe,
                normal: [p.normal.x, p.normal.y, p.normal.z],
                offset_mm: p.offset,
                linear_a: l.a,
                linear_b: l.b,
                heights_mm: r.heights_mm.clone(),
                points: r.points,
                full_rms_mm: r.full_rms_mm,
                full_max_mm: r.full_max_mm,
                linear_rms_mm: r.linear_rms_mm,
                linear_max_mm: r.linear_max_mm,
            })
            .collect(),
    };
    let body = toml::to_string_pretty(&file).unwrap_or_default();
    format!(
        "# stripe3d calibration, written by `stripe3d calibrate`. Stripe planes in the world frame (mm): \
         normal . p = offset_mm.\n# Linear model (the paper's eq. 3): height = A(r) - B(r) * u, A and B quadratics \
         in r = (v - cy) / fy.\n{body}"
    )
}

fn invalid(path: &Path, field: impl Into<String>, message: impl Into<String>) -> IoError {
    IoError::Invalid {
        path: path.to_path_buf(),
        line: None,
        field: field.into(),
        message: message.into(),
    }
}

/// Reads and checks `calib.toml`.
pub fn read_calibration(path: &Path) -> Result<Calibration, IoError> {
    let text = read_text(path)?;
    calibration_from_str(path, &text)
}

/// Parses and checks a calibration held in memory; `path` is used in messages.
pub fn calibration_from_str(path: &Path, text: &str) -> Result<Calibration, IoError> {
    let file: CalibFile = crate::config::parse(path, text)?;
    if file.format != CALIB_FORMAT {
        return Err(invalid(
            path,
            "format",
            format!(
                "\"{}\" is not a stripe3d calibration (expected \"{CALIB_FORMAT}\")",
                file.format
            ),
        ));
    }
    if file.version != CALIB_VERSION {
        return Err(invalid(
            path,
            "version",
            format!(
                "version {} is not supported (this build reads {CALIB_VERSION}); recalibrate",
                file.version
            ),
        ));
    }
    let n = file.stripe.len();
    if n == 0 || n > MAX_STRIPES {
        return Err(invalid(
            path,
            "stripe",
            format!("{n} stripes; expected 1 to {MAX_STRIPES}"),
        ));
    }
    let mut planes = Vec::with_capacity(n);
    let mut linear = Vec::with_capacity(n);
    let mut reports = Vec::with_capacity(n);
    for (i, s) in file.stripe.iter().enumerate() {
        let field = |name: &str| format!("stripe[{i}].{name}");
        if s.index != i {
            return Err(invalid(
                path,
                field("index"),
                format!("{} where {i} was expected (stripes in order)", s.index),
            ));
        }
        let all = s
            .normal
            .iter()
            .chain(&s.linear_a)
            .chain(&s.linear_b)
            .chain(std::iter::once(&s.offset_mm));
        if all.into_iter().any(|v| !v.is_finite()) {
            return Err(invalid(
                path,
                field("normal/offset_mm/linear"),
                "every number must be finite",
            ));
        }
        let normal = nalgebra::Vector3::new(s.normal[0], s.normal[1], s.normal[2]);
        let norm = normal.norm();
        if norm.is_nan() || norm <= 1e-9 {
            return Err(invalid(
                path,
                field("normal"),
                "must not be the zero vector",
            ));
        }
        planes.push(Plane {
            normal: normal / norm,
            offset: s.offset_mm / norm,
        });
        linear.push(LinearStripe {
            a: s.linear_a,
            b: s.linear_b,
        });
        reports.push(StripeReport {
            stripe: i,
            heights_mm: s.heights_mm.clone(),
            points: s.points,
            full_rms_mm: s.full_rms_mm,
            full_max_mm: s.full_max_mm,
            linear_rms_mm: s.linear_rms_mm,
            linear_max_mm: s.linear_max_mm,
        });
    }
    if file.heights_mm.iter().any(|h| !h.is_finite()) {
        return Err(invalid(path, "heights_mm", "every height must be finite"));
    }
    let camera = file.camera;
    let mut sensor = stripe3d_core::Sensor {
        camera: camera.clone(),
        ..Default::default()
    };
    sensor.laser.stripes = n;
    // Only the camera is checked here: the laser of this throwaway sensor is the default one.
    if let Err(e @ stripe3d_core::CoreError::InvalidSensor { field, .. }) = sensor.validate()
        && field.starts_with("camera.")
    {
        return Err(invalid(path, "camera", e.to_string()));
    }
    Ok(Calibration {
        linear: LinearModel {
            cy: camera.cy,
            fy: camera.fy,
            stripes: linear,
        },
        full: FullModel { camera, planes },
        heights_mm: file.heights_mm,
        stripes: reports,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use stripe3d_core::Sensor;

    fn sample() -> Calibration {
        let s = Sensor::default();
        let full = FullModel::nominal(&s);
        let n = full.planes.len();
        Calibration {
            linear: LinearModel {
                cy: s.camera.cy,
                fy: s.camera.fy,
                stripes: vec![
                    LinearStripe {
                        a: [1.0, 2.0, 3.0],
                        b: [0.2, 0.0, 0.001]
                    };
                    n
                ],
            },
            full,
            heights_mm: vec![0.0, 5.0, 10.0],
            stripes: (0..n)
                .map(|k| StripeReport {
                    stripe: k,
                    heights_mm: vec![0.0, 5.0, 10.0],
                    points: 100,
                    full_rms_mm: 0.01,
                    full_max_mm: 0.02,
                    linear_rms_mm: 0.1,
                    linear_max_mm: 0.3,
                })
                .collect(),
        }
    }

    #[test]
    fn a_calibration_round_trips() {
        let cal = sample();
        let text = calibration_to_toml(&cal);
        let back = calibration_from_str(Path::new("calib.toml"), &text).expect("reads");
        assert_eq!(back.full.camera, cal.full.camera);
        assert_eq!(back.linear, cal.linear);
        assert_eq!(back.stripes, cal.stripes);
        for (a, b) in back.full.planes.iter().zip(&cal.full.planes) {
            assert!((a.normal - b.normal).norm() < 1e-12 && (a.offset - b.offset).abs() < 1e-9);
        }
    }

    #[test]
    fn broken_calibrations_are_refused_with_the_field() {
        let text = calibration_to_toml(&sample());
        let p = Path::new("calib.toml");
        let cases = [
            (
                text.replace("format = \"stripe3d-calib\"", "format = \"other\""),
                "format",
            ),
            (text.replace("version = 1", "version = 7"), "version"),
            (
                text.replacen("index = 1", "index = 5", 1),
                "stripe[1].index",
            ),
            (
                text.replacen("offset_mm = ", "offset_mm = nan #", 1),
                "finite",
            ),
            (text.replace("fx = 462.857", "fx = -1.0"), "camera"),
            (format!("{text}\nextra = 1\n"), "unknown field"),
            ("not toml at all [".to_string(), "calib.toml:1"),
        ];
        for (bad, needle) in cases {
            let err = calibration_from_str(p, &bad).expect_err(needle).to_string();
            assert!(err.contains(needle), "{needle}: {err}");
        }
    }

    proptest::proptest! {
        #[test]
        fn arbitrary_text_never_panics(text in "\\PC{0,300}") {
            let _ = calibration_from_str(Path::new("calib.toml"), &text);
        }

        #[test]
        fn mutated_calibrations_are_refused_with_the_file_or_read(
            edits in proptest::collection::vec((0usize..100_000, proptest::prelude::any::<u8>()), 1..4),
        ) {
            let mut bytes = calibration_to_toml(&sample()).into_bytes();
            for (pos, byte) in edits {
                let k = pos % bytes.len();
                bytes[k] = byte;
            }
            if let Ok(text) = String::from_utf8(bytes) {
                if let Err(e) = calibration_from_str(Path::new("calib.toml"), &text) {
                    proptest::prop_assert!(e.to_string().contains("calib.toml"), "{}", e);
                }
            }
        }
    }
}
