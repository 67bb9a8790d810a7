//! Sessions on disk: which images a session folder holds, checked before any
//! work starts so that bad input fails fast and names the file at fault.

use std::collections::BTreeSet;
use std::path::{Path, PathBuf};

use crate::PipelineError;

/// File extensions read as images (lower case).
pub const IMAGE_EXTENSIONS: [&str; 3] = ["png", "jpg", "jpeg"];

/// A session as the user names it: `NAME=DIR`.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct SessionSpec {
    pub name: String,
    pub dir: PathBuf,
}

impl std::str::FromStr for SessionSpec {
    type Err = String;

    /// Parses `NAME=DIR`; the name must be non-empty and free of `/`.
    fn from_str(arg: &str) -> Result<Self, String> {
        let Some((name, dir)) = arg.split_once('=') else {
            return Err(format!("{arg:?} is not NAME=DIR"));
        };
        if name.is_empty() || name.contains(['/', '\\']) || name.trim() != name {
            return Err(format!("session name {name:?} must be non-empty, without '/' or surrounding spaces"));
        }
        if dir.is_empty() {
            return Err(format!("session {name} has no folder"));
        }
        Ok(Self { name: name.to_owned(), dir: PathBuf::from(dir) })
    }
}

/// A session's images, sorted by file name (= time order for numbered frames),
/// all of one size.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct SessionImages {
    pub name: String,
    /// Absolute folder.
    pub dir: PathBuf,
    /// File names inside `dir`, sorted.
    pub files: Vec<String>,
    pub width: u32,
    pub height: u32,
}

impl SessionImages {
    /// COLMAP image names, `session/file`, in file order.
    pub fn image_names(&self) -> Vec<String> {
        self.files.iter().map(|f| revisit_core::image_name(&self.name, f)).collect()
    }
}

/// Checks that no session name is given twice.
pub fn check_unique(specs: &[SessionSpec]) -> Result<(), PipelineError> {
    let mut seen = BTreeSet::new();
    for spec in specs {
        if !seen.insert(spec.name.as_str()) {
            return Err(PipelineError::DuplicateSession(spec.name.clone()));
        }
    }
    Ok(())
}

fn is_image(path: &Path) -> bool {
    path.extension()
        .and_then(|e| e.to_str())
        .is_some_and(|e| IMAGE_EXTENSIONS.contains(&e.to_ascii_lowercase().as_str()))
}

/// Lists and checks a session's images: the folder must exist and hold
/// images, every header must be readable, and all images must share one size
/// (one camera per session).
pub fn scan_session(spec: &SessionSpec) -> Result<SessionImages, PipelineError> {
    let dir =
        std::fs::canonicalize(&spec.dir).map_err(|source| PipelineError::Io { path: spec.dir.clone(), source })?;
    let entries = std::fs::read_dir(&dir).map_err(|source| PipelineError::Io { path: dir.clone(), source })?;
    let mut files = Vec::new();
    for entry in entries {
        let entry = entry.map_err(|source| PipelineError::Io { path: dir.clone(), source })?;
        let path = entry.path();
        if path.is_file() && is_image(&path) {
            if let Some(name) = path.file_name().and_then(|n| n.to_str()) {
                files.push(name.to_owned());
            }
        }
    }
    files.sort();
    let Some(first) = files.first() else {
        return Err(PipelineError::NoImages { session: spec.name.clone(), dir });
    };
    if files.len() == 1 {
        return Err(PipelineError::OneImage { session: spec.name.clone(), dir });
    }
    let size = |file: &str| {
        let path = dir.join(file);
        image::image_dimensions(&path).map_err(|e| PipelineError::BadImage { path, reason: e.to_string() })
    };
    let (width, height) = size(first)?;
    for file in &files[1..] {
        let (w, h) = size(file)?;
        if (w, h) != (width, height) {
            return Err(PipelineError::MixedSizes {
                session: spec.name.clone(),
                path: dir.join(file),
                size: (w, h),
                first: dir.join(first),
                first_size: (width, height),
            });
        }
    }
    Ok(SessionImages { name: spec.name.clone(), dir, files, width, height })
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
        assert!("a/b=/x".parse::<SessionSpec>().is_err());
        assert!("=/x".parse::<SessionSpec>().is_err());
    }

    #[test]
    fn duplicate_names_are_rejected() {
        let specs: Vec<SessionSpec> = ["a=/x", "b=/y", "a=/z"].iter().map(|s| s.parse().unwrap()).collect();
        assert_eq!(check_unique(&specs).unwrap_err().to_string(), "session a is given twice");
    }

    #[test]
    fn folders_are_checked() {
        let dir = tempfile::tempdir().unwrap();
        let spec = SessionSpec { name: "s".into(), dir: dir.path().into() };
        assert!(matches!(scan_session(&spec), Err(PipelineError::NoImages { .. })));
        image::GrayImage::new(32, 24).save(dir.path().join("b.png")).unwrap();
        assert!(matches!(scan_session(&spec), Err(PipelineError::OneImage { .. })));
        image::GrayImage::new(32, 24).save(dir.path().join("a.png")).unwrap();
        let images = scan_session(&spec).unwrap();
        assert_eq!(images.files, vec!["a.png", "b.png"]);
        assert_eq!(images.image_names(), vec!["s/a.png", "s/b.png"]);
        image::GrayImage::new(16, 24).save(dir.path().join("c.png")).unwrap();
        let err = scan_session(&spec).unwrap_err().to_string();
        assert!(err.contains("c.png is 16x24"), "{err}");
        std::fs::write(dir.path().join("d.png"), b"not a png").unwrap();
        let err = scan_session(&spec).unwrap_err().to_string();
        assert!(err.contains("c.png") || err.contains("d.png"), "{err}");
    }
}
