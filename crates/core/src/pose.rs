use nalgebra::{Matrix3, Matrix3x4, Point3, UnitQuaternion, Vector3};
use serde::{Deserialize, Serialize};

/// A rigid transform `b_from_a`: `point_in_b = b_from_a * point_in_a`.
///
/// Named after the frames it maps between, as COLMAP's `Rigid3d`
/// (`cam_from_world` maps world points into the camera frame).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Rigid3 {
    pub rotation: UnitQuaternion<f64>,
    pub translation: Vector3<f64>,
}

impl Default for Rigid3 {
    fn default() -> Self {
        Self::identity()
    }
}

impl Rigid3 {
    pub fn identity() -> Self {
        Self { rotation: UnitQuaternion::identity(), translation: Vector3::zeros() }
    }

    pub fn new(rotation: UnitQuaternion<f64>, translation: Vector3<f64>) -> Self {
        Self { rotation, translation }
    }

    /// From COLMAP's quaternion order (w, x, y, z) and a translation.
    pub fn from_wxyz(q_wxyz: [f64; 4], t: [f64; 3]) -> Self {
        let [w, x, y, z] = q_wxyz;
        let rotation = UnitQuaternion::from_quaternion(nalgebra::Quaternion::new(w, x, y, z));
        Self { rotation, translation: Vector3::new(t[0], t[1], t[2]) }
    }

    /// The quaternion in COLMAP's order (w, x, y, z).
    pub fn wxyz(&self) -> [f64; 4] {
        let q = self.rotation.quaternion();
        [q.w, q.i, q.j, q.k]
    }

    pub fn inverse(&self) -> Self {
        let rotation = self.rotation.inverse();
        Self { rotation, translation: -(rotation * self.translation) }
    }

    pub fn transform_point(&self, point: &Point3<f64>) -> Point3<f64> {
        self.rotation * point + self.translation
    }

    pub fn rotation_matrix(&self) -> Matrix3<f64> {
        self.rotation.to_rotation_matrix().into_inner()
    }

    /// The 3x4 matrix `[R | t]`.
    pub fn matrix(&self) -> Matrix3x4<f64> {
        let mut m = Matrix3x4::zeros();
        m.fixed_view_mut::<3, 3>(0, 0).copy_from(&self.rotation_matrix());
        m.fixed_view_mut::<3, 1>(0, 3).copy_from(&self.translation);
        m
    }

    /// Where the origin of frame `a` lies in frame `b`'s inverse, i.e. for
    /// `cam_from_world` the camera centre in world coordinates.
    pub fn origin_of_target(&self) -> Point3<f64> {
        Point3::from(-(self.rotation.inverse() * self.translation))
    }
}

impl std::ops::Mul for Rigid3 {
    type Output = Rigid3;
    /// `c_from_b * b_from_a = c_from_a`.
    fn mul(self, b_from_a: Rigid3) -> Rigid3 {
        Rigid3 {
            rotation: self.rotation * b_from_a.rotation,
            translation: self.rotation * b_from_a.translation + self.translation,
        }
    }
}

impl std::ops::Mul<Point3<f64>> for Rigid3 {
    type Output = Point3<f64>;
    fn mul(self, point: Point3<f64>) -> Point3<f64> {
        self.transform_point(&point)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn composition_and_inverse_cancel() {
        let a = Rigid3::new(UnitQuaternion::from_euler_angles(0.1, -0.4, 2.0), Vector3::new(1.0, 2.0, -3.0));
        let id = a * a.inverse();
        assert!(id.translation.norm() < 1e-12);
        assert!(id.rotation.angle() < 1e-12);
        let p = Point3::new(0.3, 0.2, 5.0);
        let back = a.inverse() * (a * p);
        assert!((back - p).norm() < 1e-12);
    }

    #[test]
    fn camera_centre_maps_to_origin() {
        let cam_from_world =
            Rigid3::new(UnitQuaternion::from_euler_angles(0.5, 0.1, -1.0), Vector3::new(0.4, -2.0, 7.0));
        let centre = cam_from_world.origin_of_target();
        assert!((cam_from_world * centre).coords.norm() < 1e-12);
    }

    #[test]
    fn wxyz_round_trip() {
        let q = [0.5f64.sqrt(), 0.0, 0.5f64.sqrt(), 0.0];
        let pose = Rigid3::from_wxyz(q, [1.0, 2.0, 3.0]);
        let back = pose.wxyz();
        for (a, b) in q.iter().zip(back) {
            assert!((a - b).abs() < 1e-15);
        }
    }
}
