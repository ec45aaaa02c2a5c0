//! Image files: grey PNG (8/16-bit) and float32 TIFF writing, colour-mapped previews, and reading PNG, PGM and
//! TIFF frames.

use crate::{IoError, write_atomic};
use image::{ExtendedColorType, ImageEncoder, codecs::png::PngEncoder};
use std::io::Cursor;
use std::path::Path;
use stripe3d_core::Image;

/// Largest image side accepted when reading, pixels (a guard against decompression bombs).
pub const MAX_READ_SIDE: u32 = 16_384;

fn encode_err(path: &Path, e: impl std::fmt::Display) -> IoError {
    IoError::Image {
        path: path.to_path_buf(),
        message: format!("cannot encode: {e}"),
    }
}

/// Writes a grey image as PNG: 8-bit when `bits` is 8, else 16-bit with the values as they are.
pub fn write_grey_png(path: &Path, img: &Image<u16>, bits: u8) -> Result<(), IoError> {
    let mut buf = Vec::new();
    let (w, h) = (img.width() as u32, img.height() as u32);
    let enc = PngEncoder::new(Cursor::new(&mut buf));
    if bits <= 8 {
        let bytes: Vec<u8> = img.data().iter().map(|&v| v.min(255) as u8).collect();
        enc.write_image(&bytes, w, h, ExtendedColorType::L8)
            .map_err(|e| encode_err(path, e))?;
    } else {
        let bytes: Vec<u8> = img.data().iter().flat_map(|v| v.to_ne_bytes()).collect();
        enc.write_image(&bytes, w, h, ExtendedColorType::L16)
            .map_err(|e| encode_err(path, e))?;
    }
    write_atomic(path, &buf)
}

/// Writes an RGB image (row-major, 3 bytes a pixel) as PNG.
pub fn write_rgb_png(path: &Path, width: usize, height: usize, rgb: &[u8]) -> Result<(), IoError> {
    let mut buf = Vec::new();
    PngEncoder::new(Cursor::new(&mut buf))
        .write_image(rgb, width as u32, height as u32, ExtendedColorType::Rgb8)
        .map_err(|e| encode_err(path, e))?;
    write_atomic(path, &buf)
}

/// Writes float32 samples (row-major, NaN allowed) as a one-channel TIFF.
pub fn write_f32_tiff(
    path: &Path,
    width: usize,
    height: usize,
    data: &[f32],
) -> Result<(), IoError> {
    let mut cursor = Cursor::new(Vec::new());
    let mut enc = tiff::encoder::TiffEncoder::new(&mut cursor).map_err(|e| encode_err(path, e))?;
    enc.write_image::<tiff::encoder::colortype::Gray32Float>(width as u32, height as u32, data)
        .map_err(|e| encode_err(path, e))?;
    write_atomic(path, cursor.get_ref())
}

/// A perceptually ordered colour map (dark blue, through teal and green, to yellow), `t` in [0, 1].
pub fn colormap(t: f64) -> [u8; 3] {
    const STOPS: [[f64; 3]; 5] = [
        [68.0, 1.0, 84.0],
        [59.0, 82.0, 139.0],
        [33.0, 145.0, 140.0],
        [94.0, 201.0, 98.0],
        [253.0, 231.0, 37.0],
    ];
    let t = if t.is_finite() {
        t.clamp(0.0, 1.0)
    } else {
        0.0
    } * (STOPS.len() - 1) as f64;
    let i = (t.floor() as usize).min(STOPS.len() - 2);
    let f = t - i as f64;
    let mut out = [0u8; 3];
    for (c, o) in out.iter_mut().enumerate() {
        *o = (STOPS[i][c] * (1.0 - f) + STOPS[i + 1][c] * f).round() as u8;
    }
    out
}

/// Colour-maps a height grid (rows along +y) into an RGB picture with +y up, NaN in grey.
pub fn height_preview(width: usize, height: usize, z: &[f32], lo: f64, hi: f64) -> Vec<u8> {
    let mut rgb = Vec::with_capacity(width * height * 3);
    let span = if hi > lo { hi - lo } else { 1.0 };
    for row in (0..height).rev() {
        for col in 0..width {
            let v = f64::from(z[row * width + col]);
            rgb.extend_from_slice(&if v.is_nan() {
                [128, 128, 128]
            } else {
                colormap((v - lo) / span)
            });
        }
    }
    rgb
}

/// A frame read from disk, in its own bit depth.
#[derive(Debug, Clone, PartialEq)]
pub enum FrameData {
    /// 8-bit grey.
    U8(Image<u8>),
    /// 16-bit grey.
    U16(Image<u16>),
}

impl stripe3d_core::spacetime::Frame for FrameData {
    fn width(&self) -> usize {
        self.size().0
    }
    fn height(&self) -> usize {
        self.size().1
    }
    fn value(&self, x: usize, y: usize) -> f32 {
        match self {
            FrameData::U8(img) => img.value(x, y),
            FrameData::U16(img) => img.value(x, y),
        }
    }
}

impl FrameData {
    /// Width and height.
    pub fn size(&self) -> (usize, usize) {
        match self {
            FrameData::U8(i) => (i.width(), i.height()),
            FrameData::U16(i) => (i.width(), i.height()),
        }
    }
}

/// One stripe point to draw on a [`points_picture`]: its scan line, its sub-pixel position along it, and whether
/// it is marked cut.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PointMark {
    /// Scan line (an image row, or a column when the scan lines run along columns).
    pub line: u32,
    /// Position along the scan line, pixels.
    pub x: f64,
    /// Marked cut (drawn orange instead of green).
    pub cut: bool,
}

/// A picture of a frame as the sensor sees it, with stripe points drawn on it: the grey values over the frame's
/// brightest, square-rooted (so that a dim stripe and the background show beside a saturated one), shrunk by an
/// integer factor (box average) until its longer side is at most `max_side`; each point one green pixel (orange
/// when cut). `rows_axis` false: the points' scan lines are columns. Returns width, height and RGB bytes.
pub fn points_picture(
    frame: &FrameData,
    points: &[PointMark],
    rows_axis: bool,
    max_side: usize,
) -> (usize, usize, Vec<u8>) {
    let (w, h) = frame.size();
    let value = |i: usize| -> u32 {
        match frame {
            FrameData::U8(img) => u32::from(img.data()[i]),
            FrameData::U16(img) => u32::from(img.data()[i]),
        }
    };
    let f = w.max(h).div_ceil(max_side.max(1)).max(1);
    let (pw, ph) = (w.div_ceil(f).max(1), h.div_ceil(f).max(1));
    let mut sum = vec![0u64; pw * ph];
    let mut count = vec![0u32; pw * ph];
    let mut top = 1u32;
    for y in 0..h {
        for x in 0..w {
            let v = value(y * w + x);
            top = top.max(v);
            let k = (y / f) * pw + x / f;
            sum[k] += u64::from(v);
            count[k] += 1;
        }
    }
    let mut rgb = Vec::with_capacity(pw * ph * 3);
    for (s, c) in sum.iter().zip(&count) {
        let mean = *s as f64 / f64::from((*c).max(1));
        let g = (255.0 * (mean / f64::from(top)).sqrt())
            .round()
            .clamp(0.0, 255.0) as u8;
        rgb.extend_from_slice(&[g, g, g]);
    }
    for p in points {
        let (x, y) = if rows_axis {
            (p.x, f64::from(p.line))
        } else {
            (f64::from(p.line), p.x)
        };
        if !(x.is_finite() && x >= -0.5 && y >= 0.0) {
            continue;
        }
        let (px, py) = ((x.round().max(0.0) as usize) / f, (y as usize) / f);
        if px < pw && py < ph {
            let k = 3 * (py * pw + px);
            rgb[k..k + 3].copy_from_slice(if p.cut { &[255, 140, 0] } else { &[0, 230, 0] });
        }
    }
    (pw, ph, rgb)
}

/// A frame read from disk: pixels widened to 16 bits and the bit depth of the file.
#[derive(Debug, Clone)]
pub struct LoadedFrame {
    /// The pixels.
    pub image: Image<u16>,
    /// 8 or 16.
    pub bits: u8,
}

/// What the sensor sees of a colour frame: one grey value per pixel from its red, green and blue values.
///
/// For a laser of one colour, the *colour excess* `C - (C1 + C2) / 2` of its channel `C` over the mean of the other
/// two, less its value at the frame's darkest thousandth (`excess_frame`), clamped at 0: white and grey light (ambient, printed texture, a white board) has equal channels and cancels,
/// while the laser, nearly monochromatic, stands out. A plain channel, a weighted sum (clamped to the channel's
/// range) and Rec. 601 luma are there for cameras whose filters mix the laser into several channels. A grey frame is
/// read as it is whatever is chosen.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub enum Laser {
    /// Colour frames: the colour excess (red, green or blue) highest over the frame's brightest thousandth of
    /// pixels — the laser is the most saturated light in a laser-line picture ([`AUTO_TOP_SHARE`]).
    #[default]
    Auto,
    /// `R - (G + B) / 2`, shifted.
    Red,
    /// `G - (R + B) / 2`, shifted.
    Green,
    /// `B - (R + G) / 2`, shifted.
    Blue,
    /// One channel as it is: 0 red, 1 green, 2 blue.
    Channel(usize),
    /// `clamp(wr R + wg G + wb B, 0, full scale)`.
    Weights([f64; 3]),
    /// Rec. 601 luma, `0.299 R + 0.587 G + 0.114 B`.
    Luma,
}

impl Laser {
    /// Parses `auto`, `red`, `green`, `blue`, `luma`, `r`, `g`, `b` (one channel) or `WR,WG,WB` (weights).
    pub fn parse(s: &str) -> Result<Laser, String> {
        let t = s.trim().to_ascii_lowercase();
        Ok(match t.as_str() {
            "auto" => Laser::Auto,
            "red" => Laser::Red,
            "green" => Laser::Green,
            "blue" => Laser::Blue,
            "luma" | "grey" | "gray" => Laser::Luma,
            "r" => Laser::Channel(0),
            "g" => Laser::Channel(1),
            "b" => Laser::Channel(2),
            _ => {
                let w: Vec<&str> = t.split(',').collect();
                let parsed: Vec<f64> = w
                    .iter()
                    .filter_map(|v| v.trim().parse::<f64>().ok())
                    .filter(|v| v.is_finite())
                    .collect();
                if w.len() != 3 || parsed.len() != 3 {
                    return Err(format!(
                        "`{s}`: give auto, red, green, blue, luma, one channel (r, g or b) or three weights \
                         WR,WG,WB (e.g. -0.5,1,-0.5)"
                    ));
                }
                Laser::Weights([parsed[0], parsed[1], parsed[2]])
            }
        })
    }

    /// The grey value of one pixel, `full` the channels' full scale.
    fn grey(self, [r, g, b]: [f64; 3], full: f64) -> f64 {
        let excess = |c: f64, o1: f64, o2: f64| (c - 0.5 * (o1 + o2)).max(0.0);
        match self {
            Laser::Red => excess(r, g, b),
            Laser::Green => excess(g, r, b),
            Laser::Blue => excess(b, r, g),
            Laser::Channel(c) => [r, g, b][c.min(2)],
            Laser::Weights([wr, wg, wb]) => (wr * r + wg * g + wb * b).clamp(0.0, full),
            Laser::Luma => 0.299 * r + 0.587 * g + 0.114 * b,
            Laser::Auto => excess(r, g, b),
        }
    }
}

/// Share of a frame's pixels [`Laser::Auto`] judges a colour by: its brightest thousandth.
pub const AUTO_TOP_SHARE: f64 = 0.001;

/// The colour [`Laser::Auto`] chooses: the one whose excess is highest over the brightest [`AUTO_TOP_SHARE`] of
/// the frame (a laser line is the most saturated light there is, on a few per cent of the pixels at most; a colour
/// cast of the light or the board is weak and everywhere, and a sum over the frame would choose it), the sums over
/// the frame breaking ties (a frame without colour).
fn auto_colour(rgb: &[[u16; 3]], full: f64) -> Laser {
    const COLOURS: [Laser; 3] = [Laser::Red, Laser::Green, Laser::Blue];
    let mut hist = vec![[0u32; 3]; full as usize + 1];
    let last = hist.len() - 1;
    let mut sums = [0f64; 3];
    for p in rgb {
        let c = p.map(f64::from);
        for (k, laser) in COLOURS.iter().enumerate() {
            let v = laser.grey(c, full);
            sums[k] += v;
            hist[(v as usize).min(last)][k] += 1;
        }
    }
    let top = ((rgb.len() as f64 * AUTO_TOP_SHARE).ceil() as u32).max(1);
    let mut level = [0usize; 3];
    for (k, l) in level.iter_mut().enumerate() {
        let mut seen = 0u32;
        for (v, h) in hist.iter().enumerate().rev() {
            seen += h[k];
            if seen >= top {
                *l = v;
                break;
            }
        }
    }
    let best = (0..3)
        .max_by(|&a, &b| level[a].cmp(&level[b]).then(sums[a].total_cmp(&sums[b])))
        .unwrap_or(0);
    COLOURS[best]
}

/// The grey frame a colour image gives for `laser` (8-bit channels stay 8-bit).
fn colour_to_grey(
    rgb: &[[u16; 3]],
    w: usize,
    h: usize,
    bits: u8,
    laser: Laser,
) -> Result<LoadedFrame, String> {
    let full = if bits == 8 { 255.0 } else { 65535.0 };
    let laser = match laser {
        Laser::Auto => auto_colour(rgb, full),
        other => other,
    };
    let (data, bits) = match laser {
        Laser::Red | Laser::Green | Laser::Blue => excess_frame(rgb, laser, full, bits),
        _ => (
            rgb.iter()
                .map(|p| laser.grey(p.map(f64::from), full).round().clamp(0.0, full) as u16)
                .collect(),
            bits,
        ),
    };
    Ok(LoadedFrame {
        image: Image::from_vec(w, h, data).map_err(|e| e.to_string())?,
        bits,
    })
}

/// Share of a frame's pixels that the colour excess puts at zero or below: its darkest thousandth.
pub const EXCESS_FLOOR_SHARE: f64 = 0.001;

/// The colour excess `C - (C1 + C2) / 2` of a frame, less its value at the darkest [`EXCESS_FLOOR_SHARE`] of the
/// frame (`m`, at most 0), then clamped at 0: the background's excess is mostly negative (grey light has none, and
/// the laser's colour is in no other light), and clipped at 0 it would be a frame of zeros with the odd positive
/// speck, whose median-based noise reads 0 and whose every speck stands many sigma tall. Shifted by `-m` the
/// background keeps its noise. 8-bit frames whose shifted excess passes 255 are held in 16 bits.
fn excess_frame(rgb: &[[u16; 3]], laser: Laser, full: f64, bits: u8) -> (Vec<u16>, u8) {
    let signed = |p: &[u16; 3]| -> f64 {
        let [r, g, b] = p.map(f64::from);
        match laser {
            Laser::Red => r - 0.5 * (g + b),
            Laser::Green => g - 0.5 * (r + b),
            _ => b - 0.5 * (r + g),
        }
    };
    // Histogram of the excess in half levels, offset by the full scale.
    let span = 4 * full as usize + 1;
    let mut hist = vec![0u32; span];
    for p in rgb {
        let k = ((signed(p) + full) * 2.0)
            .round()
            .clamp(0.0, (span - 1) as f64) as usize;
        hist[k] += 1;
    }
    let floor_count = ((rgb.len() as f64 * EXCESS_FLOOR_SHARE).ceil() as u32).max(1);
    let mut seen = 0u32;
    let mut floor = 0.0f64;
    for (k, h) in hist.iter().enumerate() {
        seen += h;
        if seen >= floor_count {
            floor = (k as f64 / 2.0 - full).min(0.0);
            break;
        }
    }
    let top = full - floor;
    let bits = if bits == 8 && top > 255.0 { 16 } else { bits };
    let data = rgb
        .iter()
        .map(|p| (signed(p) - floor).round().clamp(0.0, 65_535.0) as u16)
        .collect();
    (data, bits)
}

/// Reads a grey frame keeping its bit depth (8-bit frames stay 8-bit, which extraction scans fastest); a colour
/// frame is refused.
pub fn read_frame_native(path: &Path, max_pixels: usize) -> Result<FrameData, IoError> {
    read_frame_native_as(path, max_pixels, None)
}

/// [`read_frame_native`], colour frames (RGB, RGBA, 8 or 16 bits a channel; PNG, JPEG, TIFF) turned grey as `laser`
/// says; `None` refuses them.
pub fn read_frame_native_as(
    path: &Path,
    max_pixels: usize,
    laser: Option<Laser>,
) -> Result<FrameData, IoError> {
    let f = read_frame_limited(path, max_pixels, laser)?;
    let (w, h) = (f.image.width(), f.image.height());
    Ok(if f.bits == 8 {
        let data: Vec<u8> = f.image.data().iter().map(|&v| v as u8).collect();
        FrameData::U8(Image::from_vec(w, h, data).map_err(|e| IoError::Image {
            path: path.to_path_buf(),
            message: e.to_string(),
        })?)
    } else {
        FrameData::U16(f.image)
    })
}

/// Reads a grey frame (PNG 8/16-bit, PGM, TIFF). Colour images are refused: a stripe camera is monochrome and a
/// silent conversion would hide a wrong file.
pub fn read_frame(path: &Path) -> Result<LoadedFrame, IoError> {
    read_frame_limited(path, usize::MAX, None)
}

/// [`read_frame`], refusing an image of more than `max_pixels` pixels from its header, before anything is decoded
/// (a damaged or hostile header must not make us allocate gigabytes).
fn read_frame_limited(
    path: &Path,
    max_pixels: usize,
    laser: Option<Laser>,
) -> Result<LoadedFrame, IoError> {
    let bad = |message: String| IoError::Image {
        path: path.to_path_buf(),
        message,
    };
    // Opened twice: the header alone first, so that a hostile size is refused before anything is decoded.
    let open = || {
        let read = |source| IoError::Read {
            path: path.to_path_buf(),
            source,
        };
        image::ImageReader::open(path)
            .map_err(read)?
            .with_guessed_format()
            .map_err(read)
    };
    let (w, h) = crate::error::decode_guarded(path, || {
        open()?
            .into_dimensions()
            .map_err(|e| bad(format!("not a readable PNG, JPEG, PGM or TIFF image: {e}")))
    })?;
    if w == 0 || h == 0 || w > MAX_READ_SIDE || h > MAX_READ_SIDE {
        return Err(bad(format!(
            "{w}x{h} pixels: each side must be 1 to {MAX_READ_SIDE}"
        )));
    }
    if (w as usize).saturating_mul(h as usize) > max_pixels {
        return Err(bad(format!(
            "{w}x{h} pixels is more than the limit of {max_pixels}; raise it with --max-pixels"
        )));
    }
    let reader = open()?;
    let img = crate::error::decode_guarded(path, || {
        reader
            .decode()
            .map_err(|e| bad(format!("cannot decode (truncated or damaged?): {e}")))
    })?;
    let (w, h) = (img.width() as usize, img.height() as usize);
    if let Some(l) = laser.filter(|l| !matches!(l, Laser::Auto | Laser::Luma))
        && !img.color().has_color()
    {
        return Err(bad(format!(
            "is a grey image: --laser {l:?} names a colour channel it does not have (use auto or luma, or leave \
             --laser out)"
        )));
    }
    match img {
        image::DynamicImage::ImageLuma8(g) => Ok(LoadedFrame {
            image: Image::from_vec(w, h, g.into_raw().into_iter().map(u16::from).collect())
                .map_err(|e| bad(e.to_string()))?,
            bits: 8,
        }),
        image::DynamicImage::ImageLuma16(g) => Ok(LoadedFrame {
            image: Image::from_vec(w, h, g.into_raw()).map_err(|e| bad(e.to_string()))?,
            bits: 16,
        }),
        other if laser.is_some() && other.color().has_color() => {
            let laser = laser.unwrap_or_default();
            let deep = other.color().bytes_per_pixel() > 4;
            let rgb: Vec<[u16; 3]> = if deep {
                other
                    .into_rgb16()
                    .pixels()
                    .map(|p| [p.0[0], p.0[1], p.0[2]])
                    .collect()
            } else {
                other
                    .into_rgb8()
                    .pixels()
                    .map(|p| p.0.map(u16::from))
                    .collect()
            };
            colour_to_grey(&rgb, w, h, if deep { 16 } else { 8 }, laser).map_err(bad)
        }
        other => Err(bad(format!(
            "is a {:?} image; give --laser (red, green, blue, a channel or weights) to say what the sensor sees of a \
             colour frame, or convert it to grey",
            other.color()
        ))),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn png_round_trips_at_8_and_16_bits() {
        let dir = tempfile::tempdir().expect("tmp");
        let img = Image::from_vec(3, 2, vec![0u16, 1, 255, 7, 100, 200]).expect("img");
        let p8 = dir.path().join("a.png");
        write_grey_png(&p8, &img, 8).expect("write");
        let back = read_frame(&p8).expect("read");
        assert_eq!((back.bits, back.image.clone()), (8, img.clone()));
        let img16 = Image::from_vec(2, 2, vec![0u16, 1023, 4095, 65535]).expect("img");
        let p16 = dir.path().join("b.png");
        write_grey_png(&p16, &img16, 12).expect("write");
        let back = read_frame(&p16).expect("read");
        assert_eq!((back.bits, back.image), (16, img16));
    }

    #[test]
    fn bad_files_are_refused_with_their_name() {
        let dir = tempfile::tempdir().expect("tmp");
        let p = dir.path().join("junk.png");
        std::fs::write(&p, b"\x89PNG\r\n\x1a\nnot really").expect("write");
        let e = read_frame(&p).expect_err("junk");
        assert!(e.to_string().contains("junk.png"), "{e}");
        let e = read_frame(&dir.path().join("missing.png")).expect_err("missing");
        assert!(matches!(e, IoError::Read { .. }));
        let rgb = dir.path().join("rgb.png");
        write_rgb_png(&rgb, 1, 1, &[1, 2, 3]).expect("write");
        assert!(
            read_frame(&rgb)
                .expect_err("colour")
                .to_string()
                .contains("grey")
        );
    }

    #[test]
    fn a_points_picture_is_shrunk_to_its_limit_and_shows_every_point() {
        let img = Image::from_vec(10, 4, (0..40u16).map(|v| v * 100).collect()).expect("img");
        let frame = FrameData::U16(img);
        let points = [
            PointMark {
                line: 1,
                x: 2.4,
                cut: false,
            },
            PointMark {
                line: 3,
                x: 9.2,
                cut: true,
            },
            PointMark {
                line: 0,
                x: f64::NAN,
                cut: false,
            },
            PointMark {
                line: 99,
                x: 1.0,
                cut: false,
            },
        ];
        let (w, h, rgb) = points_picture(&frame, &points, true, 5);
        assert_eq!((w, h, rgb.len()), (5, 2, 30));
        // Row 1, x 2.4 -> picture (1, 0); row 3, x 9.2 -> (4, 1); the brightest pixel's box is the brightest grey.
        assert_eq!(&rgb[3..6], &[0, 230, 0]);
        assert_eq!(&rgb[3 * (5 + 4)..3 * (5 + 4) + 3], &[255, 140, 0]);
        assert!(rgb[3 * 5 + 3] > rgb[0], "brighter rows are brighter");
        // Along columns: the line is the column.
        let (_, _, cols) = points_picture(&frame, &points[..1], false, 100);
        assert_eq!(&cols[3 * (2 * 10 + 1)..3 * (2 * 10 + 1) + 3], &[0, 230, 0]);
    }

    /// A 200 x 100 colour frame: a greenish cast everywhere (with noise), and a red line one pixel wide at column
    /// 50 (0.5 % of the pixels).
    fn cast_and_line() -> Vec<[u16; 3]> {
        let mut rng = 3u32;
        let mut noise = || {
            rng = rng.wrapping_mul(1_664_525).wrapping_add(1_013_904_223);
            (rng >> 29) as u16
        };
        let mut rgb = Vec::new();
        for _y in 0..100 {
            for x in 0..200 {
                rgb.push(if x == 50 {
                    [250, 60, 60]
                } else {
                    [100 + noise(), 130 + noise(), 100 + noise()]
                });
            }
        }
        rgb
    }

    #[test]
    fn auto_takes_the_laser_line_not_the_colour_cast() {
        let rgb = cast_and_line();
        // Summed over the frame the cast's green excess (about 30 a pixel) outweighs the line's red one.
        assert_eq!(auto_colour(&rgb, 255.0), Laser::Red);
        let f = colour_to_grey(&rgb, 200, 100, 8, Laser::Auto).expect("grey");
        let row = &f.image.data()[..200];
        let peak = (0..200).max_by_key(|&x| row[x]).expect("peak");
        assert_eq!(peak, 50);
    }

    #[test]
    fn the_colour_excess_keeps_the_noise_of_the_background() {
        let rgb = cast_and_line();
        let f = colour_to_grey(&rgb, 200, 100, 8, Laser::Red).expect("grey");
        // The background's red excess is about -30: shifted, not clipped, its values still differ.
        let mut background: Vec<u16> = f
            .image
            .data()
            .iter()
            .enumerate()
            .filter(|(i, _)| i % 200 != 50)
            .map(|(_, &v)| v)
            .collect();
        background.sort_unstable();
        assert_eq!(background[0], 0, "the darkest pixels are at 0");
        let (lo, hi) = (
            background[background.len() / 4],
            background[3 * background.len() / 4],
        );
        assert!(hi > lo, "the background keeps its spread: {lo}..{hi}");
        // The line stands as far over the background as its excess over the background's.
        let line = f.image.data()[50];
        assert!(f64::from(line) - f64::from(background[background.len() / 2]) > 180.0);
        // A plain channel is read as it is.
        let g = colour_to_grey(&rgb, 200, 100, 8, Laser::Channel(1)).expect("grey");
        assert_eq!(g.image.data()[50], 60);
    }

    #[test]
    fn colormap_runs_dark_to_bright() {
        let lum = |c: [u8; 3]| u32::from(c[0]) + u32::from(c[1]) + u32::from(c[2]);
        assert!(lum(colormap(0.0)) < lum(colormap(0.5)) && lum(colormap(0.5)) < lum(colormap(1.0)));
        assert_eq!(colormap(f64::NAN), colormap(0.0));
    }

    #[test]
    fn the_pixel_limit_is_checked_before_decoding() {
        let dir = tempfile::tempdir().expect("tmp");
        let p = dir.path().join("big.png");
        write_grey_png(&p, &Image::<u16>::new(40, 30), 8).expect("write");
        let e = read_frame_native(&p, 1000).expect_err("over the limit");
        assert!(
            e.to_string().contains("40x30") && e.to_string().contains("--max-pixels"),
            "{e}"
        );
        assert!(read_frame_native(&p, 1200).is_ok());
        // A header that claims a huge image, over a few bytes of data: refused by its size, not decoded.
        let p = dir.path().join("liar.pgm");
        std::fs::write(&p, b"P5\n16383 16383\n255\n\x01\x02\x03").expect("write");
        let e = read_frame_native(&p, 64 << 20).expect_err("claims 268 M pixels");
        assert!(
            e.to_string().contains("16383x16383") && e.to_string().contains("liar.pgm"),
            "{e}"
        );
    }

    /// Small valid frames in every format read: 8- and 16-bit PNG, PGM, TIFF.
    fn valid_files() -> Vec<(&'static str, Vec<u8>)> {
        let mut out = Vec::new();
        let g8 = image::GrayImage::from_fn(9, 5, |x, y| image::Luma([(x * 20 + y * 7) as u8]));
        let g16 = image::ImageBuffer::<image::Luma<u16>, Vec<u16>>::from_fn(7, 6, |x, y| {
            image::Luma([(x * 3000 + y * 11) as u16])
        });
        for (ext, format) in [
            ("png", image::ImageFormat::Png),
            ("pgm", image::ImageFormat::Pnm),
            ("tif", image::ImageFormat::Tiff),
        ] {
            let mut b = std::io::Cursor::new(Vec::new());
            g8.write_to(&mut b, format).expect("encode 8-bit");
            out.push((ext, b.into_inner()));
        }
        let mut b = std::io::Cursor::new(Vec::new());
        g16.write_to(&mut b, image::ImageFormat::Png)
            .expect("encode 16-bit");
        out.push(("png", b.into_inner()));
        out
    }

    proptest::proptest! {
        #![proptest_config(proptest::prelude::ProptestConfig::with_cases(64))]

        #[test]
        fn damaged_frames_are_refused_or_read_never_panic(
            which in 0usize..4,
            flips in proptest::collection::vec((0usize..4096, proptest::prelude::any::<u8>()), 0..4),
            cut in proptest::option::of(0usize..4096),
        ) {
            let files = valid_files();
            let (ext, mut bytes) = files[which].clone();
            for (pos, byte) in flips {
                let k = pos % bytes.len();
                bytes[k] = byte;
            }
            if let Some(c) = cut {
                bytes.truncate(c % (bytes.len() + 1));
            }
            let dir = tempfile::tempdir().expect("tmp");
            let p = dir.path().join(format!("frame.{ext}"));
            std::fs::write(&p, &bytes).expect("write");
            match read_frame_native(&p, 1 << 20) {
                Ok(f) => {
                    let (w, h) = f.size();
                    proptest::prop_assert!(w > 0 && h > 0 && w * h <= 1 << 20);
                }
                Err(e) => proptest::prop_assert!(e.to_string().contains("frame."), "{}", e),
            }
        }

        #[test]
        fn random_bytes_are_refused_with_the_name(
            bytes in proptest::collection::vec(proptest::prelude::any::<u8>(), 0..200),
            ext in proptest::sample::select(vec!["png", "pgm", "tif", "bin"]),
        ) {
            let dir = tempfile::tempdir().expect("tmp");
            let p = dir.path().join(format!("noise.{ext}"));
            std::fs::write(&p, &bytes).expect("write");
            if let Err(e) = read_frame_native(&p, 1 << 20) {
                proptest::prop_assert!(e.to_string().contains("noise."), "{}", e);
            }
        }
    }
}
