//! Single-core time per 648x480 frame with 11 stripes for every estimator.
//! Run with `cargo bench -p stripe3d-core`. The frame is synthetic (no simulator dependency in core): 11 Gaussian
//! stripes of sigma 1.5 px on a noisy background, bending slightly along the rows.

use stripe3d_core::Image;
use stripe3d_core::extract::{ExtractParams, Extraction, Extractor, Method};

fn main() {
    divan::main();
}

fn frame() -> Image<u8> {
    let (w, h) = (648usize, 480usize);
    let mut img = Image::<u8>::new(w, h);
    let mut rng = 0x2545_f491u32;
    for y in 0..h {
        for x in 0..w {
            rng ^= rng << 13;
            rng ^= rng >> 17;
            rng ^= rng << 5;
            let mut v = 6.0 + f64::from(rng % 5);
            for s in 0..11 {
                let c = 92.0 + 46.3 * s as f64 + 3.0 * ((y as f64) / 120.0).sin();
                v += 150.0 * (-0.5 * ((x as f64 - c) / 1.5).powi(2)).exp();
            }
            img.data_mut()[y * w + x] = v.min(255.0) as u8;
        }
    }
    img
}

/// Times `params` on the synthetic frame.
fn bench_params(bencher: divan::Bencher, params: ExtractParams) {
    let img = frame();
    let mut ex = Extractor::new(params).expect("extractor");
    let mut out = Extraction::default();
    bencher.bench_local(|| {
        ex.extract_into(img.view(), &mut out);
        divan::black_box(out.points.len())
    });
}

#[divan::bench(args = ["com3", "com-roi", "linear", "parabolic", "gaussian", "blais-rioux4", "blais-rioux8", "steger", "steger2d", "fuzzy"])]
fn per_frame(bencher: divan::Bencher, method: &str) {
    let params = ExtractParams {
        method: Method::from_name(method).expect("method"),
        ..ExtractParams::default()
    };
    bench_params(bencher, params);
}

/// The cost of marking cut stripes ([`ExtractParams::cut_asymmetry`], on by default): the same frame with the
/// marking off.
#[divan::bench(args = ["linear", "steger"])]
fn per_frame_unmarked(bencher: divan::Bencher, method: &str) {
    let params = ExtractParams {
        method: Method::from_name(method).expect("method"),
        cut_asymmetry: f64::INFINITY,
        ..ExtractParams::default()
    };
    bench_params(bencher, params);
}

/// Dominant peaks and their regions of interest alone (no estimator, no marking), at a fixed threshold of 16 grey
/// levels: the part of a frame's time every estimator shares.
#[divan::bench]
fn dominant_peaks_only(bencher: divan::Bencher) {
    let img = frame();
    let mut peaks = Vec::new();
    bencher.bench_local(|| {
        let mut n = 0;
        for y in 0..img.height() {
            stripe3d_core::extract::peaks::dominant_peaks(img.view().row(y), 16, &mut peaks);
            n += peaks.len();
        }
        divan::black_box(n)
    });
}
