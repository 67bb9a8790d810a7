//! Similarity alignment of point sets (Umeyama 1991).

use crate::Rigid3;
use nalgebra::{Matrix3, Point3, Rotation3, UnitQuaternion, Vector3};
use serde::Serialize;

/// `dst = scale * rotation * src + translation`.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct Similarity {
    pub scale: f64,
    pub rotation: UnitQuaternion<f64>,
    pub translation: Vector3<f64>,
}

impl Similarity {
    pub fn identity() -> Self {
        Similarity { scale: 1.0, rotation: UnitQuaternion::identity(), translation: Vector3::zeros() }
    }

    pub fn apply(&self, point: &Point3<f64>) -> Point3<f64> {
        Point3::from(self.rotation * point.coords * self.scale + self.translation)
    }

    /// The rigid part, for [`crate::Reconstruction::transform`]
    /// (which takes the scale separately).
    pub fn rigid(&self) -> Rigid3 {
        Rigid3::new(self.rotation, self.translation)
    }
}

#[derive(Debug, thiserror::Error, PartialEq)]
pub enum AlignError {
    #[error("{src} source points but {dst} target points")]
    LengthMismatch { src: usize, dst: usize },
    #[error("{0} point pairs: a similarity needs at least 3")]
    TooFew(usize),
    #[error("the points are degenerate (coincident or collinear): no unique similarity")]
    Degenerate,
}

/// The least-squares similarity taking `src` onto `dst` (Umeyama 1991, with
/// the reflection guard).
pub fn umeyama(src: &[Point3<f64>], dst: &[Point3<f64>]) -> Result<Similarity, AlignError> {
    if src.len() != dst.len() {
        return Err(AlignError::LengthMismatch { src: src.len(), dst: dst.len() });
    }
    let n = src.len();
    if n < 3 {
        return Err(AlignError::TooFew(n));
    }
    let inv_n = 1.0 / n as f64;
    let mean_src = src.iter().fold(Vector3::zeros(), |acc, p| acc + p.coords) * inv_n;
    let mean_dst = dst.iter().fold(Vector3::zeros(), |acc, p| acc + p.coords) * inv_n;
    let mut covariance = Matrix3::zeros();
    let mut variance_src = 0.0;
    for (s, d) in src.iter().zip(dst) {
        let (sc, dc) = (s.coords - mean_src, d.coords - mean_dst);
        covariance += dc * sc.transpose();
        variance_src += sc.norm_squared();
    }
    covariance *= inv_n;
    variance_src *= inv_n;
    let svd = covariance.svd(true, true);
    let (Some(u), Some(v_t)) = (svd.u, svd.v_t) else {
        return Err(AlignError::Degenerate);
    };
    let singular = svd.singular_values;
    // Sort-independent rank check: nalgebra returns singular values unsorted.
    let mut sorted = [singular.x, singular.y, singular.z];
    sorted.sort_by(|a, b| b.total_cmp(a));
    if variance_src <= f64::EPSILON || sorted[1] <= 1e-12 * sorted[0].max(f64::MIN_POSITIVE) {
        return Err(AlignError::Degenerate);
    }
    let mut sign = Matrix3::identity();
    if u.determinant() * v_t.determinant() < 0.0 {
        // Flip the axis of the smallest singular value.
        let smallest = (0..3).min_by(|&a, &b| singular[a].total_cmp(&singular[b])).unwrap_or(2);
        sign[(smallest, smallest)] = -1.0;
    }
    let rotation = u * sign * v_t;
    let scale = (Matrix3::from_diagonal(&singular) * sign).trace() / variance_src;
    let translation = mean_dst - rotation * mean_src * scale;
    let rotation = UnitQuaternion::from_rotation_matrix(&Rotation3::from_matrix_unchecked(rotation));
    Ok(Similarity { scale, rotation, translation })
}
