//! Whether a pair's matches are true, by the truth: a pair is *wrong* when
//! the median epipolar error of its matches under the true relative pose
//! exceeds a few pixels (issue 11's definition: 4 px). Matches on the same
//! seabed point lie on each other's epipolar lines up to their keypoints'
//! noise; matches of another place, or of a wrong roll, do not.

use nalgebra::{Point2, Vector3};
use revisit_core::{Camera, Rigid3};

/// The largest median epipolar error (pixels) of a pair that counts as right.
pub const MAX_RIGHT_PAIR_ERROR_PX: f64 = 4.0;

/// The median distance (pixels of image 2) of each match's point in image 2
/// from the epipolar line of its point in image 1, under the true poses.
/// `None` without a match that both cameras can unproject.
pub fn median_epipolar_error_px(
    cameras: [&Camera; 2],
    cam1_from_world: &Rigid3,
    cam2_from_world: &Rigid3,
    matches: &[([f64; 2], [f64; 2])],
) -> Option<f64> {
    let cam2_from_cam1 = *cam2_from_world * cam1_from_world.inverse();
    let t = cam2_from_cam1.translation;
    let essential = t.cross_matrix() * cam2_from_cam1.rotation_matrix();
    let mut errors: Vec<f64> = matches
        .iter()
        .filter_map(|(p1, p2)| {
            let ray1 = cameras[0].cam_from_img(&Point2::new(p1[0], p1[1]))?;
            let ray2 = cameras[1].cam_from_img(&Point2::new(p2[0], p2[1]))?;
            // The line in image 2's normalised plane, and the point on that plane.
            let line: Vector3<f64> = essential * (ray1 / ray1.z);
            let point = ray2 / ray2.z;
            let distance = line.dot(&point).abs() / line.x.hypot(line.y);
            distance.is_finite().then_some(distance * cameras[1].focal_px())
        })
        .collect();
    if errors.is_empty() {
        return None;
    }
    errors.sort_by(f64::total_cmp);
    Some(errors[errors.len() / 2])
}

#[cfg(test)]
mod tests {
    use nalgebra::{Point3, UnitQuaternion};
    use revisit_core::CameraModel;

    use super::*;

    #[test]
    fn true_matches_lie_on_their_epipolar_lines_and_others_do_not() {
        let camera = Camera::new(1, CameraModel::Pinhole, 640, 480, vec![512.0, 512.0, 320.0, 240.0]).unwrap();
        let cam1_from_world = Rigid3::identity();
        let cam2_from_world =
            Rigid3::new(UnitQuaternion::from_euler_angles(0.05, -0.02, 1.6), Vector3::new(-0.4, 0.1, 0.05));
        let mut right = Vec::new();
        let mut wrong = Vec::new();
        for k in 0..40 {
            let world = Point3::new(f64::from(k % 8) * 0.3 - 1.0, f64::from(k / 8) * 0.3 - 0.6, 3.0 + f64::from(k % 3));
            let p1 = camera.img_from_cam(&cam1_from_world.transform_point(&world)).unwrap();
            let p2 = camera.img_from_cam(&cam2_from_world.transform_point(&world)).unwrap();
            right.push(([p1.x, p1.y], [p2.x, p2.y]));
            wrong.push(([p1.x, p1.y], [640.0 - p2.y, p2.x]));
        }
        let cameras = [&camera, &camera];
        let error = median_epipolar_error_px(cameras, &cam1_from_world, &cam2_from_world, &right).unwrap();
        assert!(error < 1e-6, "{error}");
        let error = median_epipolar_error_px(cameras, &cam1_from_world, &cam2_from_world, &wrong).unwrap();
        assert!(error > 20.0, "{error}");
        assert_eq!(median_epipolar_error_px(cameras, &cam1_from_world, &cam2_from_world, &[]), None);
    }
}
