//! A node's persistent memory: an append-only file of lines, each written and flushed to disk before
//! the work it records is announced, so that a node killed at any point and restarted knows what it
//! finished. A torn last line (the node killed while writing it) is ignored.

use std::fs::{File, OpenOptions};
use std::io::Write;
use std::path::{Path, PathBuf};

use crate::NodeError;

pub struct Journal {
    path: PathBuf,
    file: File,
}

impl Journal {
    /// Opens (or creates) the journal at `path` and returns its complete lines.
    pub fn open(path: &Path) -> Result<(Journal, Vec<String>), NodeError> {
        let io = |source: std::io::Error| NodeError::State(format!("{}: {source}", path.display()));
        if let Some(dir) = path.parent() {
            std::fs::create_dir_all(dir).map_err(io)?;
        }
        let text = match std::fs::read(path) {
            Ok(bytes) => bytes,
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => Vec::new(),
            Err(e) => return Err(io(e)),
        };
        let complete = text.iter().rposition(|b| *b == b'\n').map_or(0, |at| at + 1);
        let lines = String::from_utf8(text[..complete].to_vec())
            .map_err(|_| NodeError::State(format!("{}: not UTF-8 text", path.display())))?
            .lines()
            .map(str::to_owned)
            .collect();
        let file = OpenOptions::new().create(true).append(true).open(path).map_err(io)?;
        // Drops a torn last line, so the next one starts on a line of its own.
        file.set_len(complete as u64).map_err(io)?;
        Ok((Journal { path: path.to_path_buf(), file }, lines))
    }

    /// Appends one line (which must not hold a line break) and flushes it to disk.
    pub fn append(&mut self, line: &str) -> Result<(), NodeError> {
        debug_assert!(!line.contains('\n'));
        let io = |source: std::io::Error| NodeError::State(format!("{}: {source}", self.path.display()));
        self.file.write_all(format!("{line}\n").as_bytes()).map_err(io)?;
        self.file.sync_data().map_err(io)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn lines_survive_a_restart_and_a_torn_line_is_dropped() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("state/journal");
        let (mut journal, lines) = Journal::open(&path).unwrap();
        assert!(lines.is_empty());
        journal.append("visit a").unwrap();
        journal.append("done a/1.png").unwrap();
        drop(journal);
        std::fs::OpenOptions::new().append(true).open(&path).unwrap().write_all(b"done a/2.p").unwrap();
        let (mut journal, lines) = Journal::open(&path).unwrap();
        assert_eq!(lines, ["visit a", "done a/1.png"]);
        journal.append("done a/2.png").unwrap();
        let (_, lines) = Journal::open(&path).unwrap();
        assert_eq!(lines, ["visit a", "done a/1.png", "done a/2.png"]);
    }
}
