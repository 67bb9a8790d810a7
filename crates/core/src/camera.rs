use nalgebra::{Point2, Point3, Vector3};
use serde::{Deserialize, Serialize};

use crate::CameraId;

/// COLMAP's camera models, with COLMAP's ids, names and parameter orders.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize, Deserialize)]
pub enum CameraModel {
    /// `f, cx, cy`
    SimplePinhole,
    /// `fx, fy, cx, cy`
    Pinhole,
    /// `f, cx, cy, k`
    SimpleRadial,
    /// `f, cx, cy, k1, k2`
    Radial,
    /// `fx, fy, cx, cy, k1, k2, p1, p2`
    OpenCv,
    /// `fx, fy, cx, cy, k1, k2, k3, k4`
    OpenCvFisheye,
    /// `fx, fy, cx, cy, k1, k2, p1, p2, k3, k4, k5, k6`
    FullOpenCv,
    /// `fx, fy, cx, cy, omega`
    Fov,
    /// `f, cx, cy, k`
    SimpleRadialFisheye,
    /// `f, cx, cy, k1, k2`
    RadialFisheye,
    /// `fx, fy, cx, cy, k1, k2, p1, p2, k3, k4, sx1, sy1`
    ThinPrismFisheye,
}

#[derive(Debug, thiserror::Error, PartialEq, Eq)]
pub enum CameraModelError {
    #[error("unknown COLMAP camera model id {0}")]
    UnknownId(i64),
    #[error("unknown COLMAP camera model name {0:?}")]
    UnknownName(String),
    #[error("camera model {model} takes {expected} parameters, got {got}")]
    WrongParamCount { model: &'static str, expected: usize, got: usize },
}

const ALL_MODELS: [CameraModel; 11] = [
    CameraModel::SimplePinhole,
    CameraModel::Pinhole,
    CameraModel::SimpleRadial,
    CameraModel::Radial,
    CameraModel::OpenCv,
    CameraModel::OpenCvFisheye,
    CameraModel::FullOpenCv,
    CameraModel::Fov,
    CameraModel::SimpleRadialFisheye,
    CameraModel::RadialFisheye,
    CameraModel::ThinPrismFisheye,
];

impl CameraModel {
    /// COLMAP's numeric model id, as stored in databases and binary models.
    pub fn id(self) -> i32 {
        match self {
            Self::SimplePinhole => 0,
            Self::Pinhole => 1,
            Self::SimpleRadial => 2,
            Self::Radial => 3,
            Self::OpenCv => 4,
            Self::OpenCvFisheye => 5,
            Self::FullOpenCv => 6,
            Self::Fov => 7,
            Self::SimpleRadialFisheye => 8,
            Self::RadialFisheye => 9,
            Self::ThinPrismFisheye => 10,
        }
    }

    /// COLMAP's model name, as written in text models.
    pub fn name(self) -> &'static str {
        match self {
            Self::SimplePinhole => "SIMPLE_PINHOLE",
            Self::Pinhole => "PINHOLE",
            Self::SimpleRadial => "SIMPLE_RADIAL",
            Self::Radial => "RADIAL",
            Self::OpenCv => "OPENCV",
            Self::OpenCvFisheye => "OPENCV_FISHEYE",
            Self::FullOpenCv => "FULL_OPENCV",
            Self::Fov => "FOV",
            Self::SimpleRadialFisheye => "SIMPLE_RADIAL_FISHEYE",
            Self::RadialFisheye => "RADIAL_FISHEYE",
            Self::ThinPrismFisheye => "THIN_PRISM_FISHEYE",
        }
    }

    pub fn num_params(self) -> usize {
        match self {
            Self::SimplePinhole => 3,
            Self::Pinhole | Self::SimpleRadial | Self::SimpleRadialFisheye => 4,
            Self::Radial | Self::Fov | Self::RadialFisheye => 5,
            Self::OpenCv | Self::OpenCvFisheye => 8,
            Self::FullOpenCv | Self::ThinPrismFisheye => 12,
        }
    }

    pub fn from_id(id: i64) -> Result<Self, CameraModelError> {
        ALL_MODELS.into_iter().find(|m| i64::from(m.id()) == id).ok_or(CameraModelError::UnknownId(id))
    }

    pub fn from_name(name: &str) -> Result<Self, CameraModelError> {
        ALL_MODELS.into_iter().find(|m| m.name() == name).ok_or_else(|| CameraModelError::UnknownName(name.to_owned()))
    }
}

/// A camera: model, image size in pixels and parameters in COLMAP's order.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Camera {
    pub camera_id: CameraId,
    pub model: CameraModel,
    pub width: u32,
    pub height: u32,
    pub params: Vec<f64>,
}

impl Camera {
    pub fn new(
        camera_id: CameraId,
        model: CameraModel,
        width: u32,
        height: u32,
        params: Vec<f64>,
    ) -> Result<Self, CameraModelError> {
        if params.len() != model.num_params() {
            return Err(CameraModelError::WrongParamCount {
                model: model.name(),
                expected: model.num_params(),
                got: params.len(),
            });
        }
        Ok(Self { camera_id, model, width, height, params })
    }

    /// COLMAP's default for an unknown camera: SIMPLE_RADIAL with focal length
    /// 1.2 * max(width, height), principal point at the centre, no distortion.
    pub fn default_for_size(camera_id: CameraId, width: u32, height: u32) -> Self {
        let focal_px = 1.2 * f64::from(width.max(height));
        Self {
            camera_id,
            model: CameraModel::SimpleRadial,
            width,
            height,
            params: vec![focal_px, f64::from(width) / 2.0, f64::from(height) / 2.0, 0.0],
        }
    }

    /// (fx, fy, cx, cy) of the model, whatever its distortion.
    fn pinhole(&self) -> (f64, f64, f64, f64) {
        let p = &self.params;
        let get = |i: usize| p.get(i).copied().unwrap_or(0.0);
        match self.model {
            CameraModel::SimplePinhole
            | CameraModel::SimpleRadial
            | CameraModel::Radial
            | CameraModel::SimpleRadialFisheye
            | CameraModel::RadialFisheye => (get(0), get(0), get(1), get(2)),
            _ => (get(0), get(1), get(2), get(3)),
        }
    }

    /// Applies the model's distortion to normalised coordinates (u, v) = (x/z, y/z).
    /// Returns `None` for models whose distortion Revisit does not evaluate.
    fn distort(&self, u: f64, v: f64) -> Option<(f64, f64)> {
        let p = &self.params;
        let get = |i: usize| p.get(i).copied().unwrap_or(0.0);
        let r2 = u * u + v * v;
        match self.model {
            CameraModel::SimplePinhole | CameraModel::Pinhole => Some((u, v)),
            CameraModel::SimpleRadial => {
                let radial = get(3) * r2;
                Some((u + u * radial, v + v * radial))
            }
            CameraModel::Radial => {
                let radial = get(3) * r2 + get(4) * r2 * r2;
                Some((u + u * radial, v + v * radial))
            }
            CameraModel::OpenCv => {
                let (k1, k2, p1, p2) = (get(4), get(5), get(6), get(7));
                let radial = k1 * r2 + k2 * r2 * r2;
                let uv = u * v;
                let du = u * radial + 2.0 * p1 * uv + p2 * (r2 + 2.0 * u * u);
                let dv = v * radial + 2.0 * p2 * uv + p1 * (r2 + 2.0 * v * v);
                Some((u + du, v + dv))
            }
            CameraModel::OpenCvFisheye => {
                let r = r2.sqrt();
                if r < f64::EPSILON {
                    return Some((u, v));
                }
                let theta = r.atan();
                let t2 = theta * theta;
                let thetad = theta * (1.0 + get(4) * t2 + get(5) * t2 * t2 + get(6) * t2.powi(3) + get(7) * t2.powi(4));
                Some((u * thetad / r, v * thetad / r))
            }
            _ => None,
        }
    }

    /// Projects a point in the camera frame to pixels. `None` behind the camera
    /// or for a model whose distortion Revisit does not evaluate.
    pub fn img_from_cam(&self, point_in_cam: &Point3<f64>) -> Option<Point2<f64>> {
        if point_in_cam.z <= f64::EPSILON {
            return None;
        }
        let (u, v) = self.distort(point_in_cam.x / point_in_cam.z, point_in_cam.y / point_in_cam.z)?;
        let (fx, fy, cx, cy) = self.pinhole();
        Some(Point2::new(fx * u + cx, fy * v + cy))
    }

    /// The viewing ray of a pixel as a point on the z = 1 plane of the camera
    /// frame (distortion removed by fixed-point iteration, as COLMAP does).
    pub fn cam_from_img(&self, pixel: &Point2<f64>) -> Option<Vector3<f64>> {
        let (fx, fy, cx, cy) = self.pinhole();
        let (ud, vd) = ((pixel.x - cx) / fx, (pixel.y - cy) / fy);
        let (mut u, mut v) = (ud, vd);
        for _ in 0..100 {
            let (du, dv) = self.distort(u, v)?;
            let (eu, ev) = (du - ud, dv - vd);
            u -= eu;
            v -= ev;
            if eu.abs() < 1e-12 && ev.abs() < 1e-12 {
                break;
            }
        }
        Some(Vector3::new(u, v, 1.0))
    }

    /// The mean focal length in pixels.
    pub fn focal_px(&self) -> f64 {
        let (fx, fy, _, _) = self.pinhole();
        0.5 * (fx + fy)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ids_and_names_round_trip() {
        for m in ALL_MODELS {
            assert_eq!(CameraModel::from_id(i64::from(m.id())), Ok(m));
            assert_eq!(CameraModel::from_name(m.name()), Ok(m));
        }
        assert!(CameraModel::from_id(99).is_err());
    }

    #[test]
    fn project_unproject_round_trip() {
        let cams = [
            Camera::new(1, CameraModel::SimpleRadial, 640, 480, vec![500.0, 320.0, 240.0, -0.05]),
            Camera::new(2, CameraModel::OpenCv, 640, 480, vec![500.0, 510.0, 321.0, 239.0, 0.01, -0.02, 0.001, 0.002]),
            Camera::new(3, CameraModel::Pinhole, 640, 480, vec![500.0, 510.0, 321.0, 239.0]),
        ];
        for cam in cams {
            let cam = cam.unwrap();
            let p = Point3::new(0.3, -0.2, 2.0);
            let px = cam.img_from_cam(&p).unwrap();
            let ray = cam.cam_from_img(&px).unwrap();
            assert!((ray.x - 0.15).abs() < 1e-9 && (ray.y + 0.1).abs() < 1e-9, "{:?}", cam.model);
        }
    }

    #[test]
    fn wrong_param_count_is_rejected() {
        let err = Camera::new(1, CameraModel::Pinhole, 10, 10, vec![1.0]).unwrap_err();
        assert_eq!(err.to_string(), "camera model PINHOLE takes 4 parameters, got 1");
    }
}
