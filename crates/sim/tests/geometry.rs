//! Ground-truth tests of the simulator against closed-form geometry.

use stripe3d_core::Sensor;
use stripe3d_sim::scene::{Feature, Plate};
use stripe3d_sim::{RenderOptions, Scene, Simulator};

fn plate_scene(thickness: f64, length: f64, width: f64, grid: f64) -> Scene {
    let mut s = Scene::flat_plate();
    s.grid_mm = grid;
    s.plate = Some(Plate {
        center_x_mm: 0.0,
        center_y_mm: 0.0,
        length_mm: length,
        width_mm: width,
        thickness_mm: thickness,
        chamfer_mm: 0.0,
        albedo: 0.6,
    });
    s
}

#[test]
fn flat_plate_puts_each_stripe_where_pinhole_and_plane_geometry_predict() {
    let sensor = Sensor::default();
    let z = 12.5;
    // The plate covers the whole view, so every row of every stripe sees it.
    let scene = plate_scene(z, 200.0, 160.0, 0.5);
    let sim = Simulator::new(&sensor, &scene, RenderOptions::ideal()).expect("sim");
    let frame = sim.render(0, 0.0);
    let (c, l) = (&sensor.camera, &sensor.laser);
    let mut worst: f64 = 0.0;
    for i in 0..l.stripes {
        let x = l.sheet_x_mm(i, z);
        let u_expected = c.cx + c.fx * x / (c.height_mm - z);
        let pts: Vec<_> = frame
            .truth
            .iter()
            .filter(|p| p.stripe as usize == i)
            .collect();
        assert_eq!(
            pts.len(),
            c.height as usize,
            "stripe {i}: one point per row"
        );
        for p in pts {
            worst = worst.max((p.u - u_expected).abs());
            assert!((p.world[2] - z).abs() < 1e-9);
        }
    }
    assert!(worst < 1e-3, "worst column error {worst} px");
}

#[test]
fn distorted_camera_truth_projects_back_onto_its_pixel_and_plane() {
    let mut sensor = Sensor::default();
    sensor.camera.k1 = -0.1;
    let scene = plate_scene(5.0, 200.0, 160.0, 0.5);
    let sim = Simulator::new(&sensor, &scene, RenderOptions::ideal()).expect("sim");
    let frame = sim.render(0, 0.0);
    assert!(frame.truth.len() > 5000);
    let planes = sensor.laser.planes();
    for p in &frame.truth {
        let w = nalgebra::Vector3::new(p.world[0], p.world[1], p.world[2]);
        let (u, v) = sensor.camera.project(&w).expect("in front");
        assert!(
            (u - p.u).abs() < 1e-6 && (v - f64::from(p.row)).abs() < 1e-6,
            "{u},{v} vs {},{}",
            p.u,
            p.row
        );
        assert!(planes[p.stripe as usize].signed_distance(&w).abs() < 1e-6);
        assert!((p.world[2] - 5.0).abs() < 1e-9);
    }
}

#[test]
fn shadowed_rows_carry_no_ground_truth() {
    let sensor = Sensor::default();
    // A 30 mm block: stripe 8 meets the belt at x = 30 mm, beyond the block, so where the block stands in its
    // way (|y| < 20) the belt under it is in shadow and the stripe lies on the block's top instead.
    let scene = plate_scene(30.0, 40.0, 40.0, 0.1);
    let sim = Simulator::new(&sensor, &scene, RenderOptions::ideal()).expect("sim");
    let frame = sim.render(0, 0.0);
    let stripe = 8;
    assert!((sensor.laser.belt_x_mm(stripe) - 30.0).abs() < 1e-9);
    let on_belt: Vec<_> = frame
        .truth
        .iter()
        .filter(|p| p.stripe == stripe as u32 && p.world[2] < 1.0)
        .collect();
    let on_top: Vec<_> = frame
        .truth
        .iter()
        .filter(|p| p.stripe == stripe as u32 && p.world[2] > 29.0)
        .collect();
    assert!(
        on_belt.iter().all(|p| p.world[1].abs() > 19.9),
        "belt points inside the shadow"
    );
    assert!(
        on_belt.len() > 100,
        "the stripe is seen on the belt beside the block"
    );
    assert!(on_top.len() > 100, "the stripe is seen on the block's top");
    // The image agrees: where the stripe would be on the belt in a shadowed row, the belt is dark.
    let c = &sensor.camera;
    let u_belt = (c.cx + c.fx * 30.0 / c.height_mm).round() as usize;
    let row = c.cy.round() as usize;
    assert_eq!(frame.image.get(u_belt, row), Some(0));
    // 35 mm aside the source's rays pass clear of the block.
    let row_outside = (c.cy + c.fy * 35.0 / c.height_mm).round() as usize;
    // Dark rubber (albedo 0.25) lit at about 50 degrees: well above the shadow's zero, though no brighter.
    assert!(frame.image.get(u_belt, row_outside).expect("in view") > 30);
}

#[test]
fn a_through_hole_shows_the_stripe_on_the_belt() {
    let sensor = Sensor::default();
    let mut scene = plate_scene(3.0, 100.0, 80.0, 0.05);
    scene.features.push(Feature::Hole {
        x_mm: 0.0,
        y_mm: 0.0,
        diameter_mm: 16.0,
        designed: false,
    });
    let sim = Simulator::new(&sensor, &scene, RenderOptions::ideal()).expect("sim");
    let frame = sim.render(0, 0.0);
    let middle = 5; // meets the belt at x = 0, the hole's centre
    let in_hole: Vec<_> = frame
        .truth
        .iter()
        .filter(|p| p.stripe == middle && p.world[2].abs() < 1e-9 && p.world[1].abs() < 6.0)
        .collect();
    assert!(
        in_hole.len() > 40,
        "{} belt points seen through the hole",
        in_hole.len()
    );
    for p in &in_hole {
        let v = frame
            .image
            .get(p.u.round() as usize, p.row as usize)
            .expect("in view");
        assert!(v > 20, "stripe on the belt is bright: {v}");
    }
}

#[test]
fn noise_free_unblurred_truth_agrees_with_the_intensity_centroid() {
    let mut sensor = Sensor::default();
    sensor.camera.bits = 16;
    let scene = plate_scene(8.0, 200.0, 160.0, 0.5);
    let sim = Simulator::new(&sensor, &scene, RenderOptions::ideal()).expect("sim");
    let frame = sim.render(0, 0.0);
    let img = &frame.image;
    let mut worst: f64 = 0.0;
    for p in frame.truth.iter().filter(|p| p.row % 7 == 0) {
        let (mut s, mut sx) = (0.0, 0.0);
        let centre = p.u.round() as i64;
        for x in centre - 8..=centre + 8 {
            let v = f64::from(img.get(x as usize, p.row as usize).unwrap_or(0));
            s += v;
            sx += v * x as f64;
        }
        worst = worst.max((sx / s - p.u).abs());
    }
    assert!(worst < 0.01, "worst centroid disagreement {worst} px");
}

#[test]
fn frames_are_deterministic_and_the_part_moves_along_plus_x() {
    let sensor = Sensor::default();
    let sim = Simulator::new(&sensor, &Scene::demo(), RenderOptions::default()).expect("sim");
    let a = sim.render(3, 1.5);
    let b = sim.render(3, 1.5);
    assert_eq!(a.image, b.image);
    assert_eq!(a.truth, b.truth);
    let c = sim.render(3, 11.5);
    // Part coordinates of the truth stay on the part: world x minus travel.
    for p in &c.truth {
        assert!((p.world[0] - p.part[0] - 11.5).abs() < 1e-12);
        let h = sim.height_field().height_at(p.part[0], p.part[1]);
        assert!(
            (h - p.world[2]).abs() < 1e-6,
            "truth lies on the true surface"
        );
    }
}

#[test]
fn oversized_cameras_are_refused_not_allocated() {
    let mut sensor = Sensor::default();
    sensor.camera.width = 16_000;
    sensor.camera.height = 16_000;
    sensor.camera.cx = 7999.5;
    sensor.camera.cy = 7999.5;
    let err = Simulator::new(&sensor, &Scene::empty_belt(), RenderOptions::ideal())
        .expect_err("too large");
    assert!(err.to_string().contains("camera.width"), "{err}");
}

#[test]
fn truth_points_triangulate_back_to_their_world_points_with_the_true_planes() {
    use stripe3d_core::triangulate::{FullModel, Plane};
    let mut sensor = Sensor::default();
    sensor.camera.k1 = -0.05;
    let sim = Simulator::new(&sensor, &Scene::demo(), RenderOptions::ideal()).expect("sim");
    let frame = sim.render(3, 1.5);
    let planes = sensor
        .laser
        .planes()
        .iter()
        .map(|p| Plane::through(&p.source, &p.normal))
        .collect();
    let model = FullModel {
        camera: sensor.camera.clone(),
        planes,
    };
    assert!(frame.truth.len() > 4000);
    for t in &frame.truth {
        let p = model
            .point(t.stripe as usize, t.u, f64::from(t.row))
            .expect("ray meets its sheet");
        let err =
            ((p.x - t.world[0]).powi(2) + (p.y - t.world[1]).powi(2) + (p.z - t.world[2]).powi(2))
                .sqrt();
        assert!(err < 1e-6, "stripe {} row {}: {err} mm", t.stripe, t.row);
    }
}
