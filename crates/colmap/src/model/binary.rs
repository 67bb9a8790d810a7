//! COLMAP's binary model files: little-endian, a `u64` count, then records.

use std::collections::BTreeMap;

use nalgebra::{Point2, Point3};
use revisit_core::{Camera, CameraId, CameraModel, Image, ImageId, Observation, Point3D, Point3DId, TrackElement};

use super::{check_image_name, pose_from_stored, ColmapError};

/// COLMAP's "no 3D point" marker in `images.bin`.
const INVALID_POINT3D_ID: u64 = u64::MAX;

const CAMERAS_BIN: &str = "cameras.bin";
const IMAGES_BIN: &str = "images.bin";
const POINTS3D_BIN: &str = "points3D.bin";

/// A cursor over a binary file that knows which record it is in, for errors.
struct Reader<'a> {
    bytes: &'a [u8],
    pos: usize,
    file: &'static str,
    record: u64,
}

impl<'a> Reader<'a> {
    fn new(bytes: &'a [u8], file: &'static str) -> Self {
        Self { bytes, pos: 0, file, record: 0 }
    }

    fn take<const N: usize>(&mut self) -> Result<[u8; N], ColmapError> {
        let slice =
            self.pos.checked_add(N).and_then(|end| self.bytes.get(self.pos..end)).ok_or_else(|| self.truncated())?;
        self.pos += N;
        let mut out = [0u8; N];
        out.copy_from_slice(slice);
        Ok(out)
    }

    fn u8(&mut self) -> Result<u8, ColmapError> {
        Ok(self.take::<1>()?[0])
    }
    fn u32(&mut self) -> Result<u32, ColmapError> {
        Ok(u32::from_le_bytes(self.take()?))
    }
    fn i32(&mut self) -> Result<i32, ColmapError> {
        Ok(i32::from_le_bytes(self.take()?))
    }
    fn u64(&mut self) -> Result<u64, ColmapError> {
        Ok(u64::from_le_bytes(self.take()?))
    }
    fn f64(&mut self) -> Result<f64, ColmapError> {
        Ok(f64::from_le_bytes(self.take()?))
    }
    fn f64s<const N: usize>(&mut self) -> Result<[f64; N], ColmapError> {
        let mut out = [0.0; N];
        for value in &mut out {
            *value = self.f64()?;
        }
        Ok(out)
    }

    /// A NUL-terminated string.
    fn c_string(&mut self) -> Result<&'a [u8], ColmapError> {
        let rest = self.bytes.get(self.pos..).unwrap_or_default();
        let Some(len) = rest.iter().position(|&b| b == 0) else {
            return Err(self.truncated());
        };
        let out = rest.get(..len).unwrap_or_default();
        self.pos += len + 1;
        Ok(out)
    }

    /// The leading record count, bounded by what the remaining bytes could
    /// hold (so that a corrupt count cannot make us allocate wildly).
    fn count(&mut self, min_record_bytes: usize) -> Result<(u64, usize), ColmapError> {
        let count = self.u64()?;
        let capacity = usize::try_from(count).unwrap_or(usize::MAX).min(self.remaining() / min_record_bytes.max(1));
        Ok((count, capacity))
    }

    fn remaining(&self) -> usize {
        self.bytes.len().saturating_sub(self.pos)
    }

    fn truncated(&self) -> ColmapError {
        ColmapError::Truncated { file: self.file.to_owned(), record: self.record }
    }

    fn bad(&self, reason: impl Into<String>) -> ColmapError {
        ColmapError::BadRecord { file: self.file.to_owned(), record: self.record, reason: reason.into() }
    }

    fn finish(&self) -> Result<(), ColmapError> {
        match self.remaining() {
            0 => Ok(()),
            n => Err(ColmapError::BadRecord {
                file: self.file.to_owned(),
                record: self.record,
                reason: format!("{n} bytes after the last record"),
            }),
        }
    }
}

/// Decodes `cameras.bin`.
pub fn decode_cameras_bin(bytes: &[u8]) -> Result<BTreeMap<CameraId, Camera>, ColmapError> {
    let mut r = Reader::new(bytes, CAMERAS_BIN);
    let (count, _) = r.count(24)?;
    let mut cameras = BTreeMap::new();
    for record in 1..=count {
        r.record = record;
        let camera_id = r.u32()?;
        let model = CameraModel::from_id(i64::from(r.i32()?)).map_err(|e| r.bad(e.to_string()))?;
        let width = r.u64()?;
        let height = r.u64()?;
        let (Ok(width), Ok(height)) = (u32::try_from(width), u32::try_from(height)) else {
            return Err(r.bad(format!("camera {camera_id}: image size {width}x{height} out of range")));
        };
        let mut params = Vec::with_capacity(model.num_params());
        for _ in 0..model.num_params() {
            params.push(r.f64()?);
        }
        let camera = Camera::new(camera_id, model, width, height, params).map_err(|e| r.bad(e.to_string()))?;
        if cameras.insert(camera_id, camera).is_some() {
            return Err(r.bad(format!("duplicate camera id {camera_id}")));
        }
    }
    r.finish()?;
    Ok(cameras)
}

/// Encodes `cameras.bin`.
pub fn encode_cameras_bin(cameras: &BTreeMap<CameraId, Camera>) -> Vec<u8> {
    let mut out = Vec::new();
    out.extend_from_slice(&(cameras.len() as u64).to_le_bytes());
    for camera in cameras.values() {
        out.extend_from_slice(&camera.camera_id.to_le_bytes());
        out.extend_from_slice(&camera.model.id().to_le_bytes());
        out.extend_from_slice(&u64::from(camera.width).to_le_bytes());
        out.extend_from_slice(&u64::from(camera.height).to_le_bytes());
        for param in &camera.params {
            out.extend_from_slice(&param.to_le_bytes());
        }
    }
    out
}

/// Decodes `images.bin`.
pub fn decode_images_bin(bytes: &[u8]) -> Result<BTreeMap<ImageId, Image>, ColmapError> {
    let mut r = Reader::new(bytes, IMAGES_BIN);
    let (count, _) = r.count(77)?;
    let mut images = BTreeMap::new();
    for record in 1..=count {
        r.record = record;
        let image_id = r.u32()?;
        let q_wxyz = r.f64s::<4>()?;
        let t = r.f64s::<3>()?;
        let camera_id = r.u32()?;
        let name = String::from_utf8(r.c_string()?.to_vec())
            .map_err(|_| r.bad(format!("image {image_id}: name is not UTF-8")))?;
        let (num_points2d, capacity) = r.count(24)?;
        let mut points2d = Vec::with_capacity(capacity);
        for _ in 0..num_points2d {
            let [x, y] = r.f64s::<2>()?;
            let id = r.u64()?;
            let point3d_id = (id != INVALID_POINT3D_ID).then_some(id);
            points2d.push(Observation { xy: Point2::new(x, y), point3d_id });
        }
        let image = Image { image_id, camera_id, name, cam_from_world: pose_from_stored(q_wxyz, t), points2d };
        if images.insert(image_id, image).is_some() {
            return Err(r.bad(format!("duplicate image id {image_id}")));
        }
    }
    r.finish()?;
    Ok(images)
}

/// Encodes `images.bin`. Fails on an image name COLMAP cannot store.
pub fn encode_images_bin(images: &BTreeMap<ImageId, Image>) -> Result<Vec<u8>, ColmapError> {
    let mut out = Vec::new();
    out.extend_from_slice(&(images.len() as u64).to_le_bytes());
    for image in images.values() {
        check_image_name(IMAGES_BIN, image.image_id, &image.name, false)?;
        out.extend_from_slice(&image.image_id.to_le_bytes());
        for value in image.cam_from_world.wxyz() {
            out.extend_from_slice(&value.to_le_bytes());
        }
        for value in image.cam_from_world.translation.iter() {
            out.extend_from_slice(&value.to_le_bytes());
        }
        out.extend_from_slice(&image.camera_id.to_le_bytes());
        out.extend_from_slice(image.name.as_bytes());
        out.push(0);
        out.extend_from_slice(&(image.points2d.len() as u64).to_le_bytes());
        for observation in &image.points2d {
            out.extend_from_slice(&observation.xy.x.to_le_bytes());
            out.extend_from_slice(&observation.xy.y.to_le_bytes());
            out.extend_from_slice(&observation.point3d_id.unwrap_or(INVALID_POINT3D_ID).to_le_bytes());
        }
    }
    Ok(out)
}

/// Decodes `points3D.bin`.
pub fn decode_points3d_bin(bytes: &[u8]) -> Result<BTreeMap<Point3DId, Point3D>, ColmapError> {
    let mut r = Reader::new(bytes, POINTS3D_BIN);
    let (count, _) = r.count(51)?;
    let mut points = BTreeMap::new();
    for record in 1..=count {
        r.record = record;
        let point3d_id = r.u64()?;
        let [x, y, z] = r.f64s::<3>()?;
        let rgb = [r.u8()?, r.u8()?, r.u8()?];
        let error = r.f64()?;
        let (track_length, capacity) = r.count(8)?;
        let mut track = Vec::with_capacity(capacity);
        for _ in 0..track_length {
            let image_id = r.u32()?;
            let point2d_idx = r.u32()?;
            track.push(TrackElement { image_id, point2d_idx });
        }
        let point = Point3D { xyz: Point3::new(x, y, z), rgb, error, track };
        if points.insert(point3d_id, point).is_some() {
            return Err(r.bad(format!("duplicate point3D id {point3d_id}")));
        }
    }
    r.finish()?;
    Ok(points)
}

/// Encodes `points3D.bin`.
pub fn encode_points3d_bin(points: &BTreeMap<Point3DId, Point3D>) -> Vec<u8> {
    let mut out = Vec::new();
    out.extend_from_slice(&(points.len() as u64).to_le_bytes());
    for (point3d_id, point) in points {
        out.extend_from_slice(&point3d_id.to_le_bytes());
        for value in point.xyz.coords.iter() {
            out.extend_from_slice(&value.to_le_bytes());
        }
        out.extend_from_slice(&point.rgb);
        out.extend_from_slice(&point.error.to_le_bytes());
        out.extend_from_slice(&(point.track.len() as u64).to_le_bytes());
        for element in &point.track {
            out.extend_from_slice(&element.image_id.to_le_bytes());
            out.extend_from_slice(&element.point2d_idx.to_le_bytes());
        }
    }
    out
}
