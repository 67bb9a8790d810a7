//! A vehicle's navigation: where each image's camera was, by the vehicle's own sensors (a
//! DVL-aided INS with a position fix, or odometry), in the navigation frame.

use nalgebra::{Matrix3, Point3, Vector3};

/// One image's navigation position, metres in the navigation frame.
#[derive(Clone, Debug, PartialEq)]
pub struct NavigationFix {
    /// `session/file`.
    pub image: String,
    pub position_m: Point3<f64>,
    /// Standard deviation per axis, metres, when the source gives it.
    pub sigma_m: Option<Vector3<f64>>,
}

impl NavigationFix {
    /// The position's covariance, m² (axes independent), when its deviations are known.
    pub fn covariance_m2(&self) -> Option<Matrix3<f64>> {
        self.sigma_m.map(|sigma| Matrix3::from_diagonal(&sigma.component_mul(&sigma)))
    }
}
