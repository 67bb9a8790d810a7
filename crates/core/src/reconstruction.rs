use std::collections::BTreeMap;

use nalgebra::{Point2, Point3};
use serde::{Deserialize, Serialize};

use crate::{Camera, CameraId, ImageId, Point3DId, Rigid3};

/// A 2D observation in a model image: pixel position and the 3D point it
/// belongs to, if it was triangulated.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Observation {
    pub xy: Point2<f64>,
    pub point3d_id: Option<Point3DId>,
}

/// A registered image of a model.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Image {
    pub image_id: ImageId,
    pub camera_id: CameraId,
    /// `session/file`, see [`crate::ImageName`].
    pub name: String,
    pub cam_from_world: Rigid3,
    pub points2d: Vec<Observation>,
}

/// One element of a 3D point's track: which image and which of its 2D points.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct TrackElement {
    pub image_id: ImageId,
    pub point2d_idx: u32,
}

/// A triangulated point in world coordinates.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Point3D {
    pub xyz: Point3<f64>,
    pub rgb: [u8; 3],
    /// Mean reprojection error in pixels (COLMAP's `error`; -1 if unknown).
    pub error: f64,
    pub track: Vec<TrackElement>,
}

/// A sparse model as COLMAP writes it: cameras, registered images, points.
/// Maps are ordered by id so that writing a model is deterministic.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Reconstruction {
    pub cameras: BTreeMap<CameraId, Camera>,
    pub images: BTreeMap<ImageId, Image>,
    pub points3d: BTreeMap<Point3DId, Point3D>,
}

impl Reconstruction {
    /// The image of a given name, if registered.
    pub fn image_by_name(&self, name: &str) -> Option<&Image> {
        self.images.values().find(|image| image.name == name)
    }

    /// Projects a world point into a registered image (pixels).
    pub fn project(&self, image: &Image, point_in_world: &Point3<f64>) -> Option<Point2<f64>> {
        let camera = self.cameras.get(&image.camera_id)?;
        camera.img_from_cam(&(image.cam_from_world * *point_in_world))
    }

    /// Applies a similarity `new_from_old` (scale, then rigid) to every pose and
    /// point: `x_new = scale * R x_old + t`.
    pub fn transform(&mut self, scale: f64, new_from_old: &Rigid3) {
        for point in self.points3d.values_mut() {
            let scaled = Point3::from(point.xyz.coords * scale);
            point.xyz = *new_from_old * scaled;
        }
        for image in self.images.values_mut() {
            // cam_from_new = cam_from_old * old_from_new, with the scale folded
            // into the translation so that the camera stays metric.
            let world_from_cam = image.cam_from_world.inverse();
            let centre_new = *new_from_old * Point3::from(world_from_cam.translation * scale);
            let rotation_new = new_from_old.rotation * world_from_cam.rotation;
            image.cam_from_world = Rigid3::new(rotation_new, centre_new.coords).inverse();
        }
    }
}

#[cfg(test)]
mod tests {
    use nalgebra::{UnitQuaternion, Vector3};

    use super::*;
    use crate::CameraModel;

    #[test]
    fn similarity_keeps_projections() {
        let mut model = Reconstruction::default();
        model
            .cameras
            .insert(1, Camera::new(1, CameraModel::Pinhole, 640, 480, vec![500.0, 500.0, 320.0, 240.0]).unwrap());
        let image = Image {
            image_id: 1,
            camera_id: 1,
            name: "a/1.png".into(),
            cam_from_world: Rigid3::new(UnitQuaternion::from_euler_angles(0.1, 0.2, 0.3), Vector3::new(0.1, 0.0, 3.0)),
            points2d: vec![],
        };
        model.images.insert(1, image);
        let point = Point3::new(0.2, -0.1, 0.5);
        model.points3d.insert(1, Point3D { xyz: point, rgb: [0; 3], error: 0.0, track: vec![] });
        let before = model.project(&model.images[&1], &point).unwrap();
        let sim = Rigid3::new(UnitQuaternion::from_euler_angles(1.0, -0.5, 2.0), Vector3::new(5.0, 1.0, -2.0));
        model.transform(2.5, &sim);
        let after = model.project(&model.images[&1], &model.points3d[&1].xyz).unwrap();
        assert!((before - after).norm() < 1e-9);
    }
}
