//! Sessions on disk: which images a session folder holds and which camera
//! took each, checked before any work starts so that bad input fails fast and
//! names the file at fault.
//!
//! A session folder holds its images either directly, grouped into cameras
//! by image size (camera `WIDTHxHEIGHT`), or in one sub-folder per camera
//! (camera = the sub-folder's name; a stereo pair is `left/` and `right/`).
//! Sorted file names give the time order.

use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};

use revisit_core::{check_camera_name, check_session_name, ImageName};

use crate::images::is_image_file;
use crate::PipelineError;

/// A session as the user names it: `NAME=DIR`.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct SessionSpec {
    pub name: String,
    pub dir: PathBuf,
}

impl std::str::FromStr for SessionSpec {
    type Err = String;

    /// Parses `NAME=DIR` ([`check_specs`] checks the name, so that a bad
    /// one is reported on one line, escaped).
    fn from_str(arg: &str) -> Result<Self, String> {
        let Some((name, dir)) = arg.split_once('=') else {
            return Err(format!("{arg:?} is not NAME=DIR"));
        };
        if dir.is_empty() {
            return Err(format!("session {name} has no folder"));
        }
        Ok(Self { name: name.to_owned(), dir: PathBuf::from(dir) })
    }
}

/// One camera's images in a session.
#[derive(Clone, Debug, PartialEq)]
pub struct CameraImages {
    /// The sub-folder's name, or `WIDTHxHEIGHT` for images grouped by size.
    pub name: String,
    pub width: u32,
    pub height: u32,
    /// Files relative to the session's folder, sorted.
    pub files: Vec<String>,
    /// The EXIF focal length of the camera's first JPEG, in pixels, if it has one.
    pub exif_focal_px: Option<f64>,
}

/// A session's images, by camera.
#[derive(Clone, Debug, PartialEq)]
pub struct SessionImages {
    pub name: String,
    /// Absolute folder.
    pub dir: PathBuf,
    /// Cameras by name.
    pub cameras: Vec<CameraImages>,
}

impl SessionImages {
    /// Every image with its camera, in time order: by file name, cameras of
    /// one instant (stereo frames of the same name) side by side.
    pub fn images(&self) -> Vec<(&CameraImages, ImageName)> {
        let mut all: Vec<(&CameraImages, ImageName)> = Vec::new();
        for camera in &self.cameras {
            for file in &camera.files {
                if let Ok(name) = ImageName::new(&self.name, file) {
                    all.push((camera, name));
                }
            }
        }
        let base = |name: &ImageName| name.file().rsplit('/').next().unwrap_or("").to_owned();
        all.sort_by(|(_, a), (_, b)| (base(a), a.file()).cmp(&(base(b), b.file())));
        all
    }

    pub fn len(&self) -> usize {
        self.cameras.iter().map(|c| c.files.len()).sum()
    }

    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }
}

/// Checks every session name, and that none is given twice.
pub fn check_specs(specs: &[SessionSpec]) -> Result<(), PipelineError> {
    let mut seen = BTreeSet::new();
    for spec in specs {
        check_session_name(&spec.name).map_err(|e| PipelineError::Name(e.to_string()))?;
        if !seen.insert(spec.name.as_str()) {
            return Err(PipelineError::DuplicateSession(spec.name.clone()));
        }
    }
    Ok(())
}

fn io(path: &Path) -> impl Fn(std::io::Error) -> PipelineError + '_ {
    move |source| PipelineError::Io { path: path.to_path_buf(), source }
}

/// Image files and sub-folders of `dir`, sorted by name.
fn list(dir: &Path) -> Result<(Vec<String>, Vec<String>), PipelineError> {
    let (mut files, mut folders) = (Vec::new(), Vec::new());
    for entry in std::fs::read_dir(dir).map_err(io(dir))? {
        let path = entry.map_err(io(dir))?.path();
        let Some(name) = path.file_name().and_then(|n| n.to_str()).map(str::to_owned) else { continue };
        if name.starts_with('.') {
            continue;
        }
        if path.is_file() && is_image_file(&path) {
            files.push(name);
        } else if path.is_dir() {
            folders.push(name);
        }
    }
    files.sort();
    folders.sort();
    Ok((files, folders))
}

fn dimensions(path: &Path) -> Result<(u32, u32), PipelineError> {
    image::image_dimensions(path)
        .map_err(|e| PipelineError::BadImage { path: path.to_path_buf(), reason: e.to_string() })
}

fn exif_focal(path: &Path, width: u32, height: u32) -> Option<f64> {
    let is_jpeg = path.extension().and_then(|e| e.to_str()).is_some_and(|e| !e.eq_ignore_ascii_case("png"));
    let bytes = if is_jpeg { std::fs::read(path).ok()? } else { return None };
    crate::images::exif_focal_px(&bytes, width, height)
}

/// Lists and checks a session's images: the folder must exist and hold at
/// least two images, every image header must be readable, every name valid,
/// and each camera sub-folder must hold one image size.
pub fn scan_session(spec: &SessionSpec) -> Result<SessionImages, PipelineError> {
    let session = list_session(spec)?;
    match session.len() {
        0 => Err(PipelineError::NoImages { session: spec.name.clone(), dir: session.dir }),
        1 => Err(PipelineError::OneImage { session: spec.name.clone(), dir: session.dir }),
        _ => Ok(session),
    }
}

/// [`scan_session`] without the count: a visit still coming in (the mapper
/// node's) may hold one image, or none yet.
pub fn list_session(spec: &SessionSpec) -> Result<SessionImages, PipelineError> {
    check_session_name(&spec.name).map_err(|e| PipelineError::Name(e.to_string()))?;
    let dir = std::fs::canonicalize(&spec.dir).map_err(io(&spec.dir))?;
    let (files, folders) = list(&dir)?;
    let mut cameras = Vec::new();
    if !files.is_empty() {
        // Images directly in the folder: one camera per image size.
        let mut by_size: BTreeMap<(u32, u32), Vec<String>> = BTreeMap::new();
        for file in files {
            let size = dimensions(&dir.join(&file))?;
            by_size.entry(size).or_default().push(file);
        }
        for ((width, height), files) in by_size {
            let exif_focal_px = exif_focal(&dir.join(&files[0]), width, height);
            cameras.push(CameraImages { name: format!("{width}x{height}"), width, height, files, exif_focal_px });
        }
    } else {
        // One sub-folder per camera.
        for folder in folders {
            let (files, _) = list(&dir.join(&folder))?;
            let Some(first) = files.first() else { continue };
            check_camera_name(&folder)
                .map_err(|e| PipelineError::Name(format!("{}: {e}", dir.join(&folder).display())))?;
            let first_path = dir.join(&folder).join(first);
            let (width, height) = dimensions(&first_path)?;
            for file in &files[1..] {
                let path = dir.join(&folder).join(file);
                let size = dimensions(&path)?;
                if size != (width, height) {
                    return Err(PipelineError::MixedSizes {
                        session: spec.name.clone(),
                        camera: folder.clone(),
                        path,
                        size,
                        first: first_path,
                        first_size: (width, height),
                    });
                }
            }
            let exif_focal_px = exif_focal(&first_path, width, height);
            let files = files.iter().map(|f| format!("{folder}/{f}")).collect();
            cameras.push(CameraImages { name: folder, width, height, files, exif_focal_px });
        }
    }
    let session = SessionImages { name: spec.name.clone(), dir: dir.clone(), cameras };
    for camera in &session.cameras {
        for file in &camera.files {
            ImageName::new(&session.name, file)
                .map_err(|e| PipelineError::Name(format!("{}: {e}", dir.join(file).display())))?;
        }
    }
    Ok(session)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn session_args_parse() {
        let spec: SessionSpec = "2019=/data/a=b".parse().unwrap();
        assert_eq!(spec.name, "2019");
        assert_eq!(spec.dir, PathBuf::from("/data/a=b"));
        assert!("nodir".parse::<SessionSpec>().is_err());
    }

    #[test]
    fn bad_and_duplicate_names_are_rejected() {
        let specs: Vec<SessionSpec> = ["a=/x", "b=/y", "a=/z"].iter().map(|s| s.parse().unwrap()).collect();
        assert_eq!(check_specs(&specs).unwrap_err().to_string(), "session a is given twice");
        for bad in ["a/b=/x", "=/x", "a\nb=/x"] {
            let specs = [bad.parse::<SessionSpec>().unwrap()];
            assert!(check_specs(&specs).is_err(), "{bad:?} was accepted");
        }
        let err = check_specs(&["a\nb=/x".parse().unwrap()]).unwrap_err().to_string();
        assert!(!err.contains('\n') && err.contains("control character"), "{err}");
    }

    #[test]
    fn images_in_one_folder_are_grouped_into_cameras_by_size() {
        let dir = tempfile::tempdir().unwrap();
        let spec = SessionSpec { name: "s".into(), dir: dir.path().into() };
        assert!(matches!(scan_session(&spec), Err(PipelineError::NoImages { .. })));
        image::GrayImage::new(32, 24).save(dir.path().join("b.png")).unwrap();
        assert!(matches!(scan_session(&spec), Err(PipelineError::OneImage { .. })));
        image::GrayImage::new(32, 24).save(dir.path().join("a.png")).unwrap();
        image::GrayImage::new(16, 24).save(dir.path().join("c.png")).unwrap();
        let session = scan_session(&spec).unwrap();
        let cameras: Vec<(&str, &[String])> = session.cameras.iter().map(|c| (c.name.as_str(), &c.files[..])).collect();
        assert_eq!(
            cameras,
            [("16x24", &["c.png".to_owned()][..]), ("32x24", &["a.png".to_owned(), "b.png".to_owned()][..])]
        );
        let order: Vec<String> = session.images().iter().map(|(_, n)| n.to_string()).collect();
        assert_eq!(order, ["s/a.png", "s/b.png", "s/c.png"]);
        std::fs::write(dir.path().join("d.png"), b"not a png").unwrap();
        let err = scan_session(&spec).unwrap_err().to_string();
        assert!(err.contains("d.png"), "{err}");
    }

    #[test]
    fn sub_folders_are_cameras_and_each_holds_one_size() {
        let dir = tempfile::tempdir().unwrap();
        for (camera, frame) in
            [("left", "0001.png"), ("left", "0002.png"), ("right", "0001.png"), ("right", "0002.png")]
        {
            std::fs::create_dir_all(dir.path().join(camera)).unwrap();
            image::GrayImage::new(32, 24).save(dir.path().join(camera).join(frame)).unwrap();
        }
        let spec = SessionSpec { name: "s".into(), dir: dir.path().into() };
        let session = scan_session(&spec).unwrap();
        let order: Vec<String> = session.images().iter().map(|(c, n)| format!("{} {n}", c.name)).collect();
        assert_eq!(
            order,
            ["left s/left/0001.png", "right s/right/0001.png", "left s/left/0002.png", "right s/right/0002.png"]
        );
        image::GrayImage::new(16, 24).save(dir.path().join("right/0003.png")).unwrap();
        let err = scan_session(&spec).unwrap_err().to_string();
        assert!(err.contains("camera right") && err.contains("0003.png is 16x24"), "{err}");
    }
}
