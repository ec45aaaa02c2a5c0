//! The sensor: a down-looking pinhole camera with radial distortion, a multi-line laser projector and the
//! conveyor. This is the in-memory form of `sensor.toml` (the file itself is read by `stripe3d-io`).
//!
//! Geometry, in the world frame of `docs/design.md`:
//! - The camera's optical centre is at `(0, 0, height_mm)`, looking along −z. A world point `(x, y, z)` has
//!   normalised coordinates `xn = x / (H − z)`, `yn = −y / (H − z)`; distortion `x_d = xn (1 + k1 r²)` with
//!   `r² = xn² + yn²`; pixel `u = cx + fx x_d`, `v = cy + fy y_d` (pixel centres at integer coordinates).
//! - The projector is a point source at `(source_x_mm, 0, source_z_mm)` whose N laser sheets all contain the line
//!   through the source parallel to y (so every stripe runs along image columns). Sheet `i` meets the belt (z = 0)
//!   along the line `x = center_x_mm + (i − (N − 1)/2) · pitch_mm`; stripe 0 has the smallest x at the belt.
//!   Across its sheet, each beam has a Gaussian profile of standard deviation `sigma_mm`.

use crate::CoreError;
use nalgebra::Vector3;
use serde::{Deserialize, Serialize};

/// Largest number of laser stripes a projector may have.
pub const MAX_STRIPES: usize = 64;
/// Largest image side accepted, in pixels.
pub const MAX_IMAGE_SIDE: u32 = 16_384;

/// The whole sensor: camera, laser projector and (optionally) the conveyor.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Sensor {
    /// The camera.
    pub camera: Camera,
    /// The multi-line laser projector.
    pub laser: Laser,
    /// The conveyor, when frames are taken at a constant speed and frame rate.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub conveyor: Option<Conveyor>,
}

impl Default for Sensor {
    /// The paper's set-up: 648x480 sensor, 14 cm x 10.5 cm field of view at a 10 cm working height, 11 stripes,
    /// conveyor at 1 cm/s filmed at 20 frames/s.
    fn default() -> Self {
        Self {
            camera: Camera::default(),
            laser: Laser::default(),
            conveyor: Some(Conveyor::default()),
        }
    }
}

/// A down-looking pinhole camera with one radial distortion coefficient, and its radiometry.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Camera {
    /// Image width in pixels.
    pub width: u32,
    /// Image height in pixels.
    pub height: u32,
    /// Focal length along u, in pixels.
    pub fx: f64,
    /// Focal length along v, in pixels.
    pub fy: f64,
    /// Principal point column (pixel centres at integer coordinates).
    pub cx: f64,
    /// Principal point row.
    pub cy: f64,
    /// Radial distortion on normalised coordinates: `x_d = x (1 + k1 r²)`.
    #[serde(default)]
    pub k1: f64,
    /// Height of the optical centre above the belt, in mm.
    pub height_mm: f64,
    /// Bits per pixel of the digitised frame: 8, 10, 12 or 16.
    #[serde(default = "defaults::bits")]
    pub bits: u8,
    /// Full-well capacity in electrons (saturation).
    #[serde(default = "defaults::full_well_e")]
    pub full_well_e: f64,
    /// Read noise, electrons RMS.
    #[serde(default = "defaults::read_noise_e")]
    pub read_noise_e: f64,
    /// Electrons collected from a white Lambertian surface lit head-on by the centre of a stripe at unit power,
    /// 200 mm from the projector, on the optical axis. Sets the exposure.
    #[serde(default = "defaults::exposure_e")]
    pub exposure_e: f64,
    /// Standard deviation of the Gaussian optical point-spread function, in pixels (0 = none).
    #[serde(default = "defaults::psf_sigma_px")]
    pub psf_sigma_px: f64,
}

impl Default for Camera {
    fn default() -> Self {
        Self {
            width: 648,
            height: 480,
            // 648 px over 140 mm at 100 mm: f = 648 * 100 / 140.
            fx: 462.857,
            fy: 462.857,
            cx: 323.5,
            cy: 239.5,
            k1: 0.0,
            height_mm: 100.0,
            bits: defaults::bits(),
            full_well_e: defaults::full_well_e(),
            read_noise_e: defaults::read_noise_e(),
            exposure_e: defaults::exposure_e(),
            psf_sigma_px: defaults::psf_sigma_px(),
        }
    }
}

/// The multi-line laser projector.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Laser {
    /// Number of laser sheets (stripes), 1 to 64.
    pub stripes: usize,
    /// x of the projector's point source, in mm.
    #[serde(default = "defaults::source_x_mm")]
    pub source_x_mm: f64,
    /// Height of the projector's point source above the belt, in mm.
    #[serde(default = "defaults::source_z_mm")]
    pub source_z_mm: f64,
    /// x where the middle sheet meets the belt, in mm.
    #[serde(default)]
    pub center_x_mm: f64,
    /// Spacing of the stripes on the belt, in mm.
    #[serde(default = "defaults::pitch_mm")]
    pub pitch_mm: f64,
    /// Standard deviation of the Gaussian beam profile across each sheet, in mm.
    #[serde(default = "defaults::sigma_mm")]
    pub sigma_mm: f64,
    /// Relative laser power (1 = the exposure reference of [`Camera::exposure_e`]).
    #[serde(default = "defaults::power")]
    pub power: f64,
    /// Speckle contrast (standard deviation over mean of the speckle intensity within one pixel), 0 to 1.
    #[serde(default = "defaults::speckle_contrast")]
    pub speckle_contrast: f64,
}

impl Default for Laser {
    fn default() -> Self {
        Self {
            stripes: 11,
            source_x_mm: defaults::source_x_mm(),
            source_z_mm: defaults::source_z_mm(),
            center_x_mm: 0.0,
            pitch_mm: defaults::pitch_mm(),
            sigma_mm: defaults::sigma_mm(),
            power: defaults::power(),
            speckle_contrast: defaults::speckle_contrast(),
        }
    }
}

/// The conveyor: constant speed, constant frame rate.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Conveyor {
    /// Belt speed along +x, mm/s.
    pub speed_mm_s: f64,
    /// Frames per second.
    pub fps: f64,
}

impl Default for Conveyor {
    fn default() -> Self {
        Self {
            speed_mm_s: 10.0,
            fps: 20.0,
        }
    }
}

impl Conveyor {
    /// Belt travel since frame 0 at frame `frame`, in mm.
    pub fn travel_mm(&self, frame: usize) -> f64 {
        self.speed_mm_s * frame as f64 / self.fps
    }

    /// Belt travel between consecutive frames, in mm.
    pub fn step_mm(&self) -> f64 {
        self.travel_mm(1) - self.travel_mm(0)
    }
}

mod defaults {
    pub fn bits() -> u8 {
        8
    }
    pub fn full_well_e() -> f64 {
        10_000.0
    }
    pub fn read_noise_e() -> f64 {
        6.0
    }
    // A matte grey part (albedo 0.6) under a 45 degree stripe then reads about 60 % of full scale.
    pub fn exposure_e() -> f64 {
        14_000.0
    }
    pub fn psf_sigma_px() -> f64 {
        0.5
    }
    // With the source at (-150, 150) the 11 default sheets meet the belt at 34 to 53 degrees from vertical:
    // about one pixel of image shift per 0.22 mm of height, the paper's depth resolution.
    pub fn source_x_mm() -> f64 {
        -150.0
    }
    pub fn source_z_mm() -> f64 {
        150.0
    }
    pub fn pitch_mm() -> f64 {
        10.0
    }
    // 0.25 mm across the sheet is about 1.6 px across the stripe in the default image.
    pub fn sigma_mm() -> f64 {
        0.25
    }
    pub fn power() -> f64 {
        1.0
    }
    pub fn speckle_contrast() -> f64 {
        0.05
    }
}

/// One laser sheet: the plane through the projector's source line and the stripe's line on the belt.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LaserPlane {
    /// Unit normal, pointing towards +x (so the signed distance grows along +x).
    pub normal: Vector3<f64>,
    /// A point of the plane: the projector's source.
    pub source: Vector3<f64>,
}

impl LaserPlane {
    /// Signed distance of `p` from the sheet's centre plane, in mm (positive on the +x side).
    #[inline]
    pub fn signed_distance(&self, p: &Vector3<f64>) -> f64 {
        self.normal.dot(&(p - self.source))
    }

    /// The sheet's centre plane.
    pub fn plane(&self) -> crate::geometry::Plane {
        crate::geometry::Plane::through(&self.source, &self.normal)
    }

    /// Tangent of the sheet's angle from the vertical: how far (mm) the stripe moves towards −x per mm of height.
    pub fn tan_angle(&self) -> f64 {
        self.normal.z / self.normal.x
    }
}

impl Laser {
    /// x where sheet `i` meets the belt, in mm.
    pub fn belt_x_mm(&self, i: usize) -> f64 {
        self.center_x_mm + (i as f64 - (self.stripes as f64 - 1.0) / 2.0) * self.pitch_mm
    }

    /// x where sheet `i`'s centre plane crosses height `z_mm` (it contains lines parallel to y).
    pub fn sheet_x_mm(&self, i: usize, z_mm: f64) -> f64 {
        self.source_x_mm
            + (self.source_z_mm - z_mm) * (self.belt_x_mm(i) - self.source_x_mm) / self.source_z_mm
    }

    /// The source of the projector in world coordinates.
    pub fn source(&self) -> Vector3<f64> {
        Vector3::new(self.source_x_mm, 0.0, self.source_z_mm)
    }

    /// Sheet `i` as a plane.
    pub fn plane(&self, i: usize) -> LaserPlane {
        let dx = self.belt_x_mm(i) - self.source_x_mm;
        // Direction from the source to the belt line is (dx, 0, -z_s); the normal is perpendicular to it and to y.
        let normal = Vector3::new(self.source_z_mm, 0.0, dx).normalize();
        LaserPlane {
            normal,
            source: self.source(),
        }
    }

    /// All sheets, stripe 0 first.
    pub fn planes(&self) -> Vec<LaserPlane> {
        (0..self.stripes).map(|i| self.plane(i)).collect()
    }
}

impl Camera {
    /// Applies radial distortion to normalised coordinates.
    #[inline]
    pub fn distort(&self, xn: f64, yn: f64) -> (f64, f64) {
        let s = 1.0 + self.k1 * (xn * xn + yn * yn);
        (xn * s, yn * s)
    }

    /// Removes radial distortion (Newton's method on the radius; exact to rounding inside the valid field).
    pub fn undistort(&self, xd: f64, yd: f64) -> (f64, f64) {
        let rd = (xd * xd + yd * yd).sqrt();
        if self.k1 == 0.0 || rd == 0.0 {
            return (xd, yd);
        }
        let mut r = rd;
        for _ in 0..50 {
            let f = r + self.k1 * r * r * r - rd;
            let step = f / (1.0 + 3.0 * self.k1 * r * r);
            r -= step;
            if step.abs() < 1e-15 * (1.0 + r) {
                break;
            }
        }
        let s = r / rd;
        (xd * s, yd * s)
    }

    /// Undistorted normalised coordinates of the pixel `(u, v)`.
    #[inline]
    pub fn normalized(&self, u: f64, v: f64) -> (f64, f64) {
        self.undistort((u - self.cx) / self.fx, (v - self.cy) / self.fy)
    }

    /// The camera's optical centre in world coordinates.
    pub fn centre(&self) -> Vector3<f64> {
        Vector3::new(0.0, 0.0, self.height_mm)
    }

    /// Direction of the ray through pixel `(u, v)` in world coordinates, scaled so that its z component is −1
    /// (a step of 1 along it descends 1 mm).
    pub fn ray_direction(&self, u: f64, v: f64) -> Vector3<f64> {
        let (xn, yn) = self.normalized(u, v);
        Vector3::new(xn, -yn, -1.0)
    }

    /// Pixel `(u, v)` of a world point, or `None` when it is not in front of the camera.
    pub fn project(&self, p: &Vector3<f64>) -> Option<(f64, f64)> {
        let depth = self.height_mm - p.z;
        if depth <= 0.0 {
            return None;
        }
        let (xd, yd) = self.distort(p.x / depth, -p.y / depth);
        Some((self.cx + self.fx * xd, self.cy + self.fy * yd))
    }

    /// Size on the belt of one pixel at the image centre, in mm.
    pub fn belt_pixel_mm(&self) -> f64 {
        self.height_mm / self.fx
    }
}

fn invalid(field: &'static str, value: impl ToString, reason: impl Into<String>) -> CoreError {
    CoreError::InvalidSensor {
        field,
        value: value.to_string(),
        reason: reason.into(),
    }
}

fn finite(field: &'static str, v: f64) -> Result<f64, CoreError> {
    if v.is_finite() {
        Ok(v)
    } else {
        Err(invalid(field, v, "must be a finite number"))
    }
}

fn positive(field: &'static str, v: f64) -> Result<f64, CoreError> {
    if finite(field, v)? > 0.0 {
        Ok(v)
    } else {
        Err(invalid(field, v, "must be greater than zero"))
    }
}

impl Sensor {
    /// Checks that the sensor is physically possible and every stripe is in view; the error names the field.
    pub fn validate(&self) -> Result<(), CoreError> {
        let c = &self.camera;
        if c.width == 0 || c.width > MAX_IMAGE_SIDE {
            return Err(invalid(
                "camera.width",
                c.width,
                format!("must be 1 to {MAX_IMAGE_SIDE} pixels"),
            ));
        }
        if c.height == 0 || c.height > MAX_IMAGE_SIDE {
            return Err(invalid(
                "camera.height",
                c.height,
                format!("must be 1 to {MAX_IMAGE_SIDE} pixels"),
            ));
        }
        positive("camera.fx", c.fx)?;
        positive("camera.fy", c.fy)?;
        finite("camera.cx", c.cx)?;
        finite("camera.cy", c.cy)?;
        finite("camera.k1", c.k1)?;
        positive("camera.height_mm", c.height_mm)?;
        if ![8, 10, 12, 16].contains(&c.bits) {
            return Err(invalid("camera.bits", c.bits, "must be 8, 10, 12 or 16"));
        }
        positive("camera.full_well_e", c.full_well_e)?;
        if finite("camera.read_noise_e", c.read_noise_e)? < 0.0 {
            return Err(invalid(
                "camera.read_noise_e",
                c.read_noise_e,
                "must not be negative",
            ));
        }
        positive("camera.exposure_e", c.exposure_e)?;
        if finite("camera.psf_sigma_px", c.psf_sigma_px)? < 0.0 || c.psf_sigma_px > 20.0 {
            return Err(invalid(
                "camera.psf_sigma_px",
                c.psf_sigma_px,
                "must be 0 to 20 pixels",
            ));
        }
        // The distortion must stay monotonic out to the image corners, or pixels would map to two rays.
        if c.k1 < 0.0 {
            let corner_x = (c.cx.abs().max((c.width as f64 - 1.0 - c.cx).abs())) / c.fx;
            let corner_y = (c.cy.abs().max((c.height as f64 - 1.0 - c.cy).abs())) / c.fy;
            let r2 = corner_x * corner_x + corner_y * corner_y;
            if 1.0 + 3.0 * c.k1 * r2 * 1.5 <= 0.0 {
                return Err(invalid(
                    "camera.k1",
                    c.k1,
                    "folds the image over before its corners; use a smaller |k1|",
                ));
            }
        }
        let l = &self.laser;
        if l.stripes == 0 || l.stripes > MAX_STRIPES {
            return Err(invalid(
                "laser.stripes",
                l.stripes,
                format!("must be 1 to {MAX_STRIPES}"),
            ));
        }
        finite("laser.source_x_mm", l.source_x_mm)?;
        positive("laser.source_z_mm", l.source_z_mm)?;
        finite("laser.center_x_mm", l.center_x_mm)?;
        if l.stripes > 1 {
            positive("laser.pitch_mm", l.pitch_mm)?;
        } else {
            finite("laser.pitch_mm", l.pitch_mm)?;
        }
        positive("laser.sigma_mm", l.sigma_mm)?;
        positive("laser.power", l.power)?;
        if !(0.0..=1.0).contains(&finite("laser.speckle_contrast", l.speckle_contrast)?) {
            return Err(invalid(
                "laser.speckle_contrast",
                l.speckle_contrast,
                "must be 0 to 1",
            ));
        }
        for i in 0..l.stripes {
            let x = l.belt_x_mm(i);
            let (u, v) = c
                .project(&Vector3::new(x, 0.0, 0.0))
                .unwrap_or((f64::NAN, f64::NAN));
            let inside =
                u >= 0.0 && u <= c.width as f64 - 1.0 && v >= 0.0 && v <= c.height as f64 - 1.0;
            if !inside {
                return Err(invalid(
                    "laser.stripes",
                    l.stripes,
                    format!(
                        "stripe {i} meets the belt at x = {x:.2} mm, image column {u:.1}, outside the {} px wide view; \
                         reduce laser.pitch_mm or laser.stripes, or move laser.center_x_mm",
                        c.width
                    ),
                ));
            }
            if (x - l.source_x_mm).abs() < 1e-9 {
                return Err(invalid(
                    "laser.source_x_mm",
                    l.source_x_mm,
                    format!("stripe {i} would be vertical under the source; move the source aside"),
                ));
            }
        }
        if let Some(cv) = &self.conveyor {
            if finite("conveyor.speed_mm_s", cv.speed_mm_s)? < 0.0 {
                return Err(invalid(
                    "conveyor.speed_mm_s",
                    cv.speed_mm_s,
                    "must not be negative",
                ));
            }
            positive("conveyor.fps", cv.fps)?;
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn default_sensor_is_valid_and_has_the_papers_field_of_view() {
        let s = Sensor::default();
        s.validate().expect("valid");
        let fov = s.camera.width as f64 * s.camera.belt_pixel_mm();
        assert!((fov - 140.0).abs() < 0.01, "{fov}");
    }

    #[test]
    fn project_and_ray_are_inverse() {
        let c = Camera {
            k1: -0.08,
            ..Camera::default()
        };
        let p = Vector3::new(31.0, -22.0, 7.5);
        let (u, v) = c.project(&p).expect("in front");
        let d = c.ray_direction(u, v);
        let q = c.centre() + d * (c.height_mm - p.z);
        assert!((q - p).norm() < 1e-9, "{q} vs {p}");
        // v runs along -y
        let (_, v_up) = c.project(&Vector3::new(0.0, 10.0, 0.0)).expect("in front");
        assert!(v_up < c.cy);
    }

    #[test]
    fn planes_meet_the_belt_where_configured() {
        let l = Laser::default();
        for i in 0..l.stripes {
            let p = l.plane(i);
            let on_belt = Vector3::new(l.belt_x_mm(i), 17.0, 0.0);
            assert!(p.signed_distance(&on_belt).abs() < 1e-12);
            assert!(p.signed_distance(&(on_belt + Vector3::new(1.0, 0.0, 0.0))) > 0.0);
            assert!(p.tan_angle() > 0.0);
        }
    }

    #[test]
    fn impossible_geometry_is_refused_with_the_field() {
        let mut s = Sensor::default();
        s.camera.fx = 0.0;
        assert!(matches!(
            s.validate(),
            Err(CoreError::InvalidSensor {
                field: "camera.fx",
                ..
            })
        ));
        let mut s = Sensor::default();
        s.laser.pitch_mm = 40.0;
        assert!(matches!(
            s.validate(),
            Err(CoreError::InvalidSensor {
                field: "laser.stripes",
                ..
            })
        ));
        let mut s = Sensor::default();
        s.camera.cy = f64::NAN;
        assert!(matches!(
            s.validate(),
            Err(CoreError::InvalidSensor {
                field: "camera.cy",
                ..
            })
        ));
        let mut s = Sensor::default();
        s.laser.stripes = 65;
        assert!(s.validate().is_err());
    }
}
