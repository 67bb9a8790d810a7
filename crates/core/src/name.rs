//! Names: sessions, cameras and images, checked once where they enter.
//!
//! A COLMAP image name is `session/file`: the session part never holds a
//! separator, the file part may (`cam0/frame_001.png` for a session with a
//! camera per sub-folder). Names end up in SQL rows, CSV cells, file paths and
//! ROS messages, so control characters (line breaks, tabs, NUL) are refused.

use std::fmt;

/// Separator between a session name and a file name in COLMAP image names:
/// the image `frame_001.png` of session `2024` is named `2024/frame_001.png`.
pub const SESSION_SEPARATOR: char = '/';

#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
pub enum NameError {
    #[error("{what} name is empty")]
    Empty { what: &'static str },
    #[error("{what} name {name:?} holds a control character (line break, tab or similar)")]
    Control { what: &'static str, name: String },
    #[error("{what} name {name:?} {reason}")]
    Malformed { what: &'static str, name: String, reason: &'static str },
}

/// Checks a session name: non-empty, no `/` or `\`, no surrounding spaces,
/// no control characters.
pub fn check_session_name(name: &str) -> Result<(), NameError> {
    check_common("session", name)?;
    if name.contains(['/', '\\']) {
        return Err(NameError::Malformed { what: "session", name: name.into(), reason: "holds '/' or '\\'" });
    }
    if name.trim() != name {
        return Err(NameError::Malformed { what: "session", name: name.into(), reason: "has surrounding spaces" });
    }
    Ok(())
}

/// Checks a camera name (a sub-folder of a session, or a size such as `640x480`).
pub fn check_camera_name(name: &str) -> Result<(), NameError> {
    check_common("camera", name)?;
    if name.contains(['/', '\\', '=', ':']) {
        return Err(NameError::Malformed { what: "camera", name: name.into(), reason: "holds '/', '\\', '=' or ':'" });
    }
    Ok(())
}

fn check_common(what: &'static str, name: &str) -> Result<(), NameError> {
    if name.is_empty() {
        return Err(NameError::Empty { what });
    }
    if name.chars().any(char::is_control) {
        return Err(NameError::Control { what, name: name.into() });
    }
    Ok(())
}

/// An image's name: the session it belongs to and its file inside the
/// session's folder. Shown (and stored by COLMAP) as `session/file`.
#[derive(Clone, Debug, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub struct ImageName {
    session: String,
    file: String,
}

impl ImageName {
    /// Checks both parts: see [`check_session_name`]; the file is relative,
    /// without `..`, empty components or control characters.
    pub fn new(session: &str, file: &str) -> Result<ImageName, NameError> {
        check_session_name(session)?;
        check_common("image", file)?;
        let bad = |reason| NameError::Malformed { what: "image", name: file.into(), reason };
        if file.contains('\\') {
            return Err(bad("holds '\\'"));
        }
        if file.split(SESSION_SEPARATOR).any(|part| part.is_empty() || part == "." || part == "..") {
            return Err(bad("is not a plain relative path"));
        }
        Ok(ImageName { session: session.to_owned(), file: file.to_owned() })
    }

    /// Parses a COLMAP image name `session/file`.
    pub fn parse(name: &str) -> Result<ImageName, NameError> {
        let Some((session, file)) = name.split_once(SESSION_SEPARATOR) else {
            return Err(NameError::Malformed { what: "image", name: name.into(), reason: "has no session/ part" });
        };
        ImageName::new(session, file)
    }

    pub fn session(&self) -> &str {
        &self.session
    }

    /// The file, relative to the session's folder.
    pub fn file(&self) -> &str {
        &self.file
    }
}

impl fmt::Display for ImageName {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}{SESSION_SEPARATOR}{}", self.session, self.file)
    }
}

/// The session of a COLMAP image name (`""` for a name with no session part,
/// e.g. a model made by another tool).
pub fn session_of(name: &str) -> &str {
    name.split_once(SESSION_SEPARATOR).map_or("", |(session, _)| session)
}

/// Whether an image pair lies within one visit or across two.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord, Hash, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum PairKind {
    /// Both images of one session.
    Intra,
    /// Images of two different sessions.
    Cross,
}

impl PairKind {
    /// The word stored and reported (`intra`, `cross`).
    pub fn as_str(self) -> &'static str {
        match self {
            PairKind::Intra => "intra",
            PairKind::Cross => "cross",
        }
    }

    /// Parses [`PairKind::as_str`]'s word.
    pub fn parse(word: &str) -> Option<PairKind> {
        match word {
            "intra" => Some(PairKind::Intra),
            "cross" => Some(PairKind::Cross),
            _ => None,
        }
    }
}

impl fmt::Display for PairKind {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.as_str())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn image_names_round_trip_and_keep_sub_folders() {
        let name = ImageName::new("2019, \"north\" été", "cam0/frame 001.png").unwrap();
        assert_eq!(name.to_string(), "2019, \"north\" été/cam0/frame 001.png");
        assert_eq!(ImageName::parse(&name.to_string()).unwrap(), name);
        assert_eq!(name.session(), "2019, \"north\" été");
        assert_eq!(name.file(), "cam0/frame 001.png");
    }

    #[test]
    fn control_characters_and_odd_paths_are_refused() {
        assert!(matches!(ImageName::new("a\nb", "x.png"), Err(NameError::Control { .. })));
        assert!(matches!(ImageName::new("a", "x\r.png"), Err(NameError::Control { .. })));
        assert!(ImageName::new("a", "../x.png").is_err());
        assert!(ImageName::new("a", "/x.png").is_err());
        assert!(ImageName::new("a/b", "x.png").is_err());
        assert!(ImageName::new("", "x.png").is_err());
        assert!(ImageName::parse("nosession").is_err());
        assert!(check_camera_name("cam\t0").is_err());
        assert!(check_camera_name("640x480").is_ok());
    }

    #[test]
    fn pair_kinds_have_one_word_each() {
        for kind in [PairKind::Intra, PairKind::Cross] {
            assert_eq!(PairKind::parse(kind.as_str()), Some(kind));
        }
        assert_eq!(PairKind::parse("other"), None);
    }
}
