//! Property tests of extraction over random scan lines: no panics, and every reported centre lies inside the
//! region of interest of a dominant peak on its line.

use proptest::prelude::*;
use stripe3d_core::Image;
use stripe3d_core::extract::peaks::dominant_peaks;
use stripe3d_core::extract::{Axis, ExtractParams, Method, Policy, Threshold, extract};

fn line_strategy() -> impl Strategy<Value = Vec<u16>> {
    prop_oneof![
        prop::collection::vec(any::<u16>(), 0..80),
        prop::collection::vec(0u16..40, 0..200),
        // stripes on noise
        (
            prop::collection::vec(0u16..20, 60..200),
            prop::collection::vec((0usize..200, 30u16..4000, 1usize..8), 0..6)
        )
            .prop_map(|(mut l, stripes)| {
                let n = l.len();
                for (c, a, w) in stripes {
                    for d in 0..w {
                        if c + d < n {
                            l[c + d] = l[c + d].saturating_add(a / (1 + d as u16));
                        }
                        if c >= d && c - d < n {
                            l[c - d] = l[c - d].saturating_add(a / (1 + d as u16));
                        }
                    }
                }
                l
            }),
    ]
}

proptest! {
    #![proptest_config(ProptestConfig { cases: std::env::var("PROPTEST_CASES").ok().and_then(|v| v.parse().ok()).unwrap_or(300), ..ProptestConfig::default() })]

    #[test]
    fn every_point_lies_in_a_dominant_peaks_roi(line in line_strategy(), rows in 1usize..4, m in 0usize..12, fixed in prop::option::of(0.0f64..300.0)) {
        let w = line.len();
        let mut data = Vec::with_capacity(w * rows);
        for _ in 0..rows {
            data.extend_from_slice(&line);
        }
        let img = Image::<u16>::from_vec(w, rows, data).expect("image");
        let method = Method::ALL[m];
        let params = ExtractParams { method, threshold: fixed.map_or(Threshold::Auto, Threshold::Fixed), ..ExtractParams::default() };
        let got = extract(img.view(), &params).expect("extract");
        let mut peaks = Vec::new();
        dominant_peaks(&line, got.threshold.round() as u32, &mut peaks);
        for p in &got.points {
            prop_assert!(p.x.is_finite());
            prop_assert!((p.row as usize) < rows);
            if method != Method::Com {
                prop_assert!(peaks.iter().any(|k| p.x >= k.roi_left as f64 && p.x <= k.roi_right as f64),
                    "x {} outside every ROI {:?}", p.x, peaks);
            } else {
                prop_assert!(p.x >= 0.0 && p.x <= (w.max(1) - 1) as f64);
            }
        }
    }

    #[test]
    fn any_image_any_options_never_panics(w in 0usize..40, h in 0usize..12, seed in any::<u64>(), axis in 0..2, policy in 0usize..5, m in 0usize..12) {
        let mut x = seed | 1;
        let data: Vec<u8> = (0..w * h).map(|_| { x ^= x << 13; x ^= x >> 7; x ^= x << 17; (x >> 56) as u8 }).collect();
        let img = Image::<u8>::from_vec(w, h, data).expect("image");
        let params = ExtractParams {
            method: Method::ALL[m],
            axis: if axis == 0 { Axis::Rows } else { Axis::Columns },
            policy: [Policy::All, Policy::Brightest, Policy::First, Policy::Last, Policy::Continuity][policy],
            ..ExtractParams::default()
        };
        let got = extract(img.view(), &params).expect("extract");
        prop_assert!(got.points.windows(2).all(|p| (p[0].row, p[0].x) <= (p[1].row, p[1].x) || p[0].row < p[1].row));
    }
}
