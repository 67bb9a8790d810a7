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

    /// Models built apart, already in one frame, as one model: cameras, images and points
    /// renumbered in the order given (ids from 1), tracks and observations following.
    pub fn merge(parts: &[Reconstruction]) -> Reconstruction {
        let mut merged = Reconstruction::default();
        for part in parts {
            let camera_ids: BTreeMap<CameraId, CameraId> =
                part.cameras.keys().map(|&id| (id, merged.cameras.len() as CameraId + 1)).collect();
            let image_ids: BTreeMap<ImageId, ImageId> =
                part.images.keys().zip(merged.images.len() as ImageId + 1..).map(|(&id, new)| (id, new)).collect();
            let point_ids: BTreeMap<Point3DId, Point3DId> = part
                .points3d
                .keys()
                .zip(merged.points3d.len() as Point3DId + 1..)
                .map(|(&id, new)| (id, new))
                .collect();
            for (id, camera) in &part.cameras {
                let camera_id = camera_ids[id];
                merged.cameras.insert(camera_id, Camera { camera_id, ..camera.clone() });
            }
            for (id, image) in &part.images {
                let points2d = image
                    .points2d
                    .iter()
                    .map(|o| Observation {
                        xy: o.xy,
                        point3d_id: o.point3d_id.and_then(|p| point_ids.get(&p).copied()),
                    })
                    .collect();
                let image_id = image_ids[id];
                let camera_id = camera_ids.get(&image.camera_id).copied().unwrap_or(image.camera_id);
                merged.images.insert(image_id, Image { image_id, camera_id, points2d, ..image.clone() });
            }
            for (id, point) in &part.points3d {
                let track = point
                    .track
                    .iter()
                    .filter_map(|t| Some(TrackElement { image_id: *image_ids.get(&t.image_id)?, ..*t }))
                    .collect();
                merged.points3d.insert(point_ids[id], Point3D { track, ..point.clone() });
            }
        }
        merged
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

    #[test]
    fn merged_models_keep_every_track_and_observation() {
        let part = |name: &str, x: f64| {
            let mut model = Reconstruction::default();
            model
                .cameras
                .insert(7, Camera::new(7, CameraModel::Pinhole, 64, 48, vec![50.0, 50.0, 32.0, 24.0]).unwrap());
            let observation = Observation { xy: Point2::new(1.0, 2.0), point3d_id: Some(9) };
            let image = Image {
                image_id: 5,
                camera_id: 7,
                name: name.into(),
                cam_from_world: Rigid3::identity(),
                points2d: vec![observation],
            };
            model.images.insert(5, image);
            let track = vec![TrackElement { image_id: 5, point2d_idx: 0 }];
            model.points3d.insert(9, Point3D { xyz: Point3::new(x, 0.0, 1.0), rgb: [0; 3], error: 0.5, track });
            model
        };
        let merged = Reconstruction::merge(&[part("a/1.png", 1.0), part("b/1.png", 2.0)]);
        assert_eq!((merged.cameras.len(), merged.images.len(), merged.points3d.len()), (2, 2, 2));
        let b = merged.image_by_name("b/1.png").unwrap();
        assert_eq!((b.image_id, b.camera_id), (2, 2));
        let point = &merged.points3d[&b.points2d[0].point3d_id.unwrap()];
        assert_eq!((point.xyz.x, point.track[0].image_id), (2.0, 2));
    }
}
