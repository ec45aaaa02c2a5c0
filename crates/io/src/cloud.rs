//! Scan outputs: the point cloud as binary little-endian PLY, and the range image as float32 TIFF with a JSON
//! description, a 16-bit PNG preview (its scale in the JSON) and a colour-mapped PNG for people; with it the
//! intensity image (the stripes' peak intensity in each cell) as float32 TIFF and an 8-bit PNG preview.

use crate::images::{height_preview, write_f32_tiff, write_rgb_png};
use crate::{IoError, write_atomic};
use image::{ExtendedColorType, ImageEncoder, codecs::png::PngEncoder};
use serde_json::json;
use std::io::Cursor;
use std::path::Path;
use stripe3d_core::accumulate::{Profile, RangeImage};

/// The PLY header for `n` points with x, y, z and intensity as float32.
pub fn ply_header(n: usize) -> String {
    format!(
        "ply\nformat binary_little_endian 1.0\ncomment stripe3d point cloud, part coordinates, mm\n\
         element vertex {n}\nproperty float x\nproperty float y\nproperty float z\nproperty float intensity\n\
         end_header\n"
    )
}

/// Writes every point of `profiles` as a binary little-endian PLY (float x, y, z in mm, float intensity).
pub fn write_ply(path: &Path, profiles: &[Profile]) -> Result<usize, IoError> {
    let n: usize = profiles.iter().map(|p| p.points.len()).sum();
    let mut buf = ply_header(n).into_bytes();
    buf.reserve(n * 16);
    for p in profiles.iter().flat_map(|p| &p.points) {
        for v in [p.x_mm as f32, p.y_mm as f32, p.z_mm as f32, p.intensity] {
            buf.extend_from_slice(&v.to_le_bytes());
        }
    }
    write_atomic(path, &buf)?;
    Ok(n)
}

/// Encodes `data` (`w` x `h` samples of `colour`, native byte order) as a PNG at `path`, atomically.
fn write_png(
    path: &Path,
    data: &[u8],
    w: usize,
    h: usize,
    colour: ExtendedColorType,
) -> Result<(), IoError> {
    let mut png = Vec::new();
    PngEncoder::new(Cursor::new(&mut png))
        .write_image(data, w as u32, h as u32, colour)
        .map_err(|e| IoError::Image {
            path: path.to_path_buf(),
            message: format!("cannot encode: {e}"),
        })?;
    write_atomic(path, &png)
}

/// Writes `range.tiff`, `range.json`, `range.png` (16-bit: 0 = not measured, 1..65535 linear in height) and
/// `range-colour.png` into `dir`, and when the range image carries intensities `intensity.tiff` (float32 grey
/// levels, NaN where nothing was measured) and `intensity.png` (8-bit: 0 = not measured, 1..255 linear from 0 to
/// the brightest cell), named in the JSON's `intensity`; `extra` is merged into the JSON.
pub fn write_range(
    dir: &Path,
    range: &RangeImage,
    extra: serde_json::Value,
) -> Result<(), IoError> {
    let (w, h) = (range.width, range.height);
    write_f32_tiff(&dir.join("range.tiff"), w, h, &range.z)?;
    let (lo, hi) = range
        .z_range()
        .map_or((0.0, 1.0), |(a, b)| (f64::from(a), f64::from(b)));
    let span = (hi - lo).max(1e-6);
    let mm_per_level = span / 65534.0;
    let levels: Vec<u8> = range
        .z
        .iter()
        .flat_map(|&z| {
            let l: u16 = if z.is_finite() {
                (1.0 + ((f64::from(z) - lo) / mm_per_level).round()).clamp(1.0, 65535.0) as u16
            } else {
                0
            };
            l.to_ne_bytes()
        })
        .collect();
    write_png(
        &dir.join("range.png"),
        &levels,
        w,
        h,
        ExtendedColorType::L16,
    )?;
    // height_preview draws rows along +y bottom-up; range rows run along −y, so hand them over reversed.
    let bottom_up: Vec<f32> = range.z.chunks(w).rev().flatten().copied().collect();
    write_rgb_png(
        &dir.join("range-colour.png"),
        w,
        h,
        &height_preview(w, h, &bottom_up, lo, hi),
    )?;
    let mut doc = json!({
        "file": "range.tiff",
        "units": "mm",
        "width": w,
        "height": h,
        "origin_mm": range.origin_mm,
        "spacing_mm": range.spacing_mm,
        "axes": "column i at x = origin_mm[0] + i * spacing_mm[0]; row j at y = origin_mm[1] - j * spacing_mm[1]; \
                 part coordinates (belt coordinates minus conveyor travel since frame 0)",
        "missing": "NaN",
        "measured_cells": range.measured(),
        "z_min_mm": lo,
        "z_max_mm": hi,
        "preview": {
            "file": "range.png",
            "bits": 16,
            "level_0": "not measured",
            "height_mm": format!("{lo} + (level - 1) * {mm_per_level}"),
            "z0_mm": lo,
            "mm_per_level": mm_per_level,
        },
        "colour_preview": "range-colour.png",
    });
    if let Some(intensity) = range.intensity.as_deref().filter(|i| i.len() == w * h) {
        write_f32_tiff(&dir.join("intensity.tiff"), w, h, intensity)?;
        let brightest = intensity
            .iter()
            .copied()
            .filter(|v| v.is_finite())
            .fold(0.0f32, f32::max);
        let scale = 254.0 / f64::from(brightest.max(1e-6));
        let levels: Vec<u8> = intensity
            .iter()
            .map(|&v| {
                if v.is_finite() {
                    (1.0 + (f64::from(v.max(0.0)) * scale).round()).clamp(1.0, 255.0) as u8
                } else {
                    0
                }
            })
            .collect();
        write_png(
            &dir.join("intensity.png"),
            &levels,
            w,
            h,
            ExtendedColorType::L8,
        )?;
        if let Some(obj) = doc.as_object_mut() {
            obj.insert(
                "intensity".into(),
                json!({
                    "file": "intensity.tiff",
                    "units": "grey levels: the stripes' peak intensity, registered with the heights",
                    "missing": "NaN",
                    "preview": {
                        "file": "intensity.png",
                        "bits": 8,
                        "level_0": "not measured",
                        "grey_levels": format!("(level - 1) * {}", 1.0 / scale),
                        "grey_levels_per_level": 1.0 / scale,
                    },
                }),
            );
        }
    }
    if let (Some(obj), serde_json::Value::Object(more)) = (doc.as_object_mut(), extra) {
        obj.extend(more);
    }
    let text = serde_json::to_string_pretty(&doc).unwrap_or_default();
    write_atomic(&dir.join("range.json"), text.as_bytes())
}

#[cfg(test)]
mod tests {
    use super::*;
    use stripe3d_core::accumulate::ProfilePoint;

    #[test]
    fn the_ply_is_binary_little_endian_with_the_declared_count() {
        let dir = tempfile::tempdir().expect("tmp");
        let p = Profile {
            frame: 0,
            travel_mm: 0.0,
            points: vec![ProfilePoint {
                stripe: 1,
                row: 2,
                u: 3.0,
                x_mm: 1.5,
                y_mm: -2.0,
                z_mm: 10.25,
                intensity: 200.0,
                spacetime: false,
            }],
        };
        let path = dir.path().join("cloud.ply");
        assert_eq!(write_ply(&path, &[p.clone(), p]).expect("write"), 2);
        let bytes = std::fs::read(&path).expect("read");
        let header = ply_header(2);
        assert!(bytes.starts_with(header.as_bytes()));
        let body = &bytes[header.len()..];
        assert_eq!(body.len(), 2 * 16);
        let f = |i: usize| f32::from_le_bytes(body[i * 4..i * 4 + 4].try_into().expect("4"));
        assert_eq!((f(0), f(1), f(2), f(3)), (1.5, -2.0, 10.25, 200.0));
    }

    #[test]
    fn the_range_files_are_written_with_their_scale() {
        let dir = tempfile::tempdir().expect("tmp");
        let r = RangeImage {
            origin_mm: [-1.0, 1.0],
            spacing_mm: [0.5, 0.5],
            width: 3,
            height: 2,
            z: vec![1.0, f32::NAN, 2.0, 3.0, 1.5, f32::NAN],
            intensity: None,
        };
        write_range(dir.path(), &r, json!({"frames": 4})).expect("write");
        let doc: serde_json::Value = serde_json::from_str(
            &std::fs::read_to_string(dir.path().join("range.json")).expect("json"),
        )
        .expect("parse");
        assert_eq!(doc["frames"], 4);
        assert_eq!(doc["measured_cells"], 4);
        assert_eq!(doc["z_min_mm"], 1.0);
        let img = image::open(dir.path().join("range.png"))
            .expect("png")
            .into_luma16();
        assert_eq!(img.get_pixel(1, 0).0[0], 0, "NaN is level 0");
        assert_eq!(img.get_pixel(0, 0).0[0], 1, "the lowest height is level 1");
        assert_eq!(img.get_pixel(0, 1).0[0], 65535);
        let file = std::fs::File::open(dir.path().join("range.tiff")).expect("tiff");
        let mut dec = tiff::decoder::Decoder::new(file).expect("decoder");
        assert_eq!(dec.dimensions().expect("dims"), (3, 2));
        match dec.read_image().expect("read") {
            tiff::decoder::DecodingResult::F32(v) => {
                assert_eq!(v[0], 1.0);
                assert!(v[1].is_nan());
            }
            _ => panic!("not float32"),
        }
    }
}
