//! `sensor.toml`, scene files and stripe-coding parameter files.
//!
//! All are TOML. Syntax and type errors carry the line and column; impossible values (zero focal length,
//! stripes outside the view, a negative diameter) carry the field's dotted name and, where it is written in the
//! file, its line.

use crate::IoError;
use crate::files::read_text;
use serde::de::DeserializeOwned;
use std::path::Path;
use stripe3d_core::code::CodingParams;
use stripe3d_core::{CoreError, Sensor};
use stripe3d_sim::{Scene, SimError};

/// Largest configuration file accepted, bytes.
pub const MAX_CONFIG_BYTES: usize = 1 << 20;

pub(crate) fn parse<T: DeserializeOwned>(path: &Path, text: &str) -> Result<T, IoError> {
    if text.len() > MAX_CONFIG_BYTES {
        return Err(IoError::Invalid {
            path: path.to_path_buf(),
            line: None,
            field: "(file)".into(),
            message: format!(
                "{} bytes is larger than the {MAX_CONFIG_BYTES} accepted",
                text.len()
            ),
        });
    }
    toml::from_str(text).map_err(|e| {
        let (line, column) = e.span().map_or((1, 1), |s| line_col(text, s.start));
        IoError::Syntax {
            path: path.to_path_buf(),
            line,
            column,
            message: e.message().trim().to_string(),
        }
    })
}

/// 1-based line and column of a byte offset.
fn line_col(text: &str, offset: usize) -> (usize, usize) {
    let before = &text[..offset.min(text.len())];
    let line = before.matches('\n').count() + 1;
    let column = before.rsplit('\n').next().map_or(0, |l| l.chars().count()) + 1;
    (line, column)
}

/// Line of `section.key` (or `key` at the top) in a TOML text, when written there plainly.
fn line_of(text: &str, dotted: &str) -> Option<usize> {
    let (section, key) = match dotted.rsplit_once('.') {
        Some((s, k)) => (Some(s), k),
        None => (None, dotted),
    };
    let mut current: Option<String> = None;
    for (n, raw) in text.lines().enumerate() {
        let line = raw.trim();
        if line.starts_with('[') {
            current = Some(
                line.trim_matches(|c| c == '[' || c == ']')
                    .trim()
                    .to_string(),
            );
            continue;
        }
        let in_section = match (section, &current) {
            (None, None) => true,
            (Some(s), Some(c)) => s == c,
            _ => false,
        };
        if in_section {
            if let Some((k, _)) = line.split_once('=') {
                if k.trim() == key {
                    return Some(n + 1);
                }
            }
        }
    }
    // Not written: point at the section header, if any.
    let header = format!("[{}]", section?);
    text.lines().position(|l| l.trim() == header).map(|n| n + 1)
}

/// The error for a value the core refused in the file `path` holding `text`: the field's name and, where it is
/// written plainly, its line (`what` names the file's kind when the refusal names no field).
fn refused(path: &Path, text: &str, e: CoreError, what: &str) -> IoError {
    match e {
        CoreError::InvalidSensor {
            field,
            value,
            reason,
        }
        | CoreError::InvalidParameter {
            field,
            value,
            reason,
        } => IoError::Invalid {
            path: path.to_path_buf(),
            line: line_of(text, field),
            field: field.to_string(),
            message: format!("{value}: {reason}"),
        },
        other => IoError::Invalid {
            path: path.to_path_buf(),
            line: None,
            field: what.into(),
            message: other.to_string(),
        },
    }
}

/// Reads and validates `sensor.toml`.
pub fn read_sensor(path: &Path) -> Result<Sensor, IoError> {
    let text = read_text(path)?;
    sensor_from_str(path, &text)
}

/// Parses and validates a sensor description held in memory; `path` is used in messages.
pub fn sensor_from_str(path: &Path, text: &str) -> Result<Sensor, IoError> {
    let sensor: Sensor = parse(path, text)?;
    sensor
        .validate()
        .map_err(|e| refused(path, text, e, "(sensor)"))?;
    Ok(sensor)
}

/// Reads and validates a scene file.
pub fn read_scene(path: &Path) -> Result<Scene, IoError> {
    let text = read_text(path)?;
    scene_from_str(path, &text)
}

/// Parses and validates a scene held in memory; `path` is used in messages.
pub fn scene_from_str(path: &Path, text: &str) -> Result<Scene, IoError> {
    let scene: Scene = parse(path, text)?;
    scene.validate().map_err(|e| match e {
        SimError::InvalidScene { field, reason } => IoError::Invalid {
            line: if field.starts_with("feature[") {
                None
            } else {
                line_of(text, &field)
            },
            path: path.to_path_buf(),
            field,
            message: reason,
        },
        other => IoError::Invalid {
            path: path.to_path_buf(),
            line: None,
            field: "(scene)".into(),
            message: other.to_string(),
        },
    })?;
    Ok(scene)
}

/// Reads and validates a stripe-coding parameter file (`stripe3d scan --coding`).
pub fn read_coding_params(path: &Path) -> Result<CodingParams, IoError> {
    let text = read_text(path)?;
    coding_params_from_str(path, &text)
}

/// Parses and validates stripe-coding parameters held in memory; `path` is used in messages. Fields left out keep
/// their defaults. The measuring range (`min_height_mm`, `max_height_mm`) is refused here: a scan sets it with
/// `--range` or from the calibration, and a value in the file would be silently replaced.
pub fn coding_params_from_str(path: &Path, text: &str) -> Result<CodingParams, IoError> {
    let params: CodingParams = parse(path, text)?;
    for field in ["min_height_mm", "max_height_mm"] {
        if let Some(line) = line_of(text, field) {
            return Err(IoError::Invalid {
                path: path.to_path_buf(),
                line: Some(line),
                field: field.into(),
                message:
                    "the measuring range is set with `stripe3d scan --range MIN:MAX` (or from the \
                          calibration): remove it from this file"
                        .into(),
            });
        }
    }
    params
        .validate()
        .map_err(|e| refused(path, text, e, "(coding)"))?;
    Ok(params)
}

/// `sensor.toml` text for a sensor (every field written, with its default where the user gave none).
pub fn sensor_to_toml(sensor: &Sensor) -> String {
    let body = toml::to_string_pretty(sensor).unwrap_or_default();
    format!(
        "# stripe3d sensor description. Units: mm, pixels, seconds. World frame: z up from the belt, x along\n\
         # conveyor travel, origin on the belt below the camera's optical centre; image u along +x, v along -y.\n{body}"
    )
}

/// Scene file text for a scene.
pub fn scene_to_toml(scene: &Scene) -> String {
    toml::to_string_pretty(scene).unwrap_or_default()
}

#[cfg(test)]
mod tests {
    use super::*;

    const ISSUE_EXAMPLE: &str = r#"
[camera]
width = 648
height = 480
fx = 462.857
fy = 462.857
cx = 323.5
cy = 239.5
k1 = 0.0          # radial distortion on normalised coordinates: x_d = x (1 + k1 r^2)
height_mm = 100.0 # optical centre above the belt
[laser]
stripes = 11
[conveyor]        # optional
speed_mm_s = 10.0
fps = 20.0
"#;

    #[test]
    fn the_documented_example_is_accepted_exactly_as_written() {
        let s = sensor_from_str(Path::new("sensor.toml"), ISSUE_EXAMPLE).expect("valid");
        assert_eq!(s.camera.width, 648);
        assert_eq!(s.laser.stripes, 11);
        assert_eq!(s.conveyor.as_ref().map(|c| c.fps), Some(20.0));
        // and it round-trips through our writer
        let again = sensor_from_str(Path::new("x"), &sensor_to_toml(&s)).expect("round trip");
        assert_eq!(again, s);
    }

    #[test]
    fn errors_name_file_line_and_field() {
        let p = Path::new("cfg/sensor.toml");
        let e = sensor_from_str(p, &ISSUE_EXAMPLE.replace("fx = 462.857", "fx = 0.0"))
            .expect_err("zero fx");
        let msg = e.to_string();
        assert!(msg.starts_with("cfg/sensor.toml:5: camera.fx"), "{msg}");
        let e = sensor_from_str(p, &ISSUE_EXAMPLE.replace("fy = 462.857", "fy = \"big\""))
            .expect_err("type");
        assert!(matches!(e, IoError::Syntax { line: 6, .. }), "{e}");
        let e =
            sensor_from_str(p, &ISSUE_EXAMPLE.replace("cx = 323.5\n", "")).expect_err("missing");
        assert!(e.to_string().contains("cx"), "{e}");
        let e = sensor_from_str(
            p,
            &ISSUE_EXAMPLE.replace("stripes = 11", "stripes = 11\npitch_mm = 30"),
        )
        .expect_err("out of view");
        assert!(e.to_string().contains("outside"), "{e}");
        let e =
            sensor_from_str(p, &ISSUE_EXAMPLE.replace("k1 = 0.0", "k1 = nan")).expect_err("nan");
        assert!(e.to_string().contains("camera.k1"), "{e}");
        let e = sensor_from_str(p, &ISSUE_EXAMPLE.replace("[laser]", "[laser]\nstrips = 3"))
            .expect_err("typo");
        assert!(e.to_string().contains("strips"), "{e}");
        let e = sensor_from_str(p, "[camera\nwidth=1").expect_err("syntax");
        assert!(matches!(e, IoError::Syntax { line: 1, .. }), "{e}");
    }

    #[test]
    fn scenes_round_trip_and_bad_ones_name_the_field() {
        let demo = Scene::demo();
        let back =
            scene_from_str(Path::new("demo.toml"), &scene_to_toml(&demo)).expect("round trip");
        assert_eq!(back, demo);
        let text = "name = \"x\"\n[[feature]]\nkind = \"bump\"\nx_mm = 0\ny_mm = 0\ndiameter_mm = 3\nheight_mm = -1\n";
        let e = scene_from_str(Path::new("s.toml"), text).expect_err("negative");
        assert!(e.to_string().contains("feature[0].height_mm"), "{e}");
        let e = scene_from_str(
            Path::new("s.toml"),
            "name = \"x\"\n[[feature]]\nkind = \"blob\"\n",
        )
        .expect_err("kind");
        assert!(matches!(e, IoError::Syntax { .. }), "{e}");
    }

    #[test]
    fn coding_parameter_files_set_what_they_name_and_refuse_by_field() {
        let p = Path::new("coding.toml");
        let c = coding_params_from_str(
            p,
            "# tuned on our line\nfaint_intensity = 0.2\nmax_outlier_run = 3\n",
        )
        .expect("valid");
        assert_eq!(c.faint_intensity, 0.2);
        assert_eq!(c.max_outlier_run, 3);
        assert_eq!(
            c.jump_cost,
            CodingParams::default().jump_cost,
            "the rest keep their defaults"
        );
        assert_eq!(
            coding_params_from_str(p, "").expect("empty"),
            CodingParams::default()
        );
        // The README's example.
        let readme = "# coding.toml: our line's stripes are dimmer at the far edge of the view\n\
                      faint_intensity = 0.1\nbelt_intensity_ratio = 0.4\n";
        let c = coding_params_from_str(p, readme).expect("README example");
        assert_eq!((c.faint_intensity, c.belt_intensity_ratio), (0.1, 0.4));
        let e =
            coding_params_from_str(p, "margin = 0.3\noutlier_cost = -1\n").expect_err("negative");
        assert!(
            e.to_string().starts_with("coding.toml:2: outlier_cost"),
            "{e}"
        );
        let e = coding_params_from_str(p, "tilt_cost = 1\n").expect_err("unknown field");
        assert!(matches!(e, IoError::Syntax { line: 1, .. }), "{e}");
        assert!(e.to_string().contains("tilt_cost"), "{e}");
        let e = coding_params_from_str(p, "belt_intensity_ratio = 2\n").expect_err("ratio");
        assert!(e.to_string().contains("belt_intensity_ratio"), "{e}");
        let e = coding_params_from_str(p, "margin = nan\n").expect_err("nan");
        assert!(e.to_string().contains("margin"), "{e}");
        let e = coding_params_from_str(p, "max_outlier_run = -2\n").expect_err("type");
        assert!(matches!(e, IoError::Syntax { .. }), "{e}");
        let e = coding_params_from_str(p, "jump_mm = 1\nmax_height_mm = 30\n").expect_err("range");
        assert!(
            e.to_string().starts_with("coding.toml:2: max_height_mm"),
            "{e}"
        );
        assert!(e.to_string().contains("--range"), "{e}");
    }

    proptest::proptest! {
        #[test]
        fn arbitrary_text_never_panics(text in "\\PC{0,200}") {
            let _ = sensor_from_str(Path::new("p"), &text);
            let _ = scene_from_str(Path::new("p"), &text);
            let _ = coding_params_from_str(Path::new("p"), &text);
        }

        #[test]
        fn mutated_coding_files_never_panic(pos in 0usize..200, byte in proptest::prelude::any::<u8>()) {
            let mut bytes = b"margin = 0.3\nmax_outlier_run = 2\nbelt_intensity_ratio = 0.55\nmax_gap_rows = 40\n".to_vec();
            let i = pos % bytes.len();
            bytes[i] = byte;
            if let Ok(text) = String::from_utf8(bytes) {
                let _ = coding_params_from_str(Path::new("p"), &text);
            }
        }

        #[test]
        fn mutated_valid_files_never_panic(pos in 0usize..400, byte in proptest::prelude::any::<u8>()) {
            let mut bytes = ISSUE_EXAMPLE.as_bytes().to_vec();
            let i = pos % bytes.len();
            bytes[i] = byte;
            if let Ok(text) = String::from_utf8(bytes) {
                let _ = sensor_from_str(Path::new("p"), &text);
            }
        }
    }
}
