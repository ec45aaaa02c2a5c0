//! Renderer throughput: one 648x480 11-stripe frame of the demo scene on one core.
//! Run with `cargo bench -p stripe3d-sim`.

use stripe3d_core::Sensor;
use stripe3d_sim::{RenderOptions, Scene, Simulator};

fn main() {
    divan::main();
}

#[divan::bench(sample_count = 20)]
fn demo_frame_full_physics(bencher: divan::Bencher) {
    let sim =
        Simulator::new(&Sensor::default(), &Scene::demo(), RenderOptions::default()).expect("sim");
    bencher.bench_local(|| divan::black_box(sim.render(5, 2.5)));
}

#[divan::bench(sample_count = 20)]
fn flat_plate_frame_ideal(bencher: divan::Bencher) {
    let sim = Simulator::new(
        &Sensor::default(),
        &Scene::flat_plate(),
        RenderOptions::ideal(),
    )
    .expect("sim");
    bencher.bench_local(|| divan::black_box(sim.render(0, 0.0)));
}
