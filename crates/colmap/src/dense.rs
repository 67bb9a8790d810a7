//! Dense surfaces: each visit's own surface from its images at a model's poses, by OpenCV's
//! semi-global matching in the project's Python (`python/revisit_dense.py` says how).
//!
//! Sparse SfM points sample texture; a change map needs the surface itself. Each visit's
//! surface is built from its own images only, so that it says where that visit saw the reef.

use std::path::{Path, PathBuf};
use std::process::Command;
use std::sync::atomic::AtomicBool;

use nalgebra::Point3;
use revisit_core::{session_of, Fingerprint, Reconstruction};
use serde::{Deserialize, Serialize};

use crate::mapper::{run_until_cancelled, summary_line};

const ENTRY_POINT: &str = include_str!("../python/revisit_dense.py");

#[derive(Debug, thiserror::Error)]
pub enum DenseError {
    #[error("could not start {python}: {source}")]
    Spawn { python: PathBuf, source: std::io::Error },
    #[error("writing {path}: {source}")]
    Io { path: PathBuf, source: std::io::Error },
    #[error("dense surfaces failed: {0}")]
    Failed(String),
    #[error("dense surfaces printed no summary: {0}")]
    BadSummary(String),
    #[error("{path}: {reason}")]
    BadPly { path: PathBuf, reason: String },
    #[error("dense surfaces were stopped on request")]
    Cancelled,
}

/// How the surfaces are made.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct DenseOptions {
    /// One point per block of this many pixels a side. Default 4.
    pub step_px: u32,
    /// An image's two pairs must agree on a depth within this fraction of it. Default 0.01.
    pub agreement: f64,
    /// Pixels whose 7 x 7 neighbourhood varies less than this (standard deviation of the grey
    /// level, 0-255, at the matching scale) make no point: semi-global matching fills such
    /// areas from their surroundings, and two pairs can agree on that guess. Default 3.
    pub min_texture: f64,
    /// Points are averaged in cubes of this fraction of the altitude. Default 0.01.
    pub voxel: f64,
    /// Images are matched at this fraction of their resolution (smoothed first). Default 0.5:
    /// four times faster than full resolution, and as many corals found on the storm reefs
    /// measured (README).
    pub scale: f64,
}

impl Default for DenseOptions {
    fn default() -> Self {
        Self { step_px: 4, agreement: 0.01, min_texture: 3.0, voxel: 0.01, scale: 0.5 }
    }
}

/// One run: which model, where its images are, which visits, where the surfaces go.
#[derive(Clone, Copy, Debug)]
pub struct DenseRun<'a> {
    /// Python with pycolmap and OpenCV.
    pub python: &'a Path,
    /// A COLMAP model folder.
    pub model: &'a Path,
    /// The folder the model's image names are relative to.
    pub image_root: &'a Path,
    /// Surfaces go to `output/<visit>.ply`.
    pub output: &'a Path,
    pub visits: &'a [&'a str],
}

/// What was made of one visit.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct DenseVisit {
    pub visit: String,
    /// The visit's registered images.
    pub images: usize,
    /// Those with at least two partners, whose depths made points.
    pub fused: usize,
    /// Points after averaging in voxels.
    pub points: usize,
    /// Median depth of the visit's sparse points in its images, model units.
    pub altitude: f64,
    pub seconds: f64,
}

#[derive(Deserialize)]
struct Summary {
    visits: Vec<DenseVisit>,
}

/// The surface of `visit` under `output` (written by [`run_dense`]).
pub fn surface_path(output: &Path, visit: &str) -> PathBuf {
    output.join(format!("{visit}.ply"))
}

/// Makes the surfaces of `run.visits` (`output/<visit>.ply`, each written whole or not at all).
/// Setting `cancelled` stops the run within a tenth of a second.
pub fn run_dense(
    run: &DenseRun<'_>,
    options: &DenseOptions,
    cancelled: &AtomicBool,
) -> Result<Vec<DenseVisit>, DenseError> {
    std::fs::create_dir_all(run.output).map_err(|source| DenseError::Io { path: run.output.to_owned(), source })?;
    let script = run.output.join("revisit_dense.py");
    std::fs::write(&script, ENTRY_POINT).map_err(|source| DenseError::Io { path: script.clone(), source })?;
    let mut command = Command::new(run.python);
    command
        .arg(&script)
        .arg("--model")
        .arg(run.model)
        .arg("--image-path")
        .arg(run.image_root)
        .arg("--output")
        .arg(run.output)
        .arg("--step")
        .arg(options.step_px.to_string())
        .arg("--agreement")
        .arg(options.agreement.to_string())
        .arg("--min-texture")
        .arg(options.min_texture.to_string())
        .arg("--voxel")
        .arg(options.voxel.to_string())
        .arg("--scale")
        .arg(options.scale.to_string());
    for visit in run.visits {
        command.arg("--visit").arg(visit);
    }
    tracing::debug!(?command, "starting dense surfaces");
    let result = run_until_cancelled(command, cancelled)
        .map_err(|source| DenseError::Spawn { python: run.python.to_owned(), source })?
        .ok_or(DenseError::Cancelled)?;
    if !result.status.success() {
        let stderr = String::from_utf8_lossy(&result.stderr);
        return Err(DenseError::Failed(stderr.lines().last().unwrap_or("no message").to_owned()));
    }
    let summary: Summary = summary_line(&result.stdout).map_err(|e| DenseError::BadSummary(e.to_string()))?;
    Ok(summary.visits)
}

/// A fingerprint of what `visit`'s surface is made from: its images' names, cameras and
/// poses in `model`, the image folder and the options.
pub fn surface_fingerprint(model: &Reconstruction, visit: &str, image_root: &Path, options: &DenseOptions) -> String {
    let mut hash = Fingerprint::default();
    let DenseOptions { step_px, agreement, min_texture, voxel, scale } = *options;
    // The method itself: a surface made by an earlier version is made again.
    hash.str(ENTRY_POINT).str(&image_root.to_string_lossy()).u64(step_px.into());
    for value in [agreement, min_texture, voxel, scale] {
        hash.f64(value);
    }
    for image in model.images.values().filter(|image| session_of(&image.name) == visit) {
        hash.str(&image.name);
        let pose = &image.cam_from_world;
        for value in pose.rotation.coords.iter().chain(pose.translation.iter()) {
            hash.f64(*value);
        }
        if let Some(camera) = model.cameras.get(&image.camera_id) {
            hash.str(camera.model.name()).u64(camera.width.into()).u64(camera.height.into());
            for value in &camera.params {
                hash.f64(*value);
            }
        }
    }
    hash.hex()
}

/// The points of a surface PLY as [`run_dense`] writes it (binary little-endian vertices of
/// double x, y, z and uchar red, green, blue).
pub fn decode_surface_ply(bytes: &[u8]) -> Result<Vec<Point3<f64>>, String> {
    const END: &[u8] = b"end_header\n";
    const PROPERTIES: [&str; 6] = ["double x", "double y", "double z", "uchar red", "uchar green", "uchar blue"];
    let end = bytes.windows(END.len()).position(|w| w == END).ok_or("no PLY header (no end_header line)")?;
    let header = std::str::from_utf8(&bytes[..end]).map_err(|_| "the PLY header is not text")?;
    let mut lines = header.lines().filter(|line| !line.starts_with("comment"));
    if lines.next() != Some("ply") || lines.next() != Some("format binary_little_endian 1.0") {
        return Err("not a binary little-endian PLY".into());
    }
    let count: usize = lines
        .next()
        .and_then(|line| line.strip_prefix("element vertex "))
        .and_then(|n| n.trim().parse().ok())
        .ok_or("no vertex count")?;
    let properties: Vec<&str> = lines.map(|line| line.trim_start_matches("property ")).collect();
    if properties != PROPERTIES {
        return Err(format!("vertices of {properties:?}, expected {PROPERTIES:?}"));
    }
    const STRIDE: usize = 3 * 8 + 3;
    let body = &bytes[end + END.len()..];
    if body.len() != count * STRIDE {
        return Err(format!("{count} vertices need {} bytes, the file has {}", count * STRIDE, body.len()));
    }
    let double = |bytes: &[u8]| {
        let mut word = [0; 8];
        word.copy_from_slice(bytes);
        f64::from_le_bytes(word)
    };
    Ok(body
        .chunks_exact(STRIDE)
        .map(|v| Point3::new(double(&v[0..8]), double(&v[8..16]), double(&v[16..24])))
        .collect())
}

/// Reads a surface written by [`run_dense`].
pub fn read_surface(path: &Path) -> Result<Vec<Point3<f64>>, DenseError> {
    let bytes = std::fs::read(path).map_err(|source| DenseError::Io { path: path.to_owned(), source })?;
    decode_surface_ply(&bytes).map_err(|reason| DenseError::BadPly { path: path.to_owned(), reason })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn ply(points: &[[f64; 3]]) -> Vec<u8> {
        let mut bytes = format!(
            "ply\nformat binary_little_endian 1.0\ncomment one visit\nelement vertex {}\nproperty double x\n\
             property double y\nproperty double z\nproperty uchar red\nproperty uchar green\n\
             property uchar blue\nend_header\n",
            points.len()
        )
        .into_bytes();
        for p in points {
            p.iter().for_each(|v| bytes.extend(v.to_le_bytes()));
            bytes.extend([1, 2, 3]);
        }
        bytes
    }

    #[test]
    fn a_surface_reads_back_and_a_damaged_one_is_named() {
        let points = [[1.5, -2.0, 3.25], [500_000.125, 4_000_000.5, -12.0]];
        let read = decode_surface_ply(&ply(&points)).unwrap();
        assert_eq!(read, points.map(Point3::from).to_vec());
        let mut cut = ply(&points);
        cut.pop();
        assert!(decode_surface_ply(&cut).unwrap_err().contains("2 vertices need 54 bytes"));
        let text = b"ply\nformat ascii 1.0\nend_header\n";
        assert_eq!(decode_surface_ply(text).unwrap_err(), "not a binary little-endian PLY");
    }

    #[test]
    fn the_fingerprint_follows_the_poses_and_options() {
        let model = Reconstruction::default();
        let options = DenseOptions::default();
        let root = Path::new("images");
        let same = surface_fingerprint(&model, "s1", root, &options);
        assert_eq!(same, surface_fingerprint(&model, "s1", root, &options));
        let finer = DenseOptions { step_px: 2, ..options };
        assert_ne!(same, surface_fingerprint(&model, "s1", root, &finer));
    }
}
