//! Extraction on real photographs of laser lines on flat boards (`../shared/real/`, other people's cameras and
//! lasers, no ground truth). On a flat board each stripe is one smooth curve: the points of a board's region are
//! grouped into stripes (linked row to row within 3 px of a track's prediction, across gaps), each stripe gets a robust quadratic x(y) (fitted, points
//! more than 1 px off dropped, fitted again), and the figures are: completeness = rows of a stripe's span with a
//! point within 1 px of its curve, false = points of the region farther than 1.5 px from every curve, residual =
//! RMS distance of the points within 1.5 px. The number of stripes is not given: it is what the grouping finds.
//! Skipped with a message when `../shared/real/` is absent.

use std::path::PathBuf;
use stripe3d_core::extract::{ExtractParams, Extraction, Extractor, Method, Threshold};
use stripe3d_io::images::{FrameData, Laser, read_frame_native_as};

fn real_dir() -> Option<PathBuf> {
    let d = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../../shared/real");
    d.is_dir().then_some(d)
}

#[derive(Debug)]
struct Figures {
    stripes: usize,
    completeness: f64,
    false_rate: f64,
    residual_px: f64,
}

fn fit_quadratic(pts: &[(f64, f64)]) -> Option<[f64; 3]> {
    // Least squares of x = a + b y + c y^2, y centred for conditioning.
    let n = pts.len() as f64;
    if pts.len() < 3 {
        return None;
    }
    let ym = pts.iter().map(|p| p.0).sum::<f64>() / n;
    let mut m = nalgebra::Matrix3::<f64>::zeros();
    let mut v = nalgebra::Vector3::<f64>::zeros();
    for &(y, x) in pts {
        let t = y - ym;
        let row = nalgebra::Vector3::new(1.0, t, t * t);
        m += row * row.transpose();
        v += row * x;
    }
    let s = m.lu().solve(&v)?;
    Some([s[0], s[1], s[2]]).map(|c| {
        // Back to y: a + b (y - ym) + c (y - ym)^2.
        [
            c[0] - c[1] * ym + c[2] * ym * ym,
            c[1] - 2.0 * c[2] * ym,
            c[2],
        ]
    })
}

fn at(c: &[f64; 3], y: f64) -> f64 {
    c[0] + c[1] * y + c[2] * y * y
}

fn score(points: &[(u32, f64)], rows: (u32, u32), cols: (f64, f64)) -> Figures {
    let inside: Vec<(u32, f64)> = points
        .iter()
        .copied()
        .filter(|&(r, x)| r >= rows.0 && r <= rows.1 && x >= cols.0 && x <= cols.1)
        .collect();
    // Group row to row: each point joins the track whose prediction is nearest within 3 px, a track predicting by
    // the line through its last points (up to 20, at least 8 rows apart) across gaps of up to 100 rows (a line
    // lost on a dark square), else by its last point across gaps of up to 5 rows.
    let mut tracks: Vec<Vec<(f64, f64)>> = Vec::new();
    let predict = |t: &Vec<(f64, f64)>, y: f64| -> Option<f64> {
        let &(y1, x1) = t.last()?;
        let tail = &t[t.len().saturating_sub(20)..];
        let (y0, x0) = tail[0];
        if y1 - y0 >= 8.0 {
            (y - y1 <= 100.0).then(|| x1 + (x1 - x0) / (y1 - y0) * (y - y1))
        } else {
            (y - y1 <= 5.0).then_some(x1)
        }
    };
    for &(r, x) in &inside {
        let y = f64::from(r);
        let best = tracks
            .iter()
            .enumerate()
            .filter(|(_, t)| t.last().is_some_and(|l| l.0 < y))
            .filter_map(|(i, t)| predict(t, y).map(|p| (i, (p - x).abs())))
            .filter(|&(_, d)| d <= 3.0)
            .min_by(|a, b| a.1.total_cmp(&b.1))
            .map(|(i, _)| i);
        match best {
            Some(i) => tracks[i].push((y, x)),
            None => tracks.push(vec![(y, x)]),
        }
    }
    let span = f64::from(rows.1 - rows.0 + 1);
    let mut curves = Vec::new();
    for t in tracks.iter().filter(|t| t.len() as f64 >= 0.3 * span) {
        let Some(c) = fit_quadratic(t) else { continue };
        let kept: Vec<(f64, f64)> = t
            .iter()
            .copied()
            .filter(|&(y, x)| (at(&c, y) - x).abs() <= 1.0)
            .collect();
        if let Some(c) = fit_quadratic(&kept) {
            let (y0, y1) = kept
                .iter()
                .fold((f64::INFINITY, f64::NEG_INFINITY), |a, p| {
                    (a.0.min(p.0), a.1.max(p.0))
                });
            curves.push((c, y0, y1));
        }
    }
    let (mut rows_total, mut rows_hit) = (0usize, 0usize);
    for (c, y0, y1) in &curves {
        for r in (*y0 as u32)..=(*y1 as u32) {
            rows_total += 1;
            let y = f64::from(r);
            if inside
                .iter()
                .any(|&(pr, x)| pr == r && (at(c, y) - x).abs() <= 1.0)
            {
                rows_hit += 1;
            }
        }
    }
    let (mut false_points, mut sq, mut near) = (0usize, 0.0, 0usize);
    for &(r, x) in &inside {
        let d = curves
            .iter()
            .map(|(c, _, _)| (at(c, f64::from(r)) - x).abs())
            .fold(f64::INFINITY, f64::min);
        if d > 1.5 {
            false_points += 1;
        } else {
            sq += d * d;
            near += 1;
        }
    }
    Figures {
        stripes: curves.len(),
        completeness: rows_hit as f64 / rows_total.max(1) as f64,
        false_rate: false_points as f64 / inside.len().max(1) as f64,
        residual_px: (sq / near.max(1) as f64).sqrt(),
    }
}

fn extract(path: &std::path::Path) -> Vec<(u32, f64)> {
    let frame = read_frame_native_as(path, 64 << 20, Some(Laser::Auto)).expect("frame");
    // As `stripe3d extract` reads a photo: the local noise's threshold.
    let mut ex = Extractor::new(ExtractParams {
        method: Method::Steger,
        threshold: Threshold::Local,
        ..ExtractParams::default()
    })
    .expect("extractor");
    let mut out = Extraction::default();
    match &frame {
        FrameData::U8(i) => ex.extract_into(i.view(), &mut out),
        FrameData::U16(i) => ex.extract_into(i.view(), &mut out),
    }
    out.points.iter().map(|p| (p.row, p.x)).collect()
}

/// The boards' regions (rows, columns, full-resolution pixels) chosen by looking at each photo
/// (`stripe3d extract PHOTO --picture P.png`): the flat board lit by the lines, away from its edges; the ChArUco
/// board's two planes apart, its fold (rows 540-640) left out. Then what this build measures there, with a margin:
/// least completeness, most false points, largest residual (px). The targets (completeness >= 0.99, false <= 1 %,
/// residual <= 0.25 px) are not met yet (docs/extraction.md).
type Board = (&'static str, (u32, u32), (f64, f64), [f64; 3]);
const BOARDS: [Board; 5] = [
    (
        "image1.png",
        (460, 960),
        (940.0, 1440.0),
        [0.88, 0.12, 0.40],
    ),
    ("image5.png", (230, 500), (430.0, 730.0), [0.87, 0.05, 0.35]),
    ("1Left.png", (400, 800), (760.0, 1160.0), [0.87, 0.02, 0.40]),
    (
        "charuco_board_laser.png",
        (120, 540),
        (660.0, 1120.0),
        [0.35, 0.70, 1.10],
    ),
    (
        "charuco_board_laser.png",
        (640, 1120),
        (660.0, 1120.0),
        [0.60, 0.60, 1.00],
    ),
];

#[test]
fn flat_boards_give_one_smooth_curve_per_stripe() {
    let Some(dir) = real_dir() else {
        eprintln!("skipped: ../shared/real/ is not beside the checkout");
        return;
    };
    for (name, rows, cols, [completeness, false_rate, residual]) in BOARDS {
        let path = dir.join(name);
        if !path.is_file() {
            eprintln!("skipped {name}: not in {}", dir.display());
            continue;
        }
        let f = score(&extract(&path), rows, cols);
        eprintln!("{name} rows {rows:?} columns {cols:?}: {f:?}");
        assert!(f.stripes >= 1, "{name}: no stripe found: {f:?}");
        assert!(f.completeness >= completeness, "{name}: {f:?}");
        assert!(f.false_rate <= false_rate, "{name}: {f:?}");
        assert!(f.residual_px <= residual, "{name}: {f:?}");
    }
}
