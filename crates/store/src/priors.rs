//! Pose priors: each image's position by the vehicle's navigation, in COLMAP's own
//! `pose_priors` table (COLMAP 4's schema), where pycolmap's mapping reads them.

use nalgebra::{Matrix3, Point3};
use revisit_core::{CameraId, ImageId};
use rusqlite::params;

use crate::{blob, Result, Store};

/// COLMAP's `SensorType::CAMERA`.
const SENSOR_CAMERA: i64 = 0;
/// COLMAP's `PosePrior::CoordinateSystem::CARTESIAN` (metres in a local frame, not WGS84).
const CARTESIAN: i64 = 1;

/// One image's position prior.
#[derive(Clone, Debug, PartialEq)]
pub struct PosePrior {
    pub image_id: ImageId,
    /// The image's camera (COLMAP keys a prior by the sensor that took the image).
    pub camera_id: CameraId,
    /// The camera centre in the navigation frame, metres.
    pub position_m: Point3<f64>,
    /// Its covariance, m²; `None` when unknown (COLMAP then assumes 1 m per axis).
    pub covariance_m2: Option<Matrix3<f64>>,
}

impl Store {
    /// Writes `priors` in one transaction, replacing an image's earlier prior.
    pub fn write_pose_priors(&mut self, priors: &[PosePrior]) -> Result<()> {
        let path = self.path.clone();
        let sql = |source| crate::StoreError::Sqlite { path: path.clone(), source };
        let tx = self.conn.transaction().map_err(sql)?;
        for prior in priors {
            let covariance = prior.covariance_m2.unwrap_or_else(|| Matrix3::from_element(f64::NAN));
            tx.execute(
                "INSERT OR REPLACE INTO pose_priors (corr_data_id, corr_sensor_id, corr_sensor_type, position, \
                 position_covariance, gravity, coordinate_system) VALUES (?1, ?2, ?3, ?4, ?5, ?6, ?7)",
                params![
                    prior.image_id,
                    prior.camera_id,
                    SENSOR_CAMERA,
                    blob::f64s(prior.position_m.coords.as_slice()),
                    blob::matrix_row_major(&covariance),
                    blob::f64s(&[f64::NAN; 3]),
                    CARTESIAN,
                ],
            )
            .map_err(sql)?;
        }
        tx.commit().map_err(sql)
    }

    /// Every image's position prior, by image id.
    pub fn pose_priors(&self) -> Result<Vec<PosePrior>> {
        let mut stmt = self
            .conn
            .prepare(
                "SELECT corr_data_id, corr_sensor_id, position, position_covariance FROM pose_priors \
                 WHERE corr_sensor_type = ?1 ORDER BY corr_data_id",
            )
            .map_err(|e| self.sql(e))?;
        let rows = stmt
            .query_map([SENSOR_CAMERA], |r| {
                Ok((
                    r.get::<_, ImageId>(0)?,
                    r.get::<_, CameraId>(1)?,
                    r.get::<_, Vec<u8>>(2)?,
                    r.get::<_, Vec<u8>>(3)?,
                ))
            })
            .map_err(|e| self.sql(e))?;
        let mut priors = Vec::new();
        for row in rows {
            let (image_id, camera_id, position, covariance) = row.map_err(|e| self.sql(e))?;
            let corrupt = |what: &str| self.corrupt(format!("pose prior of image {image_id}"), what);
            let position = blob::to_f64s(&position).filter(|p| p.len() == 3).ok_or_else(|| corrupt("position"))?;
            let covariance =
                blob::to_f64s(&covariance).filter(|c| c.len() == 9).ok_or_else(|| corrupt("position covariance"))?;
            let covariance = Matrix3::from_row_slice(&covariance);
            priors.push(PosePrior {
                image_id,
                camera_id,
                position_m: Point3::new(position[0], position[1], position[2]),
                covariance_m2: covariance.iter().all(|v| v.is_finite()).then_some(covariance),
            });
        }
        Ok(priors)
    }
}
