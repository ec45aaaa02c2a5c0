//! Random scenes drawn over what production lines show, for the robustness bench (`stripe3d bench robustness`).
//!
//! A scene seed fixes every draw, so a bad scene is reproduced by its seed alone. Each draw is independent and
//! uniform over its range (log-uniform where the range spans a factor of ten or more):
//!
//! | quantity | range | |
//! |---|---|---|
//! | belt reflectance | 0.03-0.5, log-uniform | black rubber to grey PVC |
//! | part reflectance | 0.1-0.95 | the brightest of its printed cells |
//! | printed texture | half the parts: square cells of 0.5-5 mm (log-uniform), contrast 1:1 to 4:1 | |
//! | part | nine in ten scenes a plate of 20-100 x 20-100 mm, 0.5-30 mm high, centre within 20 mm of the view's, chamfer 0-1 mm (at most half its height); else the empty belt | |
//! | stripes | 1-31, spread over 100 mm of belt (pitch at most 10 mm) | |
//! | beam | sigma 0.1-0.5 mm across the sheet | |
//! | optics | point-spread sigma 0.3-1.5 px, radial distortion k1 -0.05 to +0.05, vignetting in half the scenes | |
//! | camera | 8, 10, 12 or 16 bits; read noise 0.1-1.2 % of full scale, log-uniform (0.25-3 levels at 8 bits) | |
//! | ambient light | 0-0.3 of a stripe's centre irradiance | |
//! | speckle | contrast 0-0.4 | |
//! | exposure | the dimmer surface's stripes peak at 8-128 levels of an 8-bit scale (log-uniform); the brighter one, up to 30 times that, saturates where it must | |
//! | conveyor | 10 mm/s at a frame step of 0.1-0.5 mm (log-uniform): scans of 20 frames (`stripe3d bench scans`) | |
//!
//! The exposure is set from the scene itself: a noise-free render (blur and vignetting on, no ambient light) gives
//! each true stripe point's peak, the medians over belt points and over part points give each surface's level, and
//! the camera's exposure is scaled so that the dimmer of the two reaches the drawn level. The exposure is then held
//! where the brightest surface's ambient light stays below [`AMBIENT_HEADROOM`] of full scale: a sensor on a line
//! is set up so that stripes rise over the ambient light, and where the background itself saturates no stripe can
//! be measured (such a draw lowers the exposure, so its dim stripes peak below the drawn level).

use crate::SimError;
use crate::render::{EdgeMap, Frame, RenderOptions, Simulator};
use crate::scene::{Belt, Feature, Lighting, Plate, Scene};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use stripe3d_core::Sensor;

/// Belt reflectance range (log-uniform).
pub const BELT_ALBEDO: (f64, f64) = (0.03, 0.5);
/// Part reflectance range.
pub const PART_ALBEDO: (f64, f64) = (0.1, 0.95);
/// Printed cell side, mm (log-uniform).
pub const TEXTURE_CELL_MM: (f64, f64) = (0.5, 5.0);
/// Largest brightest-to-darkest ratio of printed cells.
pub const TEXTURE_CONTRAST: f64 = 4.0;
/// Part height range, mm.
pub const PART_HEIGHT_MM: (f64, f64) = (0.5, 30.0);
/// Stripe count range.
pub const STRIPES: (usize, usize) = (1, 31);
/// Belt width the stripes are spread over, mm.
pub const STRIPE_SPAN_MM: f64 = 100.0;
/// Beam sigma range, mm.
pub const BEAM_SIGMA_MM: (f64, f64) = (0.1, 0.5);
/// Optical point-spread sigma range, px.
pub const PSF_SIGMA_PX: (f64, f64) = (0.3, 1.5);
/// Radial distortion range.
pub const K1: (f64, f64) = (-0.05, 0.05);
/// Read noise range, fraction of full scale (log-uniform).
pub const READ_NOISE: (f64, f64) = (0.001, 0.012);
/// Conveyor travel per frame, mm (log-uniform).
pub const FRAME_STEP_MM: (f64, f64) = (0.1, 0.5);
/// Ambient light range.
pub const AMBIENT: (f64, f64) = (0.0, 0.3);
/// Speckle contrast range.
pub const SPECKLE: (f64, f64) = (0.0, 0.4);
/// Peak of the dimmer surface's stripes, levels of an 8-bit scale (log-uniform).
pub const DIM_PEAK_LEVELS_8BIT: (f64, f64) = (8.0, 128.0);

/// Largest ambient background of any surface, fraction of full scale (the rest is the stripes' headroom).
pub const AMBIENT_HEADROOM: f64 = 0.5;

/// One random scene: the sensor, the part, what to render, and the draws in words.
#[derive(Debug, Clone)]
pub struct RandomScene {
    /// The scene seed.
    pub seed: u64,
    /// The sensor (its exposure set by [`RandomScene::render`]).
    pub sensor: Sensor,
    /// The part.
    pub scene: Scene,
    /// Render options (noise, speckle, blur, ambient on; vignetting as drawn).
    pub opts: RenderOptions,
    /// The peak of the dimmer surface's stripes, fraction of full scale: as drawn, or lower once
    /// [`RandomScene::render`] holds the exposure for the ambient light.
    pub dim_peak: f64,
}

fn log_uniform(rng: &mut ChaCha8Rng, (a, b): (f64, f64)) -> f64 {
    a * (b / a).powf(rng.random::<f64>())
}

fn uniform(rng: &mut ChaCha8Rng, (a, b): (f64, f64)) -> f64 {
    a + (b - a) * rng.random::<f64>()
}

impl RandomScene {
    /// Draws the scene of `seed`.
    pub fn draw(seed: u64) -> Self {
        let mut rng = ChaCha8Rng::seed_from_u64(seed ^ 0x5EED_0F5C_E9E5);
        let mut sensor = Sensor::default();
        let stripes = rng.random_range(STRIPES.0..=STRIPES.1);
        sensor.laser.stripes = stripes;
        if stripes > 1 {
            sensor.laser.pitch_mm = (STRIPE_SPAN_MM / (stripes - 1) as f64).min(10.0);
        }
        sensor.laser.sigma_mm = uniform(&mut rng, BEAM_SIGMA_MM);
        sensor.laser.speckle_contrast = uniform(&mut rng, SPECKLE);
        let cam = &mut sensor.camera;
        cam.psf_sigma_px = uniform(&mut rng, PSF_SIGMA_PX);
        cam.k1 = uniform(&mut rng, K1);
        cam.bits = [8u8, 10, 12, 16][rng.random_range(0..4)];
        cam.read_noise_e = cam.full_well_e * log_uniform(&mut rng, READ_NOISE);
        let vignetting = rng.random_bool(0.5);
        let belt = log_uniform(&mut rng, BELT_ALBEDO);
        let part = uniform(&mut rng, PART_ALBEDO);
        let mut scene = Scene {
            name: format!("random-{seed}"),
            belt: Belt { albedo: belt },
            lighting: Lighting {
                ambient: uniform(&mut rng, AMBIENT),
                vignetting,
            },
            ..Scene::empty_belt()
        };
        if rng.random_bool(0.9) {
            let (length, width) = (
                uniform(&mut rng, (20.0, 100.0)),
                uniform(&mut rng, (20.0, 100.0)),
            );
            let thickness = uniform(&mut rng, PART_HEIGHT_MM);
            let plate = Plate {
                center_x_mm: uniform(&mut rng, (-20.0, 20.0)),
                center_y_mm: uniform(&mut rng, (-20.0, 20.0)),
                length_mm: length,
                width_mm: width,
                thickness_mm: thickness,
                chamfer_mm: uniform(&mut rng, (0.0, 1.0)).min(thickness / 2.0),
                albedo: part,
            };
            if rng.random_bool(0.5) {
                let contrast = uniform(&mut rng, (1.0, TEXTURE_CONTRAST));
                scene.features.push(Feature::Texture {
                    x0_mm: plate.center_x_mm - length / 2.0,
                    y0_mm: plate.center_y_mm - width / 2.0,
                    x1_mm: plate.center_x_mm + length / 2.0,
                    y1_mm: plate.center_y_mm + width / 2.0,
                    cell_mm: log_uniform(&mut rng, TEXTURE_CELL_MM),
                    low: part / contrast,
                    high: part,
                    seed,
                });
            }
            scene.plate = Some(plate);
        }
        let dim_peak = log_uniform(&mut rng, DIM_PEAK_LEVELS_8BIT) / 255.0;
        // Drawn last, so that the draws before it stay those of the single-frame scenes.
        let step = log_uniform(&mut rng, FRAME_STEP_MM);
        let speed_mm_s = 10.0;
        sensor.conveyor = Some(stripe3d_core::sensor::Conveyor {
            speed_mm_s,
            fps: speed_mm_s / step,
        });
        let opts = RenderOptions {
            vignetting,
            seed,
            ..RenderOptions::default()
        };
        Self {
            seed,
            sensor,
            scene,
            opts,
            dim_peak,
        }
    }

    /// The draws in one line (for the bench's worst scenes).
    pub fn describe(&self) -> String {
        let cam = &self.sensor.camera;
        let laser = &self.sensor.laser;
        let part = match &self.scene.plate {
            None => "empty belt".to_string(),
            Some(p) => {
                let texture = self.scene.features.iter().find_map(|f| match f {
                    Feature::Texture {
                        cell_mm, low, high, ..
                    } => Some(format!(", texture {cell_mm:.1} mm {:.1}:1", high / low)),
                    _ => None,
                });
                format!(
                    "part {:.2}{} {:.1} mm high",
                    p.albedo,
                    texture.unwrap_or_default(),
                    p.thickness_mm
                )
            }
        };
        format!(
            "{} stripes, {} bit, belt {:.2}, {part}, dim peak {:.0}/255, read noise {:.2}/255, ambient {:.2}, \
             beam {:.2} mm, psf {:.2} px, k1 {:+.3}, speckle {:.2}",
            laser.stripes,
            cam.bits,
            self.scene.belt.albedo,
            self.dim_peak * 255.0,
            cam.read_noise_e / cam.full_well_e * 255.0,
            self.scene.lighting.ambient,
            laser.sigma_mm,
            cam.psf_sigma_px,
            cam.k1,
            laser.speckle_contrast,
        )
    }

    /// Sets the exposure from a noise-free render (module docs) and renders the frame.
    pub fn render(&mut self) -> Result<Frame, SimError> {
        self.expose()?;
        Ok(Simulator::new(&self.sensor, &self.scene, self.opts.clone())?.render(0, 0.0))
    }

    /// Sets the camera's exposure from a noise-free render of frame 0 (module docs); [`RandomScene::sensor`] is then
    /// the one to render and scan the scene with.
    pub fn expose(&mut self) -> Result<(), SimError> {
        let levels = self.unit_peaks(&self.scene)?;
        let dim = levels
            .iter()
            .flatten()
            .copied()
            .filter(|&p| p > 0.0)
            .fold(f64::INFINITY, f64::min);
        if dim.is_finite() {
            let cam = &mut self.sensor.camera;
            cam.exposure_e = self.dim_peak * cam.full_well_e / dim;
        }
        // Ambient light adds `ambient · albedo` (times n_z and the vignetting, both at most 1) to a surface.
        let brightest = self.scene.plate.as_ref().map_or(0.0, |p| p.albedo);
        let ambient = self.scene.lighting.ambient * brightest.max(self.scene.belt.albedo);
        if self.opts.ambient && ambient > 0.0 {
            let cam = &mut self.sensor.camera;
            let held = AMBIENT_HEADROOM * cam.full_well_e / ambient;
            if held < cam.exposure_e {
                // The dim stripes now peak lower, and the description says so.
                self.dim_peak *= held / cam.exposure_e;
                cam.exposure_e = held;
            }
        }
        Ok(())
    }

    /// The sensor to calibrate this scene's camera with: its exposure set so that the gauge plates' stripes peak at
    /// half of full scale. A user exposes for the plates when calibrating; the scene's own exposure, set for its
    /// dimmer surface, can saturate them (a plate of reflectance 0.6 under an exposure set for a black belt), and a
    /// saturated stripe's centre is not the sheet's. The planes do not depend on the exposure.
    pub fn calibration_sensor(&self) -> Result<Sensor, SimError> {
        let levels = self.unit_peaks(&Scene::covering_plate(5.0))?;
        let mut sensor = self.sensor.clone();
        if let Some(peak) = levels[1].filter(|&p| p > 0.0) {
            sensor.camera.exposure_e = 0.5 * sensor.camera.full_well_e / peak;
        }
        Ok(sensor)
    }

    /// The median peak of the true stripe points on the belt and on the part of `scene`, per unit of exposure (a
    /// fraction of full scale for an exposure of one full well), from a noise-free render.
    fn unit_peaks(&self, scene: &Scene) -> Result<[Option<f64>; 2], SimError> {
        let mut probe = self.sensor.clone();
        // Linear and unclipped: 2^14 levels for unit radiance, far below the 16-bit ceiling.
        probe.camera.bits = 16;
        probe.camera.full_well_e = 4.0e9;
        probe.camera.exposure_e = 1.0e9;
        let unit = 65_535.0 / 4.0;
        let opts = RenderOptions {
            blur: true,
            vignetting: self.opts.vignetting,
            ..RenderOptions::ideal()
        };
        let ideal = Simulator::new(&probe, scene, opts)?.render(0, 0.0);
        let (mut belt, mut part) = (Vec::new(), Vec::new());
        let w = ideal.image.width();
        for t in &ideal.truth {
            let u = t.u.round().clamp(0.0, (w - 1) as f64) as usize;
            let v = ideal.image.data()[t.row as usize * w + u];
            let peak = f64::from(v) / unit;
            if t.world[2] < 1e-3 {
                belt.push(peak);
            } else {
                part.push(peak);
            }
        }
        let median = |v: &mut Vec<f64>| {
            v.sort_by(f64::total_cmp);
            v.get(v.len() / 2).copied()
        };
        Ok([median(&mut belt), median(&mut part)])
    }

    /// Where the frame's visible surface breaks ([`Simulator::edge_map`]: walls, laser-shadow boundaries, albedo
    /// edges), for scoring away from them.
    pub fn edge_map(&self) -> Result<EdgeMap, SimError> {
        Ok(Simulator::new(&self.sensor, &self.scene, self.opts.clone())?.edge_map(0.0))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The scene's camera shrunk to 160 x 120 with the same field of view (quick renders).
    fn small_camera(d: &mut RandomScene) {
        let cam = &mut d.sensor.camera;
        cam.width = 160;
        cam.height = 120;
        cam.fx /= 4.05;
        cam.fy /= 4.05;
        cam.cx = 79.5;
        cam.cy = 59.5;
    }

    #[test]
    fn every_draw_is_a_valid_scene_and_sensor_and_seeds_reproduce() {
        for seed in 0..200 {
            let d = RandomScene::draw(seed);
            d.scene.validate().expect("scene");
            d.sensor.validate().expect("sensor");
            assert_eq!(d.describe(), RandomScene::draw(seed).describe());
        }
        assert_ne!(
            RandomScene::draw(1).describe(),
            RandomScene::draw(2).describe()
        );
    }

    #[test]
    fn the_gauge_plates_are_exposed_for_themselves() {
        // Seed 38: a black belt (0.03) whose dim stripes set an exposure that saturates a 0.6 plate.
        let mut d = RandomScene::draw(38);
        small_camera(&mut d);
        d.opts.noise = false;
        d.opts.speckle = false;
        d.expose().expect("expose");
        // The median of the plate's stripes at their true centres, a share of full scale.
        let peak = |sensor: &Sensor| {
            let f = Simulator::new(sensor, &Scene::covering_plate(5.0), d.opts.clone())
                .expect("sim")
                .render(0, 0.0);
            let full = f64::from((1u32 << sensor.camera.bits) - 1);
            let w = f.image.width();
            let mut v: Vec<f64> = f
                .truth
                .iter()
                .map(|t| {
                    let u = t.u.round().clamp(0.0, (w - 1) as f64) as usize;
                    f64::from(f.image.data()[t.row as usize * w + u]) / full
                })
                .collect();
            v.sort_by(f64::total_cmp);
            v[v.len() / 2]
        };
        let scene_peak = peak(&d.sensor);
        assert!(
            scene_peak > 0.99,
            "the scene's exposure saturates the plate: {scene_peak}"
        );
        let p = peak(&d.calibration_sensor().expect("calibration sensor"));
        assert!((0.4..0.75).contains(&p), "plate peak {p} of full scale");
    }

    #[test]
    fn ambient_light_leaves_the_stripes_headroom() {
        // Seed 20: a white part (0.91) under strong ambient light (0.21), whose drawn exposure saturates the part.
        let mut d = RandomScene::draw(20);
        small_camera(&mut d);
        d.sensor.camera.bits = 16;
        d.opts.noise = false;
        d.opts.speckle = false;
        let drawn = d.dim_peak;
        let lit = d.render().expect("render");
        assert!(
            d.dim_peak < drawn,
            "the exposure is held for the ambient light"
        );
        let dark = Simulator::new(
            &d.sensor,
            &d.scene,
            RenderOptions {
                ambient: false,
                ..d.opts.clone()
            },
        )
        .expect("sim")
        .render(0, 0.0);
        let ambient = lit
            .image
            .data()
            .iter()
            .zip(dark.image.data())
            .map(|(&a, &b)| f64::from(a.saturating_sub(b)) / 65_535.0)
            .fold(0.0, f64::max);
        assert!(
            ambient > 0.3 && ambient <= AMBIENT_HEADROOM + 1e-3,
            "ambient {ambient}"
        );
    }

    #[test]
    fn the_dimmer_surface_peaks_at_the_drawn_level() {
        // A small frame keeps the test quick; the exposure rule does not depend on the size.
        let mut d = RandomScene::draw(7);
        small_camera(&mut d);
        d.opts.noise = false;
        d.opts.speckle = false;
        d.opts.ambient = false;
        d.sensor.camera.bits = 16;
        let frame = d.render().expect("render");
        let full = 65_535.0;
        let mut peaks: Vec<(bool, f64)> = frame
            .truth
            .iter()
            .map(|t| {
                let u = t.u.round() as usize;
                let v =
                    f64::from(frame.image.data()[t.row as usize * frame.image.width() + u]) / full;
                (t.world[2] < 1e-3, v)
            })
            .collect();
        peaks.sort_by(|a, b| a.1.total_cmp(&b.1));
        let med = |belt: bool| {
            let v: Vec<f64> = peaks.iter().filter(|p| p.0 == belt).map(|p| p.1).collect();
            v.get(v.len() / 2).copied()
        };
        let dim = [med(true), med(false)]
            .into_iter()
            .flatten()
            .fold(f64::INFINITY, f64::min);
        assert!(
            (dim - d.dim_peak).abs() < 0.02 * d.dim_peak + 1.0 / full,
            "{dim} vs {}",
            d.dim_peak
        );
    }
}
