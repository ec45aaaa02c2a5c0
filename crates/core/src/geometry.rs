//! Geometry shared by the stages: the one plane type ([`Plane`], `normal · p = offset`) and its total-least-squares
//! fit ([`fit_plane`]: the smallest singular vector of the centred points). A laser sheet
//! ([`crate::sensor::LaserPlane`]) is a [`Plane`] with the projector's source point on it
//! ([`crate::sensor::LaserPlane::plane`]); the calibrated stripes are [`Plane`]s.

use nalgebra::{Matrix3, Vector3};

/// A plane `normal · p = offset` with a unit normal.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Plane {
    /// Unit normal.
    pub normal: Vector3<f64>,
    /// Signed distance of the origin along the normal, mm.
    pub offset: f64,
}

impl Plane {
    /// Signed distance of `p` from the plane, mm.
    pub fn distance(&self, p: &Vector3<f64>) -> f64 {
        self.normal.dot(p) - self.offset
    }

    /// The plane through `point` with unit `normal`.
    pub fn through(point: &Vector3<f64>, normal: &Vector3<f64>) -> Plane {
        let n = normal.normalize();
        Plane {
            normal: n,
            offset: n.dot(point),
        }
    }
}

/// The best plane through `points` in the total-least-squares sense, with the RMS distance of the points from it
/// (mm); `None` for fewer than three points or points on a line.
pub fn fit_plane(points: &[Vector3<f64>]) -> Option<(Plane, f64)> {
    if points.len() < 3 {
        return None;
    }
    let centroid = points.iter().fold(Vector3::zeros(), |a, p| a + p) / points.len() as f64;
    let mut scatter = Matrix3::zeros();
    for p in points {
        let d = p - centroid;
        scatter += d * d.transpose();
    }
    let eig = scatter.symmetric_eigen();
    let (mut min_i, mut mid) = (0, f64::INFINITY);
    for i in 0..3 {
        if eig.eigenvalues[i] < mid {
            mid = eig.eigenvalues[i];
            min_i = i;
        }
    }
    // A line has two vanishing eigenvalues: no unique plane.
    let mut sorted = [eig.eigenvalues[0], eig.eigenvalues[1], eig.eigenvalues[2]];
    sorted.sort_by(f64::total_cmp);
    if sorted[1] <= 1e-12 * sorted[2].max(1e-300) {
        return None;
    }
    let normal = eig.eigenvectors.column(min_i).into_owned();
    let plane = Plane::through(&centroid, &normal);
    let rms = (points
        .iter()
        .map(|p| plane.distance(p).powi(2))
        .sum::<f64>()
        / points.len() as f64)
        .sqrt();
    Some((plane, rms))
}
