//! Triangulation: from a stripe point (stripe index, sub-pixel column, scan line) to millimetres.
//!
//! Two models, as the paper and today's practice use them:
//! - [`FullModel`]: the pinhole camera with radial distortion of `sensor.toml` and one fitted 3-D plane per stripe;
//!   each pixel's ray is intersected with its stripe's plane (exact up to the calibration).
//! - [`LinearModel`]: the paper's eq. 3, H = tan(φ) · W/f · D2, with one constant per stripe (a quadratic in the row,
//!   where the fan geometry or the lens needs it): the height is proportional to the stripe's image offset D2 from where it lies on the
//!   belt. It ignores perspective, so it is only as good as that approximation (the scanning issue measures by how
//!   much).
//!
//! Planes and their fitting are in [`crate::geometry`] (re-exported here).

pub use crate::geometry::{Plane, fit_plane};
use crate::sensor::{Camera, Sensor};
use nalgebra::Vector3;
use serde::{Deserialize, Serialize};

/// Pinhole camera plus one plane per stripe.
#[derive(Debug, Clone, PartialEq)]
pub struct FullModel {
    /// The camera.
    pub camera: Camera,
    /// Stripe planes, stripe 0 first.
    pub planes: Vec<Plane>,
}

impl FullModel {
    /// The model of the sensor's nominal geometry (`sensor.toml`'s laser as designed, before calibration).
    pub fn nominal(sensor: &Sensor) -> FullModel {
        FullModel {
            camera: sensor.camera.clone(),
            planes: sensor.laser.planes().iter().map(|p| p.plane()).collect(),
        }
    }

    /// World point (mm) where the ray of pixel (`u`, `v`) meets stripe `stripe`'s plane; `None` for an unknown
    /// stripe, a ray parallel to the plane, or an intersection behind the camera.
    pub fn point(&self, stripe: usize, u: f64, v: f64) -> Option<Vector3<f64>> {
        let plane = self.planes.get(stripe)?;
        let origin = self.camera.centre();
        let dir = self.camera.ray_direction(u, v);
        let denom = plane.normal.dot(&dir);
        if denom.abs() < 1e-12 {
            return None;
        }
        let t = (plane.offset - plane.normal.dot(&origin)) / denom;
        (t > 0.0).then(|| origin + dir * t)
    }

    /// Height (mm) of the point of stripe `stripe` seen at pixel (`u`, `v`): the z of [`FullModel::point`], without
    /// building the point.
    #[inline]
    pub fn height(&self, stripe: usize, u: f64, v: f64) -> Option<f64> {
        let (xn, yn) = self.camera.normalized(u, v);
        self.height_normalized(stripe, xn, yn)
    }

    /// [`FullModel::height`] for a pixel already turned into undistorted normalised coordinates
    /// ([`crate::sensor::Camera::normalized`]): the same value, without undistorting the pixel again for every
    /// stripe a caller tries.
    #[inline]
    pub fn height_normalized(&self, stripe: usize, xn: f64, yn: f64) -> Option<f64> {
        let plane = self.planes.get(stripe)?;
        let h = self.camera.height_mm;
        // Ray from (0, 0, H) along (xn, -yn, -1).
        let denom = plane.normal.x * xn - plane.normal.y * yn - plane.normal.z;
        if denom.abs() < 1e-12 {
            return None;
        }
        let t = (plane.offset - plane.normal.z * h) / denom;
        (t > 0.0).then_some(h - t)
    }

    /// The column at which stripe `stripe` shows a surface of height `z_mm` on row `v` (possibly outside the
    /// image); `None` when the stripe's plane has no such point in front of the camera.
    ///
    /// The points of the plane at that height form a line; its point imaged on row `v` is found by Newton's method
    /// on y (one step without distortion).
    pub fn column_at_height(&self, stripe: usize, v: f64, z_mm: f64) -> Option<f64> {
        let plane = self.planes.get(stripe)?;
        let n = plane.normal;
        let depth = self.camera.height_mm - z_mm;
        if n.x.abs() < 1e-12 || depth <= 0.0 || !z_mm.is_finite() || !v.is_finite() {
            return None;
        }
        let at = |y: f64| Vector3::new((plane.offset - n.y * y - n.z * z_mm) / n.x, y, z_mm);
        let mut y = -(v - self.camera.cy) * depth / self.camera.fy;
        let step = 1e-3 * depth;
        for _ in 0..30 {
            let (u, vp) = self.camera.project(&at(y))?;
            let err = vp - v;
            if err.abs() < 1e-9 {
                return Some(u);
            }
            let (_, vh) = self.camera.project(&at(y + step))?;
            let slope = (vh - vp) / step;
            if slope.abs() < 1e-12 || !slope.is_finite() {
                return None;
            }
            y -= err / slope;
        }
        let (u, vp) = self.camera.project(&at(y))?;
        ((vp - v).abs() < 1e-6).then_some(u)
    }
}

/// The paper's linear model (eq. 3, H = tan(φ) · W/f · D2) for one stripe: the height is proportional to the
/// stripe's image offset D2 = u_belt − u from where it lies on the belt. The constant k = tan(φ) · W/f and the
/// belt column u_belt may vary along the stripe (the fan of a real projector, lens distortion), so both are
/// quadratics in the normalised row r = (v − cy) / fy: height = A(r) − B(r) · u with A = k · u_belt and B = k.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct LinearStripe {
    /// `A(r) = a[0] + a[1] r + a[2] r²`, mm.
    pub a: [f64; 3],
    /// `B(r) = b[0] + b[1] r + b[2] r²`, mm per pixel.
    pub b: [f64; 3],
}

impl LinearStripe {
    /// Height (mm) at column `u` on normalised row `r`.
    #[inline]
    pub fn height(&self, u: f64, r: f64) -> f64 {
        let a = self.a[0] + r * (self.a[1] + r * self.a[2]);
        let b = self.b[0] + r * (self.b[1] + r * self.b[2]);
        a - b * u
    }

    /// The paper's constants on normalised row `r`: (u_belt, k) with height = k · (u_belt − u).
    pub fn constants(&self, r: f64) -> (f64, f64) {
        let a = self.a[0] + r * (self.a[1] + r * self.a[2]);
        let b = self.b[0] + r * (self.b[1] + r * self.b[2]);
        (a / b, b)
    }
}

/// The paper's linear model, one [`LinearStripe`] per stripe.
#[derive(Debug, Clone, PartialEq)]
pub struct LinearModel {
    /// Principal point row and focal length along v, for the normalised row.
    pub cy: f64,
    /// Focal length along v in pixels.
    pub fy: f64,
    /// Stripes, stripe 0 first.
    pub stripes: Vec<LinearStripe>,
}

impl LinearModel {
    /// Height (mm) of stripe `stripe` seen at column `u` on row `v`.
    pub fn height(&self, stripe: usize, u: f64, v: f64) -> Option<f64> {
        let s = self.stripes.get(stripe)?;
        Some(s.height(u, (v - self.cy) / self.fy))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn fitted_planes_recover_the_laser_sheets() {
        let s = Sensor::default();
        for i in 0..s.laser.stripes {
            let sheet = s.laser.plane(i);
            // Points of the sheet at several heights and y, with a little noise.
            let mut pts = Vec::new();
            for (k, z) in [0.0, 5.0, 10.0, 20.0].iter().enumerate() {
                for j in 0..10 {
                    let y = -40.0 + 8.0 * j as f64;
                    let x = s.laser.sheet_x_mm(i, *z);
                    let noise = 1e-3 * (((k * 10 + j) as f64) * 1.7).sin();
                    pts.push(Vector3::new(x + noise, y, *z));
                }
            }
            let (plane, rms) = fit_plane(&pts).expect("plane");
            assert!(rms < 2e-3);
            let sheet_plane = sheet.plane();
            let p = Vector3::new(s.laser.belt_x_mm(i), 3.0, 0.0);
            assert!(plane.distance(&p).abs() < 2e-3);
            assert!(plane.normal.dot(&sheet_plane.normal).abs() > 1.0 - 1e-6);
        }
        assert!(
            fit_plane(&[Vector3::zeros(), Vector3::x(), Vector3::x() * 2.0]).is_none(),
            "collinear"
        );
        assert!(fit_plane(&[Vector3::zeros(), Vector3::x()]).is_none());
    }

    #[test]
    fn the_full_model_inverts_the_projection() {
        let mut s = Sensor::default();
        s.camera.k1 = -0.07;
        let planes: Vec<Plane> = s.laser.planes().iter().map(|p| p.plane()).collect();
        let model = FullModel {
            camera: s.camera.clone(),
            planes,
        };
        for i in [0usize, 5, 10] {
            for (y, z) in [(-30.0, 0.0), (12.0, 7.5), (25.0, 31.0)] {
                let x = s.laser.sheet_x_mm(i, z);
                let w = Vector3::new(x, y, z);
                let (u, v) = s.camera.project(&w).expect("visible");
                let back = model.point(i, u, v).expect("intersects");
                assert!((back - w).norm() < 1e-9, "{back} vs {w}");
            }
        }
        assert!(model.point(11, 300.0, 200.0).is_none());
    }

    #[test]
    fn the_linear_model_is_proportional() {
        let m = LinearModel {
            cy: 100.0,
            fy: 50.0,
            stripes: vec![
                LinearStripe {
                    a: [60.0, 0.0, 0.0],
                    b: [0.2, 0.0, 0.0],
                },
                LinearStripe {
                    a: [100.0, 10.0, 0.0],
                    b: [0.25, 0.0, 0.01],
                },
            ],
        };
        assert_eq!(m.height(0, 290.0, 7.0), Some(2.0));
        assert!((m.height(1, 390.0, 100.0).expect("h") - 2.5).abs() < 1e-12);
        let (u_belt, k) = m.stripes[0].constants(0.0);
        assert!((u_belt - 300.0).abs() < 1e-12 && (k - 0.2).abs() < 1e-12);
        assert!((m.height(1, 390.0, 150.0).expect("h") - (110.0 - 0.26 * 390.0)).abs() < 1e-9);
        assert_eq!(m.height(2, 390.0, 0.0), None);
    }
}
