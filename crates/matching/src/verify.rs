use kornia_3d::pose::{ransac_fundamental, RansacParams};
use kornia_algebra::Vec2F64;
use nalgebra::Matrix3;
use revisit_core::{Keypoint, TwoViewConfig, TwoViewGeometry};
use serde::{Deserialize, Serialize};

use crate::{check_range, OptionsError};

/// Geometric verification of putative matches by a seeded fundamental-matrix
/// RANSAC (kornia-3d: 8-point minimal solver, Sampson error, local
/// optimisation and DEGENSAC recovery for dominant planes).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct VerifyOptions {
    /// Largest epipolar (Sampson) error of an inlier, pixels. Default 4 (COLMAP's).
    pub max_error_px: f64,
    /// Fewer inliers than this and the pair is degenerate. Default 15 (COLMAP's).
    pub min_inliers: usize,
    /// Fewer inliers than this share of the matches and the pair is
    /// degenerate. Default 0.25 (COLMAP's `min_inlier_ratio`).
    pub min_inlier_ratio: f64,
    /// RANSAC iteration cap (the loop stops earlier at 99.99% confidence). Default 10000.
    pub max_iterations: usize,
    /// RANSAC seed. Default 0.
    pub seed: u64,
}

impl Default for VerifyOptions {
    fn default() -> Self {
        Self { max_error_px: 4.0, min_inliers: 15, min_inlier_ratio: 0.25, max_iterations: 10_000, seed: 0 }
    }
}

impl VerifyOptions {
    pub fn check(&self) -> Result<(), OptionsError> {
        check_range("max_error_px", self.max_error_px, 1e-3, 1e3, "in [0.001, 1000]")?;
        check_range("min_inliers", self.min_inliers, 8, usize::MAX, "at least 8")?;
        check_range("min_inlier_ratio", self.min_inlier_ratio, 0.0, 1.0, "in [0, 1]")
    }
}

/// Verifies `matches` (`[index in image 1, index in image 2]`) between the
/// keypoints of two images. Pairs with fewer than `min_inliers` inliers come
/// back [`TwoViewConfig::Degenerate`] with no inliers; others
/// [`TwoViewConfig::Uncalibrated`] with the fundamental matrix.
pub fn verify(
    keypoints1: &[Keypoint],
    keypoints2: &[Keypoint],
    matches: &[[u32; 2]],
    options: &VerifyOptions,
) -> TwoViewGeometry {
    let mut x1 = Vec::with_capacity(matches.len());
    let mut x2 = Vec::with_capacity(matches.len());
    let mut valid = Vec::with_capacity(matches.len());
    for m in matches {
        let (Some(a), Some(b)) = (keypoints1.get(m[0] as usize), keypoints2.get(m[1] as usize)) else {
            continue;
        };
        x1.push(Vec2F64::new(f64::from(a.x), f64::from(a.y)));
        x2.push(Vec2F64::new(f64::from(b.x), f64::from(b.y)));
        valid.push(*m);
    }
    if valid.len() < options.min_inliers.max(8) {
        return TwoViewGeometry::degenerate();
    }
    let params = RansacParams {
        max_iterations: options.max_iterations,
        threshold: options.max_error_px,
        min_inliers: options.min_inliers,
        random_seed: Some(options.seed),
        refit: true,
    };
    let Ok(result) = ransac_fundamental(&x1, &x2, &params) else {
        return TwoViewGeometry::degenerate();
    };
    let inlier_matches: Vec<[u32; 2]> =
        valid.iter().zip(&result.inliers).filter(|(_, &inlier)| inlier).map(|(m, _)| *m).collect();
    let ratio = inlier_matches.len() as f64 / valid.len() as f64;
    if inlier_matches.len() < options.min_inliers || ratio < options.min_inlier_ratio {
        return TwoViewGeometry::degenerate();
    }
    // kornia's matrices are column-major, as nalgebra's storage.
    let f = Matrix3::from_column_slice(&result.model.to_cols_array());
    TwoViewGeometry {
        config: TwoViewConfig::Uncalibrated,
        inlier_matches,
        f: Some(f),
        e: None,
        h: None,
        cam2_from_cam1: None,
    }
}

#[cfg(test)]
mod tests {
    use nalgebra::{Point3, UnitQuaternion, Vector3};
    use revisit_core::{Camera, CameraModel, Rigid3};

    use super::*;

    /// Two views of a random 3D cloud with a share of wrong matches mixed in.
    fn two_views(outlier_every: usize) -> (Vec<Keypoint>, Vec<Keypoint>, Vec<[u32; 2]>, usize) {
        let camera = Camera::new(1, CameraModel::Pinhole, 640, 480, vec![500.0, 500.0, 320.0, 240.0]).unwrap();
        let cam2_from_cam1 =
            Rigid3::new(UnitQuaternion::from_euler_angles(0.05, -0.1, 0.3), Vector3::new(-0.5, 0.05, 0.1));
        let (mut k1, mut k2, mut matches) = (vec![], vec![], vec![]);
        let mut outliers = 0;
        let mut state = 12345u64;
        let mut rand = || {
            state = state.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
            (state >> 33) as f64 / f64::from(1u32 << 31)
        };
        for i in 0..200u32 {
            let p = Point3::new(rand() * 4.0 - 2.0, rand() * 3.0 - 1.5, 4.0 + rand() * 3.0);
            let a = camera.img_from_cam(&p).unwrap();
            let mut b = camera.img_from_cam(&(cam2_from_cam1 * p)).unwrap();
            if (i as usize).is_multiple_of(outlier_every) {
                b = nalgebra::Point2::new(rand() * 640.0, rand() * 480.0);
                outliers += 1;
            }
            k1.push(Keypoint { x: a.x as f32, y: a.y as f32, scale: 1.0, orientation: 0.0 });
            k2.push(Keypoint { x: b.x as f32, y: b.y as f32, scale: 1.0, orientation: 0.0 });
            matches.push([i, i]);
        }
        (k1, k2, matches, 200 - outliers)
    }

    #[test]
    fn finds_the_inliers_among_outliers() {
        let (k1, k2, matches, true_inliers) = two_views(4);
        let geometry = verify(&k1, &k2, &matches, &VerifyOptions::default());
        assert_eq!(geometry.config, TwoViewConfig::Uncalibrated);
        let found = geometry.inlier_matches.len();
        assert!(found >= true_inliers && found <= true_inliers + 5, "{found} vs {true_inliers}");
        assert!(geometry.inlier_matches.iter().all(|m| m[0] % 4 != 0 || found > true_inliers));
    }

    #[test]
    fn random_matches_are_degenerate() {
        let (k1, mut k2, matches, _) = two_views(1000);
        k2.reverse();
        let geometry = verify(&k1, &k2, &matches, &VerifyOptions::default());
        assert_eq!(geometry.config, TwoViewConfig::Degenerate);
        assert!(geometry.inlier_matches.is_empty());
    }

    #[test]
    fn same_seed_same_result() {
        let (k1, k2, matches, _) = two_views(3);
        let a = verify(&k1, &k2, &matches, &VerifyOptions::default());
        let b = verify(&k1, &k2, &matches, &VerifyOptions::default());
        assert_eq!(a, b);
    }
}
