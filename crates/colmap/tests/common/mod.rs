//! A small model with awkward numbers, shared by the integration tests.
#![allow(dead_code, clippy::unwrap_used)]

use nalgebra::{Point2, Point3, UnitQuaternion, Vector3};
use revisit_core::{Camera, CameraModel, Image, Observation, Point3D, Reconstruction, Rigid3, TrackElement};

/// A deterministic generator of awkward f64s (xorshift64*).
pub struct Rng(u64);

impl Rng {
    pub fn new(seed: u64) -> Self {
        Self(seed.max(1))
    }
    pub fn next_f64(&mut self) -> f64 {
        self.0 ^= self.0 >> 12;
        self.0 ^= self.0 << 25;
        self.0 ^= self.0 >> 27;
        (self.0.wrapping_mul(0x2545_F491_4F6C_DD1D) >> 11) as f64 / (1u64 << 53) as f64
    }
    pub fn range(&mut self, lo: f64, hi: f64) -> f64 {
        lo + (hi - lo) * self.next_f64()
    }
}

/// Two cameras, four images in two sessions (ids 1, 2, 5, 9), 12 points with
/// tracks of 2-4 images consistent with the images' observations, plus
/// untriangulated observations. Points project for real (positive depth).
pub fn sample_model() -> Reconstruction {
    let mut rng = Rng::new(7);
    let mut model = Reconstruction::default();
    model.cameras.insert(
        1,
        Camera::new(1, CameraModel::SimpleRadial, 640, 480, vec![rng.range(400.0, 600.0), 320.1, 239.7, -0.0123456789])
            .unwrap(),
    );
    model.cameras.insert(
        3,
        Camera::new(
            3,
            CameraModel::OpenCv,
            1280,
            720,
            vec![rng.range(800.0, 900.0), rng.range(800.0, 900.0), 640.3, 360.2, 1e-3, -2.5e-7, 1e-300, 0.0],
        )
        .unwrap(),
    );
    let names = [(1u32, 1u32, "2019/a.png"), (2, 1, "2019/b.png"), (5, 3, "2024/c.png"), (9, 3, "2024/dir/d.png")];
    for (image_id, camera_id, name) in names {
        let rotation =
            UnitQuaternion::from_euler_angles(rng.range(-0.2, 0.2), rng.range(-0.2, 0.2), rng.range(-3.0, 3.0));
        let cam_from_world = Rigid3::new(rotation, Vector3::new(rng.range(-1.0, 1.0), rng.range(-1.0, 1.0), 5.0));
        let mut points2d = Vec::new();
        for _ in 0..3 {
            points2d
                .push(Observation { xy: Point2::new(rng.range(0.0, 640.0), rng.range(0.0, 480.0)), point3d_id: None });
        }
        model.images.insert(image_id, Image { image_id, camera_id, name: name.to_owned(), cam_from_world, points2d });
    }
    let image_ids: Vec<u32> = model.images.keys().copied().collect();
    for k in 0..12u64 {
        let point3d_id = 100 + 3 * k;
        let xyz = Point3::new(rng.range(-1.0, 1.0), rng.range(-1.0, 1.0), rng.range(-0.5, 0.5));
        let track_len = 2 + (k as usize % 3);
        let start = k as usize % image_ids.len();
        let mut track = Vec::new();
        for j in 0..track_len {
            let image_id = image_ids[(start + j) % image_ids.len()];
            let image = model.images.get(&image_id).unwrap().clone();
            let xy = model.project(&image, &xyz).unwrap();
            let image = model.images.get_mut(&image_id).unwrap();
            image.points2d.push(Observation { xy, point3d_id: Some(point3d_id) });
            track.push(TrackElement { image_id, point2d_idx: (image.points2d.len() - 1) as u32 });
        }
        let rgb = [(k * 20) as u8, 255 - (k * 7) as u8, 3];
        model.points3d.insert(point3d_id, Point3D { xyz, rgb, error: rng.range(0.0, 2.0), track });
    }
    model
}
