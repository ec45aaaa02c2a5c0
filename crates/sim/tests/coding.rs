//! Stripe coding measured against the simulator's ground truth: every coded point whose column lies within 0.5 px
//! of a truth point of its row is checked against that point's stripe.

use stripe3d_core::code::{Coding, CodingParams, CodingStats, StripeCoder};
use stripe3d_core::extract::{ExtractParams, Extraction, Extractor, Method};
use stripe3d_core::triangulate::FullModel;
use stripe3d_core::{Image, Sensor};
use stripe3d_sim::evaluate::TruthRows;
use stripe3d_sim::{Frame, RenderOptions, Scene, Simulator};

/// What coding did on a set of frames, against the truth.
#[derive(Debug, Default)]
struct Tally {
    stats: CodingStats,
    /// Coded points matched to a truth point.
    matched: usize,
    /// Of those, with the truth's stripe.
    right: usize,
    /// Coded points with no truth point within 0.5 px (extraction's false points that got an index).
    unmatched: usize,
    /// Truth points.
    truth: usize,
}

impl Tally {
    fn wrong(&self) -> usize {
        self.matched - self.right
    }
    fn right_rate(&self) -> f64 {
        self.right as f64 / self.matched.max(1) as f64
    }
    fn coverage(&self) -> f64 {
        self.right as f64 / self.truth.max(1) as f64
    }
}

/// A coder on the nominal sensor model and a Steger extractor.
fn coder_and_extractor(sensor: &Sensor, params: CodingParams) -> (StripeCoder, Extractor) {
    let model = FullModel::nominal(sensor);
    let coder =
        StripeCoder::new(&model, sensor.camera.width, sensor.camera.height, params).expect("coder");
    let ex = Extractor::new(ExtractParams {
        method: Method::Steger,
        ..ExtractParams::default()
    })
    .expect("extractor");
    (coder, ex)
}

/// A rendered frame as the 8-bit image a camera would give.
fn eight_bit(f: &Frame) -> Image<u8> {
    let data: Vec<u8> = f.image.data().iter().map(|&v| v.min(255) as u8).collect();
    Image::from_vec(f.image.width(), f.image.height(), data).expect("image")
}

fn tally(sensor: &Sensor, frames: &[Frame], params: CodingParams) -> Tally {
    let (mut coder, mut ex) = coder_and_extractor(sensor, params);
    let mut extraction = Extraction::default();
    let mut coding = Coding::default();
    let mut t = Tally::default();
    for f in frames {
        ex.extract_into(eight_bit(f).view(), &mut extraction);
        coder.code_into(&extraction.points, &mut coding);
        t.stats.add(&coding.stats);
        t.truth += f.truth.len();
        let rows = TruthRows::new(&f.truth);
        for (p, s) in extraction.points.iter().zip(&coding.stripes) {
            let Some(s) = s else { continue };
            let truth = rows.stripe_of(p);
            match truth {
                Some(q) => {
                    t.matched += 1;
                    if q == u32::from(*s) {
                        t.right += 1;
                    }
                }
                None => t.unmatched += 1,
            }
        }
    }
    t
}

fn render(sensor: &Sensor, scene: &Scene, frames: usize, step_mm: f64) -> Vec<Frame> {
    let sim = Simulator::new(sensor, scene, RenderOptions::default()).expect("sim");
    (0..frames)
        .map(|k| sim.render(k, k as f64 * step_mm))
        .collect()
}

#[test]
fn flat_plates_are_coded_without_a_single_wrong_index() {
    let sensor = Sensor::default();
    let mut frames = Vec::new();
    for (k, z) in [0.0, 4.0, 11.0, 23.0].iter().enumerate() {
        let scene = if *z == 0.0 {
            Scene::empty_belt()
        } else {
            Scene::covering_plate(*z)
        };
        let sim = Simulator::new(&sensor, &scene, RenderOptions::default()).expect("sim");
        frames.push(sim.render(k, 0.0));
    }
    let t = tally(&sensor, &frames, CodingParams::default());
    eprintln!("flat: {t:?}");
    assert_eq!(t.wrong(), 0, "{t:?}");
    assert!(t.coverage() > 0.99, "{t:?}");
}

#[test]
fn the_demo_part_with_holes_shadows_and_ghosts_is_coded() {
    let sensor = Sensor::default();
    let frames = render(&sensor, &Scene::demo(), 4, 2.5);
    let t = tally(&sensor, &frames, CodingParams::default());
    eprintln!(
        "demo: {t:?} right {:.5} coverage {:.4}",
        t.right_rate(),
        t.coverage()
    );
    // The target: >= 99.9 % right. Stripes whose sheet just misses a corner light it with their beam's
    // tail; those fragments run the whole length of the plate's edge, and the row labelling read them as one more
    // stripe (80.4% right) until extraction marked cut profiles and coding let dim ones follow a stripe but not
    // start one (93.3%). A step whose neighbouring stripes are hidden read as well one stripe over, until the rows
    // preferred a level surface (`CodingParams::tilt_cost_per_mm`) and alike neighbours on the belt:
    // 99.995% right, 94.7% of the points coded (was 70.2%).
    assert!(t.right_rate() >= 0.999, "{t:?}");
    assert!(t.coverage() >= 0.9, "{t:?}");
}

#[test]
fn a_tall_block_that_hides_four_stripes_is_coded() {
    let sensor = Sensor::default();
    let frames = render(&sensor, &Scene::block(), 3, 3.0);
    let t = tally(&sensor, &frames, CodingParams::default());
    eprintln!(
        "block: {t:?} right {:.5} coverage {:.4}",
        t.right_rate(),
        t.coverage()
    );
    assert!(t.right_rate() >= 0.999, "{t:?}");
    // 87.6% coded (72% before the rows preferred a level surface and compared the belt's neighbouring stripes'
    // brightness: the belt's stripe 3 lies on the column of the block's stripe 7, and the rows were ambiguous).
    assert!(t.coverage() >= 0.85, "{t:?}");
}

/// Temporal reconciliation on 22 consecutive frames (0.5 mm apart) of a plate with four defects, one a hole that
/// makes the coder drop other stripes' points in its rows: the points it recovers are right, or the tail of the sheet
/// they are labelled with.
#[test]
fn temporal_reconciliation_recovers_dropped_points_right() {
    use stripe3d_core::code::{CodedFrame, TemporalParams, reconcile};
    let sensor = Sensor::default();
    let frames = render(&sensor, &Scene::defect_plate(19, 4), 22, 0.5);
    let (mut coder, mut ex) = coder_and_extractor(&sensor, CodingParams::default());
    let mut extraction = Extraction::default();
    let mut coded = Vec::new();
    for f in &frames {
        ex.extract_into(eight_bit(f).view(), &mut extraction);
        let mut c = CodedFrame::default();
        coder.code_into(&extraction.points, &mut c.coding);
        c.points = extraction.points.clone();
        coded.push(c);
    }
    let before: Vec<Vec<Option<u16>>> = coded.iter().map(|c| c.coding.stripes.clone()).collect();
    let recovered = reconcile(&mut coded, &TemporalParams::default());
    let (mut right, mut wrong, mut untrue, mut relabelled, mut dropped) = (0, 0, 0, 0, 0);
    for ((c, f), b) in coded.iter().zip(&frames).zip(&before) {
        let rows = TruthRows::new(&f.truth);
        for ((p, s), was) in c.points.iter().zip(&c.coding.stripes).zip(b) {
            match (s, was) {
                (Some(s), None) => match rows.stripe_of(p) {
                    Some(q) if q == u32::from(*s) => right += 1,
                    Some(_) => wrong += 1,
                    None => untrue += 1,
                },
                (None, Some(_)) => dropped += 1,
                (Some(s), Some(w)) if s != w => relabelled += 1,
                _ => {}
            }
        }
    }
    eprintln!(
        "reconciled: {recovered} changed: recovered {right} right, {wrong} wrong, {untrue} without truth; \
         {relabelled} relabelled, {dropped} dropped"
    );
    // Measured: 385 changed: 342 recovered right, 4 wrong, 39 without a truth point within 0.5 px.
    // Those 39 are mostly the tail of stripe 9's sheet lighting the hole's rim (rows the sheet otherwise falls into the
    // hole): their track never settled, the row's order leaves them stripe 9 alone, and 9 is the sheet that lit
    // them, but their column is 1-4 px from the sheet's centre. (76 changed, 74 right before such unopposed points
    // were recovered; 527 before segments kept the label of their last settled point across rows read one stripe
    // over without confidence.)
    // Wrong: 4, all on row 85, the plate's front edge, where the belt's stripe 7 and the top's stripe 8 meet within
    // a pixel and one track runs over both (the junction `docs/extraction.md` calls a blend): the point the edge's
    // scan line gives is the belt's, its track the top's. The scan's coding as a whole is not worse for it (`stripe3d
    // bench coding --defect-plate 19`: 44 wrong of 106,809 after reconciliation, as without the partial-row line
    // ends that make the track). 4 of 342 is 1.2 %; more than 2 % of the right ones is a fault of reconciliation.
    assert!(recovered >= 40, "{recovered}");
    assert!(50 * wrong <= right, "{wrong} wrong, {right} right");
    assert!(right >= 60, "{right}");
    assert!(
        untrue <= right,
        "{untrue} recovered points off every truth point"
    );
}

/// A 10 mm plate lying on the belt moves its stripes by almost exactly one pitch: near its edges a row can read the
/// whole plate one stripe over with confidence. The segments running down the plate drop those readings; the point
/// whose plate column is its neighbour's belt column reads as belt and must not keep that wrong label, and the belt's
/// stripes on the plate's first and last rows must not join the plate's segments.
#[test]
fn a_plate_on_the_belt_read_one_stripe_over_near_its_edges_keeps_no_wrong_index() {
    let sensor = Sensor::default();
    let frames = render(&sensor, &Scene::flat_plate(), 2, 0.5);
    let t = tally(&sensor, &frames, CodingParams::default());
    eprintln!("plate on the belt: {t:?} right {:.5}", t.right_rate());
    // 24 without the overruled points' order; 6 with it, on the plate's chamfer rows, whose stripes lie between
    // the belt's and the plate's columns; 3 when a segment does not take on a point half as bright as its last
    // (the last chamfer row), 0 when it does not take on one twice as bright either (the first chamfer row,
    // `CodingParams::link_intensity_ratio`).
    // 4 with the extraction's sum along three scan lines: on the plate's first and last rows it blends the belt's
    // and the plate's stripe into one point between their columns, which the coder reads one stripe over.
    assert!(t.wrong() <= 4, "{t:?}");
    assert!(t.coverage() > 0.97, "{t:?}");
}
