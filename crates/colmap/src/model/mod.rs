//! COLMAP sparse models on disk: `cameras`, `images` and `points3D` in the
//! binary (`.bin`) and text (`.txt`) forms of COLMAP 3.8 and pycolmap 4.2.1,
//! and a PLY export of the points.
//!
//! The codecs ([`decode_cameras_bin`], [`encode_points3d_txt`], ...) are pure
//! functions on bytes and strings; [`read_model`], [`write_binary`],
//! [`write_text`] and [`write_ply`] are the thin file wrappers. Files are
//! written atomically (temporary name in the same folder, then rename).
//!
//! Binary models round-trip byte for byte (quaternions are kept as stored
//! when they are unit to 1e-9). Text models print every number with Rust's
//! shortest round-trip formatting, so text round-trips exactly too.
//! pycolmap 4 also writes `rigs` and `frames` files: they are ignored.

mod binary;
mod ply;
mod text;

use std::path::{Path, PathBuf};

use nalgebra::{Quaternion, UnitQuaternion};
use revisit_core::{Reconstruction, Rigid3};

pub use binary::{
    decode_cameras_bin, decode_images_bin, decode_points3d_bin, encode_cameras_bin, encode_images_bin,
    encode_points3d_bin,
};
pub use ply::{encode_ply, session_palette, PlyColors, SESSION_PALETTE};
pub use text::{
    decode_cameras_txt, decode_images_txt, decode_points3d_txt, encode_cameras_txt, encode_images_txt,
    encode_points3d_txt,
};

/// What went wrong reading or writing a model. Every variant names the file;
/// decoding errors also name the record (binary, 1-based; 0 is the leading
/// count) or the line (text, 1-based).
#[derive(Debug, thiserror::Error)]
pub enum ColmapError {
    #[error("cannot {action} {path}")]
    Io {
        action: &'static str,
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    #[error("{file}: truncated in record {record}")]
    Truncated { file: String, record: u64 },
    #[error("{file}: record {record}: {reason}")]
    BadRecord { file: String, record: u64, reason: String },
    #[error("{file}: line {line}: {reason}")]
    BadLine { file: String, line: usize, reason: String },
    #[error("{file}: image {image_id} ({name:?}): {reason}")]
    BadImageName { file: String, image_id: u32, name: String, reason: &'static str },
    #[error("{}: no COLMAP model here (expected cameras, images and points3D, all .bin or all .txt, or numbered sub-models)", dir.display())]
    NoModel { dir: PathBuf },
}

impl ColmapError {
    /// Replaces the bare file name a decoder reports by the full path.
    fn in_file(self, path: &Path) -> Self {
        let full = path.display().to_string();
        match self {
            Self::Truncated { record, .. } => Self::Truncated { file: full, record },
            Self::BadRecord { record, reason, .. } => Self::BadRecord { file: full, record, reason },
            Self::BadLine { line, reason, .. } => Self::BadLine { file: full, line, reason },
            Self::BadImageName { image_id, name, reason, .. } => {
                Self::BadImageName { file: full, image_id, name, reason }
            }
            other => other,
        }
    }
}

/// The two on-disk forms of a model.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ModelFormat {
    Binary,
    Text,
}

impl ModelFormat {
    fn extension(self) -> &'static str {
        match self {
            Self::Binary => "bin",
            Self::Text => "txt",
        }
    }
}

const CAMERAS: &str = "cameras";
const IMAGES: &str = "images";
const POINTS3D: &str = "points3D";

/// Which form of model `dir` holds, if any (binary wins when both are there,
/// as in COLMAP).
pub fn detect_format(dir: &Path) -> Option<ModelFormat> {
    [ModelFormat::Binary, ModelFormat::Text].into_iter().find(|format| {
        [CAMERAS, IMAGES, POINTS3D].iter().all(|stem| dir.join(format!("{stem}.{}", format.extension())).is_file())
    })
}

/// Reads the model in `dir`, binary or text (see [`detect_format`]).
pub fn read_model(dir: &Path) -> Result<Reconstruction, ColmapError> {
    let Some(format) = detect_format(dir) else {
        return Err(ColmapError::NoModel { dir: dir.to_owned() });
    };
    let path = |stem: &str| dir.join(format!("{stem}.{}", format.extension()));
    let (cameras_path, images_path, points_path) = (path(CAMERAS), path(IMAGES), path(POINTS3D));
    let model = match format {
        ModelFormat::Binary => Reconstruction {
            cameras: decode_cameras_bin(&read_bytes(&cameras_path)?).map_err(|e| e.in_file(&cameras_path))?,
            images: decode_images_bin(&read_bytes(&images_path)?).map_err(|e| e.in_file(&images_path))?,
            points3d: decode_points3d_bin(&read_bytes(&points_path)?).map_err(|e| e.in_file(&points_path))?,
        },
        ModelFormat::Text => Reconstruction {
            cameras: decode_cameras_txt(&read_string(&cameras_path)?).map_err(|e| e.in_file(&cameras_path))?,
            images: decode_images_txt(&read_string(&images_path)?).map_err(|e| e.in_file(&images_path))?,
            points3d: decode_points3d_txt(&read_string(&points_path)?).map_err(|e| e.in_file(&points_path))?,
        },
    };
    Ok(model)
}

/// Reads `dir` as one model, or, if it holds none, every numbered sub-model
/// (`dir/0`, `dir/1`, ... as COLMAP's mapper writes them), in numeric order.
pub fn read_models(dir: &Path) -> Result<Vec<(PathBuf, Reconstruction)>, ColmapError> {
    if detect_format(dir).is_some() {
        return Ok(vec![(dir.to_owned(), read_model(dir)?)]);
    }
    let entries =
        std::fs::read_dir(dir).map_err(|source| ColmapError::Io { action: "list", path: dir.to_owned(), source })?;
    let mut numbered: Vec<(u64, PathBuf)> = Vec::new();
    for entry in entries {
        let entry = entry.map_err(|source| ColmapError::Io { action: "list", path: dir.to_owned(), source })?;
        let path = entry.path();
        let number = entry.file_name().to_str().and_then(|name| name.parse::<u64>().ok());
        if let Some(number) = number {
            if detect_format(&path).is_some() {
                numbered.push((number, path));
            }
        }
    }
    if numbered.is_empty() {
        return Err(ColmapError::NoModel { dir: dir.to_owned() });
    }
    numbered.sort();
    numbered.into_iter().map(|(_, path)| read_model(&path).map(|model| (path, model))).collect()
}

/// Writes `cameras.bin`, `images.bin` and `points3D.bin` into `dir` (created
/// if missing).
pub fn write_binary(model: &Reconstruction, dir: &Path) -> Result<(), ColmapError> {
    let images = encode_images_bin(&model.images)?;
    create_dir(dir)?;
    write_atomic(&dir.join("cameras.bin"), &encode_cameras_bin(&model.cameras))?;
    write_atomic(&dir.join("images.bin"), &images)?;
    write_atomic(&dir.join("points3D.bin"), &encode_points3d_bin(&model.points3d))
}

/// Writes `cameras.txt`, `images.txt` and `points3D.txt` into `dir` (created
/// if missing).
pub fn write_text(model: &Reconstruction, dir: &Path) -> Result<(), ColmapError> {
    let images = encode_images_txt(&model.images)?;
    create_dir(dir)?;
    write_atomic(&dir.join("cameras.txt"), encode_cameras_txt(&model.cameras).as_bytes())?;
    write_atomic(&dir.join("images.txt"), images.as_bytes())?;
    write_atomic(&dir.join("points3D.txt"), encode_points3d_txt(&model.points3d).as_bytes())
}

/// Writes the model's points as a binary little-endian PLY (see [`encode_ply`]).
pub fn write_ply(model: &Reconstruction, path: &Path, colors: PlyColors) -> Result<(), ColmapError> {
    if let Some(parent) = path.parent().filter(|p| !p.as_os_str().is_empty()) {
        create_dir(parent)?;
    }
    write_atomic(path, &encode_ply(model, colors))
}

fn read_bytes(path: &Path) -> Result<Vec<u8>, ColmapError> {
    std::fs::read(path).map_err(|source| ColmapError::Io { action: "read", path: path.to_owned(), source })
}

fn read_string(path: &Path) -> Result<String, ColmapError> {
    std::fs::read_to_string(path).map_err(|source| ColmapError::Io { action: "read", path: path.to_owned(), source })
}

fn create_dir(dir: &Path) -> Result<(), ColmapError> {
    std::fs::create_dir_all(dir).map_err(|source| ColmapError::Io { action: "create", path: dir.to_owned(), source })
}

/// Writes to a temporary file next to `path`, then renames it over `path`,
/// so that a reader never sees a half-written file.
fn write_atomic(path: &Path, bytes: &[u8]) -> Result<(), ColmapError> {
    use std::io::Write;
    let file_name = path.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default();
    let tmp = path.with_file_name(format!(".{file_name}.tmp{}", std::process::id()));
    let io = |action: &'static str, p: &Path| {
        let p = p.to_owned();
        move |source| ColmapError::Io { action, path: p, source }
    };
    let mut file = std::fs::File::create(&tmp).map_err(io("create", &tmp))?;
    file.write_all(bytes).map_err(io("write", &tmp))?;
    file.sync_all().map_err(io("write", &tmp))?;
    drop(file);
    std::fs::rename(&tmp, path).map_err(|source| {
        let _ = std::fs::remove_file(&tmp);
        ColmapError::Io { action: "rename into", path: path.to_owned(), source }
    })
}

/// A pose from COLMAP's stored quaternion (w, x, y, z) and translation. A
/// quaternion that is unit to 1e-9 is kept bit for bit (so that models
/// round-trip exactly); any other is normalised.
fn pose_from_stored(q_wxyz: [f64; 4], t: [f64; 3]) -> Rigid3 {
    let [w, x, y, z] = q_wxyz;
    let q = Quaternion::new(w, x, y, z);
    let mut pose = Rigid3::from_wxyz(q_wxyz, t);
    if (q.norm() - 1.0).abs() < 1e-9 {
        pose.rotation = UnitQuaternion::new_unchecked(q);
    }
    pose
}

/// Names COLMAP cannot store: empty or with a NUL (the binary terminator);
/// in the text form also a line break or leading/trailing whitespace.
fn check_image_name(file: &str, image_id: u32, name: &str, text: bool) -> Result<(), ColmapError> {
    let reason = if name.is_empty() {
        Some("empty image name")
    } else if name.contains('\0') {
        Some("image name holds a NUL")
    } else if text && (name.contains('\n') || name.contains('\r')) {
        Some("image name holds a line break")
    } else if text && name.trim() != name {
        Some("image name starts or ends with whitespace")
    } else {
        None
    };
    match reason {
        Some(reason) => {
            Err(ColmapError::BadImageName { file: file.to_owned(), image_id, name: name.to_owned(), reason })
        }
        None => Ok(()),
    }
}
