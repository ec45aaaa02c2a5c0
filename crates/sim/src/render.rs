//! Frame rendering and exact ground truth.
//!
//! Radiometry (relative units): a surface point lit by sheet `i` receives the irradiance
//! `power · exp(−d²/2σ²) · (R_REF / r)` where `d` is its distance from the sheet's centre plane, `r` its distance
//! from the source (a fan spreads in one dimension, so irradiance falls as 1/r) and `R_REF` = 200 mm. Its radiance
//! towards the camera is `E · (albedo (1 − gloss) cos θᵢ + gloss (n+2)/2 (R·V)ⁿ)` (Lambertian plus normalised
//! Phong, both without the common 1/π). Ambient light adds `ambient · albedo (1 − gloss) · n_z`. The camera
//! collects `exposure_e` electrons per unit radiance, times cos⁴ of the field angle when vignetting is on.
//! Speckle multiplies the laser light by a Gamma variate of mean 1 and the configured contrast; the optical PSF is
//! a Gaussian; shot noise is Poisson (Gaussian above 50 electrons), read noise Gaussian; the ADC quantises to the
//! configured bits and saturates at full well.

use crate::SimError;
use crate::heightfield::HeightField;
use crate::scene::{DefectTruth, Scene};
use nalgebra::Vector3;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, Gamma, Poisson, StandardNormal};
use serde::{Deserialize, Serialize};
use stripe3d_core::{Image, LaserPlane, Sensor};

/// Distance from the source at which irradiance equals `power`, mm.
pub const R_REF_MM: f64 = 200.0;
/// Beam profile beyond this many sigmas is taken as zero.
const BEAM_CUTOFF_SIGMAS: f64 = 5.0;
/// Phong exponent of glossy patches.
const PHONG_EXPONENT: i32 = 40;
/// Offset of a shadow ray's start towards the light, mm (keeps it off the surface it starts on).
const SHADOW_OFFSET_MM: f64 = 0.01;
/// A root of the sheet distance is accepted as ground truth when the distance there is below this, mm; larger
/// residuals mark a jump of the visible surface (an occluding edge), not a crossing.
const TRUTH_RESIDUAL_MM: f64 = 1e-6;

/// Largest image the simulator renders, pixels (its per-pixel ray table and buffers take about 40 bytes a pixel).
pub const MAX_RENDER_PIXELS: usize = 16 * 1024 * 1024;

/// What to render. Every effect can be switched off for closed-form tests.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct RenderOptions {
    /// Shot and read noise.
    pub noise: bool,
    /// Laser speckle.
    pub speckle: bool,
    /// Optical point-spread function.
    pub blur: bool,
    /// Highlights and ghost stripes from glossy patches.
    pub gloss: bool,
    /// Ambient light (the scene's level) when true; none when false.
    pub ambient: bool,
    /// Vignetting as the scene says when true; none when false.
    pub vignetting: bool,
    /// Samples per pixel side (1 = one ray through the pixel centre; n = n x n rays over the pixel area).
    pub supersample: u32,
    /// Seed of every random draw; frame k uses a stream derived from (seed, k).
    pub seed: u64,
}

impl Default for RenderOptions {
    fn default() -> Self {
        Self {
            noise: true,
            speckle: true,
            blur: true,
            gloss: true,
            ambient: true,
            vignetting: true,
            supersample: 1,
            seed: 1,
        }
    }
}

impl RenderOptions {
    /// Everything off: geometry and Lambertian shading only.
    pub fn ideal() -> Self {
        Self {
            noise: false,
            speckle: false,
            blur: false,
            gloss: false,
            ambient: false,
            vignetting: false,
            supersample: 1,
            seed: 1,
        }
    }
}

/// One ground-truth stripe point: where the camera ray of `(u, row)` meets the lit surface on a sheet's centre.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct TruthPoint {
    /// Image row.
    pub row: u32,
    /// Stripe index (0 = smallest x at the belt).
    pub stripe: u32,
    /// Sub-pixel column (pixel centres at integer coordinates).
    pub u: f64,
    /// World point, mm.
    pub world: [f64; 3],
    /// The same point in part coordinates, mm.
    pub part: [f64; 3],
}

/// A rendered frame and its ground truth.
#[derive(Debug, Clone)]
pub struct Frame {
    /// Frame index.
    pub index: usize,
    /// Conveyor travel since frame 0, mm.
    pub travel_mm: f64,
    /// Digitised image (values up to 2^bits − 1).
    pub image: Image<u16>,
    /// Ground-truth stripe points, sorted by row, then stripe, then u.
    pub truth: Vec<TruthPoint>,
}

/// Height difference between neighbouring pixels' surface points that makes an edge ([`Simulator::edge_map`]), mm.
pub const EDGE_JUMP_MM: f64 = 0.5;

/// Ratio of neighbouring pixels' reflectances that makes an edge ([`Simulator::edge_map`]): across an albedo edge
/// a stripe's intensity centre leaves the sheet's centre (by up to a pixel on the demo's dark patch).
pub const EDGE_ALBEDO_RATIO: f64 = 1.25;

/// Pixels on each side of a stripe point within which an edge makes it an edge point ([`EdgeMap::near`]): the
/// stripe's light spreads about three sigmas of its width (1-1.5 px on the demo) plus the optics' blur.
pub const EDGE_REACH_PX: usize = 5;

/// The edges of one frame's visible surface ([`Simulator::edge_map`]).
#[derive(Debug, Clone)]
pub struct EdgeMap {
    width: usize,
    height: usize,
    /// Per pixel: the surface breaks between it and its left neighbour.
    marks: Vec<bool>,
}

impl EdgeMap {
    /// Whether the surface breaks within [`EDGE_REACH_PX`] pixels of column `u` on image row `row` (rows outside
    /// the image: no).
    pub fn near(&self, row: u32, u: f64) -> bool {
        let v = row as usize;
        if v >= self.height || !u.is_finite() {
            return false;
        }
        let c = u.round().clamp(0.0, (self.width - 1) as f64) as usize;
        let (a, b) = (
            c.saturating_sub(EDGE_REACH_PX - 1),
            (c + EDGE_REACH_PX).min(self.width - 1),
        );
        self.marks[v * self.width + a..=v * self.width + b]
            .iter()
            .any(|&m| m)
    }
}

/// A ready-to-render sensor and scene.
#[derive(Debug, Clone)]
pub struct Simulator {
    sensor: Sensor,
    field: HeightField,
    defects: Vec<DefectTruth>,
    planes: Vec<LaserPlane>,
    /// Undistorted normalised coordinates of every pixel centre, row-major.
    rays: Vec<(f64, f64)>,
    opts: RenderOptions,
    ambient: f64,
    vignetting: bool,
}

/// Per-pixel light, split so that speckle touches only the laser.
#[derive(Debug, Clone, Copy, Default)]
struct Light {
    ambient: f64,
    laser: f64,
}

impl Simulator {
    /// Validates the sensor and scene and prepares the renderer.
    pub fn new(sensor: &Sensor, scene: &Scene, opts: RenderOptions) -> Result<Self, SimError> {
        sensor.validate()?;
        if opts.supersample == 0 || opts.supersample > 8 {
            return Err(SimError::InvalidScene {
                field: "supersample".into(),
                reason: format!("{} must be 1 to 8", opts.supersample),
            });
        }
        let cam = &sensor.camera;
        let (w, h) = (cam.width as usize, cam.height as usize);
        if w * h > MAX_RENDER_PIXELS {
            return Err(SimError::InvalidScene {
                field: "camera.width x camera.height".into(),
                reason: format!(
                    "{w} x {h} pixels is more than the {MAX_RENDER_PIXELS} the simulator renders"
                ),
            });
        }
        let (field, defects) = scene.rasterize()?;
        let mut rays = Vec::with_capacity(w * h);
        for v in 0..h {
            for u in 0..w {
                rays.push(cam.normalized(u as f64, v as f64));
            }
        }
        Ok(Self {
            planes: sensor.laser.planes(),
            sensor: sensor.clone(),
            field,
            defects,
            rays,
            ambient: if opts.ambient {
                scene.lighting.ambient
            } else {
                0.0
            },
            vignetting: opts.vignetting && scene.lighting.vignetting,
            opts,
        })
    }

    /// The sensor rendered.
    pub fn sensor(&self) -> &Sensor {
        &self.sensor
    }

    /// The part's true height field (part coordinates).
    pub fn height_field(&self) -> &HeightField {
        &self.field
    }

    /// The defects put into the scene.
    pub fn defects(&self) -> &[DefectTruth] {
        &self.defects
    }

    /// Height of the visible surface along the ray (xn, yn) with the part moved by `travel` mm.
    fn cast(&self, xn: f64, yn: f64, travel: f64) -> f64 {
        let hgt = self.sensor.camera.height_mm;
        let top = (self.field.max_height_mm() + 1e-6).min(hgt * 0.999);
        // Ray points at heights `top` and 0, in part coordinates.
        let a = [xn * (hgt - top) - travel, -yn * (hgt - top), top];
        let b = [xn * hgt - travel, -yn * hgt, 0.0];
        match self.field.first_hit(a, b) {
            Some(s) => top * (1.0 - s),
            None => 0.0,
        }
    }

    fn world_point(&self, xn: f64, yn: f64, z: f64) -> Vector3<f64> {
        let depth = self.sensor.camera.height_mm - z;
        Vector3::new(xn * depth, -yn * depth, z)
    }

    /// True when the segment from `p` (world) to `q` (world) is blocked by the part.
    fn blocked(&self, p: &Vector3<f64>, q: &Vector3<f64>, travel: f64) -> bool {
        let dir = (q - p).normalize();
        let start = p + dir * SHADOW_OFFSET_MM;
        let a = [start.x - travel, start.y, start.z];
        let b = [q.x - travel, q.y, q.z];
        // The end point itself may lie on a surface (a mirror): stop just short of it.
        let b = [
            a[0] + (b[0] - a[0]) * 0.999_999,
            a[1] + (b[1] - a[1]) * 0.999_999,
            a[2] + (b[2] - a[2]) * 0.999_999,
        ];
        match self.field.first_hit(a, b) {
            None => false,
            Some(s) => s > 0.0 || self.field.height_at(a[0], a[1]) > a[2] + 1e-9,
        }
    }

    /// Light reflected towards the camera from the visible surface point at height `z` on ray (xn, yn).
    fn shade(&self, xn: f64, yn: f64, z: f64, travel: f64) -> Light {
        let p = self.world_point(xn, yn, z);
        let sp = self.field.surface_at(p.x - travel, p.y);
        let n = Vector3::new(-sp.dzdx, -sp.dzdy, 1.0).normalize();
        let diffuse = sp.albedo * (1.0 - if self.opts.gloss { sp.gloss } else { 0.0 });
        let mut light = Light {
            ambient: self.ambient * diffuse * n.z.max(0.0),
            laser: 0.0,
        };
        let laser = &self.sensor.laser;
        let sigma = laser.sigma_mm;
        let source = laser.source();
        let to_src = source - p;
        let r = to_src.norm();
        let l = to_src / r;
        let cos_i = n.dot(&l);
        let view = (self.sensor.camera.centre() - p).normalize();
        // Direct light from every sheet.
        if cos_i > 0.0 {
            let mut beam = 0.0;
            for plane in &self.planes {
                let d = plane.signed_distance(&p);
                if d.abs() < BEAM_CUTOFF_SIGMAS * sigma {
                    beam += (-0.5 * (d / sigma).powi(2)).exp();
                }
            }
            if beam > 0.0 && !self.blocked(&p, &source, travel) {
                let e = laser.power * beam * R_REF_MM / r;
                let mut brdf = diffuse * cos_i;
                if self.opts.gloss && sp.gloss > 0.0 {
                    let refl = n * (2.0 * cos_i) - l;
                    let rv = refl.dot(&view).max(0.0);
                    brdf += sp.gloss * (f64::from(PHONG_EXPONENT) + 2.0) / 2.0
                        * rv.powi(PHONG_EXPONENT);
                }
                light.laser += e * brdf;
            }
        }
        // Ghost stripes: sheets mirrored by glossy planar patches.
        if self.opts.gloss {
            for m in self.field.mirrors() {
                light.laser += self.ghost(m, &p, &n, diffuse, travel);
            }
        }
        light
    }

    /// Irradiance times diffuse reflectance at `p` from the sheets as mirrored by `m`.
    fn ghost(
        &self,
        m: &crate::heightfield::Mirror,
        p: &Vector3<f64>,
        n: &Vector3<f64>,
        diffuse: f64,
        travel: f64,
    ) -> f64 {
        let laser = &self.sensor.laser;
        let sigma = laser.sigma_mm;
        // Mirror plane in world coordinates: z = a + b (x − travel) + c y.
        let [a, b, c] = m.plane;
        let mn = Vector3::new(-b, -c, 1.0).normalize();
        let m0 = Vector3::new(travel, 0.0, a);
        let side = |q: &Vector3<f64>| mn.dot(&(q - m0));
        let src = laser.source();
        let (ds, dp) = (side(&src), side(p));
        if ds <= 0.0 || dp <= 1e-3 {
            return 0.0;
        }
        let virt = src - mn * (2.0 * ds);
        // Mirrored sheets: reflect the normals, keep passing through the (virtual) source.
        let mut beam = 0.0;
        for plane in &self.planes {
            let nn = plane.normal - mn * (2.0 * plane.normal.dot(&mn));
            let d = nn.dot(&(p - virt));
            if d.abs() < BEAM_CUTOFF_SIGMAS * sigma {
                beam += (-0.5 * (d / sigma).powi(2)).exp();
            }
        }
        if beam == 0.0 {
            return 0.0;
        }
        // Where the path from the virtual source to p crosses the mirror.
        let dv = side(&virt);
        let t = dv / (dv - dp);
        let q = virt + (p - virt) * t;
        let (qx, qy) = (q.x - travel, q.y);
        if qx < m.rect[0] || qx > m.rect[2] || qy < m.rect[1] || qy > m.rect[3] {
            return 0.0;
        }
        let to_q = q - p;
        let cos_i = n.dot(&to_q.normalize());
        if cos_i <= 0.0 || self.blocked(&q, &src, travel) || self.blocked(p, &q, travel) {
            return 0.0;
        }
        let path = (p - virt).norm();
        laser.power * m.gloss * beam * R_REF_MM / path * diffuse * cos_i
    }

    fn vignette(&self, xn: f64, yn: f64) -> f64 {
        if self.vignetting {
            (1.0 / (1.0 + xn * xn + yn * yn)).powi(2)
        } else {
            1.0
        }
    }

    /// Renders frame `index` with the part moved `travel_mm` along +x since frame 0.
    pub fn render(&self, index: usize, travel_mm: f64) -> Frame {
        let cam = &self.sensor.camera;
        let (w, h) = (cam.width as usize, cam.height as usize);
        let mut rng = ChaCha8Rng::seed_from_u64(
            self.opts.seed ^ (index as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15),
        );
        let mut electrons = vec![0f32; w * h];
        let mut centre_z = vec![0f64; w * h];
        let speckle = (self.opts.speckle && self.sensor.laser.speckle_contrast > 0.0).then(|| {
            let c2 = self.sensor.laser.speckle_contrast.powi(2);
            Gamma::new(1.0 / c2, c2).ok()
        });
        let ss = self.opts.supersample as usize;
        for v in 0..h {
            for u in 0..w {
                let k = v * w + u;
                let (xn, yn) = self.rays[k];
                let z = self.cast(xn, yn, travel_mm);
                centre_z[k] = z;
                let (light, gain) = if ss == 1 {
                    (self.shade(xn, yn, z, travel_mm), self.vignette(xn, yn))
                } else {
                    let mut sum = Light::default();
                    for sy in 0..ss {
                        for sx in 0..ss {
                            let du = (sx as f64 + 0.5) / ss as f64 - 0.5;
                            let dv = (sy as f64 + 0.5) / ss as f64 - 0.5;
                            let (x2, y2) = cam.normalized(u as f64 + du, v as f64 + dv);
                            let z2 = self.cast(x2, y2, travel_mm);
                            let l = self.shade(x2, y2, z2, travel_mm);
                            let g = self.vignette(x2, y2);
                            sum.ambient += l.ambient * g;
                            sum.laser += l.laser * g;
                        }
                    }
                    let n = (ss * ss) as f64;
                    (
                        Light {
                            ambient: sum.ambient / n,
                            laser: sum.laser / n,
                        },
                        1.0,
                    )
                };
                let mut laser = light.laser;
                if laser > 0.0 {
                    if let Some(Some(g)) = &speckle {
                        laser *= g.sample(&mut rng);
                    }
                }
                electrons[k] = ((light.ambient + laser) * gain * cam.exposure_e) as f32;
            }
        }
        if self.opts.blur && cam.psf_sigma_px > 0.0 {
            gaussian_blur(&mut electrons, w, h, cam.psf_sigma_px);
        }
        let max_dn = f64::from((1u32 << cam.bits) - 1);
        let dn_per_e = max_dn / cam.full_well_e;
        let data: Vec<u16> = electrons
            .iter()
            .map(|&e| {
                let mut e = f64::from(e).max(0.0);
                if self.opts.noise {
                    e = if e < 50.0 {
                        Poisson::new(e.max(1e-9)).map_or(e, |p| p.sample(&mut rng))
                    } else {
                        e + e.sqrt() * rng.sample::<f64, _>(StandardNormal)
                    };
                    e += cam.read_noise_e * rng.sample::<f64, _>(StandardNormal);
                }
                let e = e.clamp(0.0, cam.full_well_e);
                (e * dn_per_e).round().clamp(0.0, max_dn) as u16
            })
            .collect();
        let image = Image::from_vec(w, h, data).unwrap_or_else(|_| Image::new(w, h));
        let truth = self.truth(&centre_z, travel_mm);
        Frame {
            index,
            travel_mm,
            image,
            truth,
        }
    }

    /// Where in a frame (the part moved by `travel_mm`) the visible surface breaks: a pixel is marked when the
    /// height seen through it differs from its left neighbour's by more than [`EDGE_JUMP_MM`] (a wall, an occluding
    /// edge, a hole's rim: steeper than about 70 degrees at the paper's scale of 0.17 mm a pixel), when one of the
    /// two surface points is lit by the projector and the other is not (a laser shadow's boundary), or when their
    /// reflectances differ by more than [`EDGE_ALBEDO_RATIO`] (an albedo edge); a pixel and the one above it are both
    /// marked when they differ so (a rim running along the rows, which a stripe crosses at a grazing angle). A
    /// stripe whose light falls across such a pixel has no single centre on one surface, or an intensity centre off
    /// the sheet's: the benchmarks score points there apart ([`EdgeMap::near`]).
    pub fn edge_map(&self, travel_mm: f64) -> EdgeMap {
        let cam = &self.sensor.camera;
        let (w, h) = (cam.width as usize, cam.height as usize);
        let mut marks = vec![false; w * h];
        // Per pixel of the previous row and of this one: height, lit, reflectance.
        let mut above: Vec<(f64, bool, f64)> = Vec::with_capacity(w);
        let mut here: Vec<(f64, bool, f64)> = Vec::with_capacity(w);
        let breaks = |a: (f64, bool, f64), b: (f64, bool, f64)| {
            let (lo, hi) = (a.2.min(b.2), a.2.max(b.2));
            (a.0 - b.0).abs() > EDGE_JUMP_MM || a.1 != b.1 || hi > EDGE_ALBEDO_RATIO * lo
        };
        for v in 0..h {
            here.clear();
            for u in 0..w {
                let (xn, yn) = self.rays[v * w + u];
                let z = self.cast(xn, yn, travel_mm);
                let p = self.world_point(xn, yn, z);
                let lit = self.lit(&p, travel_mm);
                let albedo = self.field.surface_at(p.x - travel_mm, p.y).albedo;
                let s = (z, lit, albedo);
                if u > 0 && breaks(here[u - 1], s) {
                    marks[v * w + u] = true;
                }
                // A break with the pixel above marks both: a rim running along the rows breaks the surface between
                // rows, and the stripe crossing it there at a grazing angle is smeared over both (the optics' blur).
                if v > 0 && breaks(above[u], s) {
                    marks[v * w + u] = true;
                    marks[(v - 1) * w + u] = true;
                }
                here.push(s);
            }
            std::mem::swap(&mut above, &mut here);
        }
        EdgeMap {
            width: w,
            height: h,
            marks,
        }
    }

    /// True when the surface point `p` (world) is lit directly by the projector.
    fn lit(&self, p: &Vector3<f64>, travel: f64) -> bool {
        let sp = self.field.surface_at(p.x - travel, p.y);
        let n = Vector3::new(-sp.dzdx, -sp.dzdy, 1.0);
        let src = self.sensor.laser.source();
        n.dot(&(src - p)) > 0.0 && !self.blocked(p, &src, travel)
    }

    /// Exact ground truth from the centre-ray heights of a rendered frame.
    fn truth(&self, centre_z: &[f64], travel: f64) -> Vec<TruthPoint> {
        let cam = &self.sensor.camera;
        let (w, h) = (cam.width as usize, cam.height as usize);
        let mut out = Vec::new();
        let mut dist = vec![0f64; w];
        for v in 0..h {
            for (s, plane) in self.planes.iter().enumerate() {
                for u in 0..w {
                    let (xn, yn) = self.rays[v * w + u];
                    dist[u] = plane.signed_distance(&self.world_point(xn, yn, centre_z[v * w + u]));
                }
                for u in 0..w.saturating_sub(1) {
                    if (dist[u] >= 0.0) == (dist[u + 1] >= 0.0) {
                        continue;
                    }
                    let f = |uc: f64| {
                        let (xn, yn) = cam.normalized(uc, v as f64);
                        let z = self.cast(xn, yn, travel);
                        let p = self.world_point(xn, yn, z);
                        (plane.signed_distance(&p), p)
                    };
                    if let Some((uc, p)) =
                        refine_root(f, u as f64, dist[u], u as f64 + 1.0, dist[u + 1])
                    {
                        if self.lit(&p, travel) {
                            out.push(TruthPoint {
                                row: v as u32,
                                stripe: s as u32,
                                u: uc,
                                world: [p.x, p.y, p.z],
                                part: [p.x - travel, p.y, p.z],
                            });
                        }
                    }
                }
            }
        }
        out
    }
}

/// Root of `f` in `[a, b]` where `f(a)` and `f(b)` differ in sign (Illinois regula falsi, then a residual check).
fn refine_root(
    f: impl Fn(f64) -> (f64, Vector3<f64>),
    mut a: f64,
    mut fa: f64,
    mut b: f64,
    mut fb: f64,
) -> Option<(f64, Vector3<f64>)> {
    let mut side = 0;
    let mut best = None;
    for _ in 0..100 {
        let c = if fb != fa {
            (a * fb - b * fa) / (fb - fa)
        } else {
            0.5 * (a + b)
        };
        let c = if c > a.min(b) && c < a.max(b) {
            c
        } else {
            0.5 * (a + b)
        };
        let (fc, p) = f(c);
        best = Some((c, fc, p));
        if fc == 0.0 || (b - a).abs() < 1e-10 {
            break;
        }
        if (fc >= 0.0) == (fb >= 0.0) {
            b = c;
            fb = fc;
            if side == 1 {
                fa *= 0.5;
            }
            side = 1;
        } else {
            a = c;
            fa = fc;
            if side == -1 {
                fb *= 0.5;
            }
            side = -1;
        }
    }
    let (c, fc, p) = best?;
    (fc.abs() < TRUTH_RESIDUAL_MM).then_some((c, p))
}

/// In-place separable Gaussian blur with clamp-to-edge borders.
fn gaussian_blur(img: &mut [f32], w: usize, h: usize, sigma: f64) {
    let r = (3.0 * sigma).ceil() as isize;
    let mut k: Vec<f32> = (-r..=r)
        .map(|i| (-0.5 * (i as f64 / sigma).powi(2)).exp() as f32)
        .collect();
    let sum: f32 = k.iter().sum();
    k.iter_mut().for_each(|x| *x /= sum);
    let mut tmp = vec![0f32; w * h];
    let clamp = |i: isize, n: usize| i.clamp(0, n as isize - 1) as usize;
    for y in 0..h {
        let row = &img[y * w..(y + 1) * w];
        for x in 0..w {
            let mut acc = 0f32;
            for (t, kv) in k.iter().enumerate() {
                acc += kv * row[clamp(x as isize + t as isize - r, w)];
            }
            tmp[y * w + x] = acc;
        }
    }
    for y in 0..h {
        for x in 0..w {
            let mut acc = 0f32;
            for (t, kv) in k.iter().enumerate() {
                acc += kv * tmp[clamp(y as isize + t as isize - r, h) * w + x];
            }
            img[y * w + x] = acc;
        }
    }
}

/// Scene names and files a simulator run was asked for, as recorded in manifests.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct RunInfo {
    /// Scene name.
    pub scene: String,
    /// Travel of every frame, mm.
    pub travel_mm: Vec<f64>,
    /// Options used.
    pub options: RenderOptions,
}

impl Scene {
    /// Convenience: a simulator of this scene with `sensor` and `opts`.
    pub fn simulator(&self, sensor: &Sensor, opts: RenderOptions) -> Result<Simulator, SimError> {
        Simulator::new(sensor, self, opts)
    }
}
