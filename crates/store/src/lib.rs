//! The store: one SQLite file that is both a COLMAP database (3.8 schema, read
//! by COLMAP 3.8 and pycolmap 4.x, plus COLMAP 4's `pose_priors`) and
//! Revisit's memory of the work done: sessions, which image pairs were
//! matched, how and with what result.
//!
//! Invariant: the only code in Revisit that speaks SQL. Every write of one
//! image's features or one pair's matches is a single transaction, so a killed
//! run leaves complete records only, and "is it done?" is "is the row there?".

mod blob;
mod learned;
mod priors;
mod schema;

pub use learned::CrossSide;
pub use priors::PosePrior;
pub use revisit_core::CrossKey;

use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};

use revisit_core::{
    pair_from_id, pair_id, Camera, CameraId, CameraModel, Features, ImageId, Keypoint, PairKind, TwoViewConfig,
    TwoViewGeometry,
};
use rusqlite::{params, Connection, OptionalExtension};

#[derive(Debug, thiserror::Error)]
pub enum StoreError {
    #[error("store {path}: {source}")]
    Sqlite { path: PathBuf, source: rusqlite::Error },
    #[error("store {path}: {what} is corrupt: {reason}")]
    Corrupt { path: PathBuf, what: String, reason: String },
    #[error("store {path}: session {session:?} was added from {stored}, not {given}")]
    SessionSourceMismatch { path: PathBuf, session: String, stored: String, given: String },
    #[error("store {path}: {key} was {stored} when the store was made, not {given}; use a new output folder")]
    SettingMismatch { path: PathBuf, key: String, stored: String, given: String },
    #[error("store {path} was made by an older Revisit (its sessions have no visit order); use a new output folder")]
    OldSchema { path: PathBuf },
    #[error("store {path}: camera {name} is {stored}, not {given}")]
    CameraMismatch { path: PathBuf, name: String, stored: String, given: String },
    #[error("store {path}: no image with id {image_id}")]
    UnknownImage { path: PathBuf, image_id: ImageId },
}

pub type Result<T> = std::result::Result<T, StoreError>;

/// What Revisit remembers of one matched image pair.
#[derive(Clone, Debug, PartialEq)]
pub struct PairRecord {
    pub image_id1: ImageId,
    pub image_id2: ImageId,
    pub kind: PairKind,
    /// The matcher, e.g. `sift`.
    pub method: String,
    /// The roll applied to image 2 before matching, degrees (0 for SIFT).
    pub roll_deg: i32,
    /// The roll the visits' other pairs predicted for image 2, degrees, when one was
    /// (`roll_deg` is the one that won).
    pub predicted_roll_deg: Option<i32>,
    pub num_matches: usize,
    pub num_inliers: usize,
}

/// A session as stored: its name, where its images came from, and its place
/// in the order of visits (0 = the first, the reference).
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct SessionRecord {
    pub name: String,
    pub source: String,
    pub visit: usize,
}

pub struct Store {
    conn: Connection,
    path: PathBuf,
}

impl Store {
    /// Opens (creating if needed) the store at `path`.
    pub fn open(path: &Path) -> Result<Self> {
        let conn = Connection::open(path).map_err(|source| StoreError::Sqlite { path: path.into(), source })?;
        let store = Self { conn, path: path.to_path_buf() };
        // Write-ahead logging: readers watching a running reconstruction (a
        // viewer, a node, a test) neither block the writer nor starve behind it.
        let _mode: String =
            store.conn.query_row("PRAGMA journal_mode=WAL", [], |row| row.get(0)).map_err(|e| store.sql(e))?;
        store.conn.execute_batch(schema::SCHEMA).map_err(|e| store.sql(e))?;
        let visit_column: i64 = store
            .conn
            .query_row("SELECT COUNT(*) FROM pragma_table_info('revisit_sessions') WHERE name = 'visit'", [], |r| {
                r.get(0)
            })
            .map_err(|e| store.sql(e))?;
        if visit_column == 0 {
            return Err(StoreError::OldSchema { path: path.to_path_buf() });
        }
        Ok(store)
    }

    /// Opens an existing store read-only, e.g. to watch a running
    /// reconstruction without taking a write lock.
    pub fn open_read_only(path: &Path) -> Result<Self> {
        let conn = Connection::open_with_flags(path, rusqlite::OpenFlags::SQLITE_OPEN_READ_ONLY)
            .map_err(|source| StoreError::Sqlite { path: path.into(), source })?;
        Ok(Self { conn, path: path.to_path_buf() })
    }

    pub fn path(&self) -> &Path {
        &self.path
    }

    /// Writes a consistent copy of the whole store to `to` (a new file; SQLite's `VACUUM
    /// INTO`), e.g. to start another reconstruction from this one's work.
    pub fn copy_to(&self, to: &Path) -> Result<()> {
        let target = to.to_str().ok_or_else(|| self.corrupt(to.display().to_string(), "not a UTF-8 path"))?;
        self.conn.execute("VACUUM INTO ?1", [target]).map_err(|e| self.sql(e))?;
        Ok(())
    }

    fn sql(&self, source: rusqlite::Error) -> StoreError {
        StoreError::Sqlite { path: self.path.clone(), source }
    }

    fn corrupt(&self, what: impl Into<String>, reason: impl Into<String>) -> StoreError {
        StoreError::Corrupt { path: self.path.clone(), what: what.into(), reason: reason.into() }
    }

    /// Records `value` under `key` the first time; later calls must give the
    /// same value (e.g. the feature options a store was built with).
    pub fn pin_setting(&self, key: &str, value: &str) -> Result<()> {
        let stored: Option<String> = self
            .conn
            .query_row("SELECT value FROM revisit_settings WHERE key = ?1", [key], |r| r.get(0))
            .optional()
            .map_err(|e| self.sql(e))?;
        match stored {
            Some(stored) if stored != value => Err(StoreError::SettingMismatch {
                path: self.path.clone(),
                key: key.into(),
                stored,
                given: value.into(),
            }),
            Some(_) => Ok(()),
            None => {
                self.conn
                    .execute("INSERT INTO revisit_settings (key, value) VALUES (?1, ?2)", [key, value])
                    .map_err(|e| self.sql(e))?;
                Ok(())
            }
        }
    }

    /// The sessions in the store, in visit order.
    pub fn sessions(&self) -> Result<Vec<SessionRecord>> {
        let mut stmt = self
            .conn
            .prepare("SELECT name, source, visit FROM revisit_sessions ORDER BY visit")
            .map_err(|e| self.sql(e))?;
        let rows = stmt
            .query_map([], |r| Ok(SessionRecord { name: r.get(0)?, source: r.get(1)?, visit: count(r.get(2)?) }))
            .map_err(|e| self.sql(e))?;
        rows.collect::<std::result::Result<_, _>>().map_err(|e| self.sql(e))
    }

    /// Adds a session as the next visit, or returns the stored one if it was
    /// added before from the same source.
    pub fn ensure_session(&mut self, name: &str, source: &str) -> Result<SessionRecord> {
        let sessions = self.sessions()?;
        if let Some(stored) = sessions.iter().find(|s| s.name == name) {
            if stored.source != source {
                return Err(StoreError::SessionSourceMismatch {
                    path: self.path.clone(),
                    session: name.into(),
                    stored: stored.source.clone(),
                    given: source.into(),
                });
            }
            return Ok(stored.clone());
        }
        let visit = sessions.iter().map(|s| s.visit + 1).max().unwrap_or(0);
        self.conn
            .execute(
                "INSERT INTO revisit_sessions (name, source, visit) VALUES (?1, ?2, ?3)",
                params![name, source, visit as i64],
            )
            .map_err(|e| self.sql(e))?;
        Ok(SessionRecord { name: name.into(), source: source.into(), visit })
    }

    /// Adds the camera named `name` (e.g. `session/camera`) or returns the
    /// stored one, which must have the same model and size; its parameters
    /// are kept as first stored. `prior_focal_length` marks the focal length
    /// as known (calibrated, or from EXIF), as COLMAP does.
    pub fn ensure_camera(&mut self, name: &str, camera: &Camera, prior_focal_length: bool) -> Result<Camera> {
        let stored: Option<CameraId> = self
            .conn
            .query_row("SELECT camera_id FROM revisit_cameras WHERE name = ?1", [name], |r| r.get(0))
            .optional()
            .map_err(|e| self.sql(e))?;
        if let Some(camera_id) = stored {
            let stored = self.camera(camera_id)?;
            if (stored.model, stored.width, stored.height) != (camera.model, camera.width, camera.height) {
                return Err(StoreError::CameraMismatch {
                    path: self.path.clone(),
                    name: name.into(),
                    stored: format!("{} {}x{}", stored.model.name(), stored.width, stored.height),
                    given: format!("{} {}x{}", camera.model.name(), camera.width, camera.height),
                });
            }
            return Ok(stored);
        }
        let path = self.path.clone();
        let sql = |source| StoreError::Sqlite { path: path.clone(), source };
        let tx = self.conn.transaction().map_err(sql)?;
        tx.execute(
            "INSERT INTO cameras (model, width, height, params, prior_focal_length) VALUES (?1, ?2, ?3, ?4, ?5)",
            params![camera.model.id(), camera.width, camera.height, blob::f64s(&camera.params), prior_focal_length],
        )
        .map_err(sql)?;
        let camera_id = CameraId::try_from(tx.last_insert_rowid()).unwrap_or(0);
        tx.execute("INSERT INTO revisit_cameras (name, camera_id) VALUES (?1, ?2)", params![name, camera_id])
            .map_err(sql)?;
        tx.commit().map_err(sql)?;
        Ok(Camera { camera_id, ..camera.clone() })
    }

    pub fn camera(&self, camera_id: CameraId) -> Result<Camera> {
        let (model, width, height, params): (i64, u32, u32, Vec<u8>) = self
            .conn
            .query_row("SELECT model, width, height, params FROM cameras WHERE camera_id = ?1", [camera_id], |r| {
                Ok((r.get(0)?, r.get(1)?, r.get(2)?, r.get(3)?))
            })
            .map_err(|e| self.sql(e))?;
        let what = || format!("camera {camera_id}");
        let model = CameraModel::from_id(model).map_err(|e| self.corrupt(what(), e.to_string()))?;
        let params = blob::to_f64s(&params).ok_or_else(|| self.corrupt(what(), "params blob length"))?;
        Camera::new(camera_id, model, width, height, params).map_err(|e| self.corrupt(what(), e.to_string()))
    }

    /// Adds images (COLMAP names `session/file`) with their camera, keeping
    /// those already there; returns every image's id by name.
    /// Only new names are inserted, so ids run without gaps in the order
    /// images were first added, however often a visit is added again.
    pub fn ensure_images(&mut self, names: &[String], camera_id: CameraId) -> Result<BTreeMap<String, ImageId>> {
        let stored = self.image_ids()?;
        let path = self.path.clone();
        let sql = |source| StoreError::Sqlite { path: path.clone(), source };
        let tx = self.conn.transaction().map_err(sql)?;
        {
            let mut insert =
                tx.prepare("INSERT OR IGNORE INTO images (name, camera_id) VALUES (?1, ?2)").map_err(sql)?;
            for name in names.iter().filter(|name| !stored.contains_key(*name)) {
                insert.execute(params![name, camera_id]).map_err(sql)?;
            }
        }
        tx.commit().map_err(sql)?;
        self.image_ids()
    }

    /// Every image's id, by name.
    pub fn image_ids(&self) -> Result<BTreeMap<String, ImageId>> {
        let mut stmt = self.conn.prepare("SELECT name, image_id FROM images").map_err(|e| self.sql(e))?;
        let rows = stmt.query_map([], |r| Ok((r.get(0)?, r.get(1)?))).map_err(|e| self.sql(e))?;
        rows.collect::<std::result::Result<_, _>>().map_err(|e| self.sql(e))
    }

    /// Images whose features are stored.
    pub fn images_with_features(&self) -> Result<BTreeSet<ImageId>> {
        let mut stmt = self
            .conn
            .prepare("SELECT k.image_id FROM keypoints k JOIN descriptors d ON d.image_id = k.image_id")
            .map_err(|e| self.sql(e))?;
        let rows = stmt.query_map([], |r| r.get(0)).map_err(|e| self.sql(e))?;
        rows.collect::<std::result::Result<_, _>>().map_err(|e| self.sql(e))
    }

    /// Stores one image's keypoints and descriptors in one transaction.
    pub fn write_features(&mut self, image_id: ImageId, features: &Features) -> Result<()> {
        let path = self.path.clone();
        let sql = |source| StoreError::Sqlite { path: path.clone(), source };
        let keypoints: Vec<f32> = features.keypoints.iter().flat_map(Keypoint::to_affine).collect();
        let tx = self.conn.transaction().map_err(sql)?;
        tx.execute(
            "INSERT OR REPLACE INTO keypoints (image_id, rows, cols, data) VALUES (?1, ?2, 6, ?3)",
            params![image_id, features.len() as i64, blob::f32s(&keypoints)],
        )
        .map_err(sql)?;
        tx.execute(
            "INSERT OR REPLACE INTO descriptors (image_id, rows, cols, data) VALUES (?1, ?2, ?3, ?4)",
            params![image_id, features.len() as i64, features.descriptor_dim as i64, features.descriptors],
        )
        .map_err(sql)?;
        tx.commit().map_err(sql)
    }

    /// The image's own (SIFT) features: keypoints with descriptors. Keypoints
    /// that cross-visit matching appended after them are not included.
    pub fn read_features(&self, image_id: ImageId) -> Result<Features> {
        let what = || format!("features of image {image_id}");
        let row = self
            .conn
            .query_row(
                "SELECT k.rows, k.cols, k.data, d.rows, d.cols, d.data FROM keypoints k \
                 JOIN descriptors d ON d.image_id = k.image_id WHERE k.image_id = ?1",
                [image_id],
                |r| {
                    Ok((
                        count(r.get(0)?),
                        count(r.get(1)?),
                        r.get::<_, Option<Vec<u8>>>(2)?.unwrap_or_default(),
                        count(r.get(3)?),
                        count(r.get(4)?),
                        r.get::<_, Option<Vec<u8>>>(5)?.unwrap_or_default(),
                    ))
                },
            )
            .optional()
            .map_err(|e| self.sql(e))?;
        let Some((rows, cols, kp_blob, drows, dcols, descriptors)) = row else {
            return Err(StoreError::UnknownImage { path: self.path.clone(), image_id });
        };
        let values = blob::to_f32s(&kp_blob).ok_or_else(|| self.corrupt(what(), "keypoint blob length"))?;
        if values.len() != rows * cols || drows > rows || descriptors.len() != drows * dcols || cols == 0 {
            return Err(self.corrupt(what(), "row/column counts disagree with the blobs"));
        }
        // Keypoints past the descriptors' rows were added by cross-visit matching.
        let keypoints = values
            .chunks_exact(cols)
            .take(drows)
            .map(|row| Keypoint::from_columns(row).ok_or_else(|| self.corrupt(what(), format!("{cols} columns"))))
            .collect::<Result<Vec<_>>>()?;
        Ok(Features { keypoints, descriptors, descriptor_dim: dcols })
    }

    /// Every keypoint of the image: its own (SIFT) ones, then the learned
    /// keypoints registered after them.
    pub fn read_keypoints(&self, image_id: ImageId) -> Result<Vec<Keypoint>> {
        let what = || format!("keypoints of image {image_id}");
        let row: Option<(usize, usize, Vec<u8>)> = self
            .conn
            .query_row("SELECT rows, cols, data FROM keypoints WHERE image_id = ?1", [image_id], |r| {
                Ok((count(r.get(0)?), count(r.get(1)?), r.get::<_, Option<Vec<u8>>>(2)?.unwrap_or_default()))
            })
            .optional()
            .map_err(|e| self.sql(e))?;
        let Some((rows, cols, data)) = row else {
            return Err(StoreError::UnknownImage { path: self.path.clone(), image_id });
        };
        let values = blob::to_f32s(&data).filter(|v| v.len() == rows * cols && cols > 0);
        let values = values.ok_or_else(|| self.corrupt(what(), "row/column counts disagree with the blob"))?;
        values
            .chunks_exact(cols)
            .map(|row| Keypoint::from_columns(row).ok_or_else(|| self.corrupt(what(), format!("{cols} columns"))))
            .collect()
    }

    /// The method each stored pair was matched with, by COLMAP pair id.
    pub fn pair_methods(&self) -> Result<BTreeMap<u64, String>> {
        let mut stmt = self.conn.prepare("SELECT pair_id, method FROM revisit_pairs").map_err(|e| self.sql(e))?;
        let rows = stmt.query_map([], |r| Ok((r.get::<_, i64>(0)? as u64, r.get(1)?))).map_err(|e| self.sql(e))?;
        rows.collect::<std::result::Result<_, _>>().map_err(|e| self.sql(e))
    }

    /// Pairs already matched and verified (COLMAP pair ids).
    pub fn matched_pairs(&self) -> Result<BTreeSet<u64>> {
        let mut stmt = self.conn.prepare("SELECT pair_id FROM revisit_pairs").map_err(|e| self.sql(e))?;
        let rows = stmt.query_map([], |r| r.get::<_, i64>(0)).map_err(|e| self.sql(e))?;
        rows.map(|r| r.map(|id| id as u64)).collect::<std::result::Result<_, _>>().map_err(|e| self.sql(e))
    }

    /// Stores one pair's raw matches, verified geometry and record in one
    /// transaction. Matches index (image 1, image 2) of `record`; they are
    /// swapped as COLMAP wants when image 1 has the larger id.
    pub fn write_pair(&mut self, record: &PairRecord, matches: &[[u32; 2]], geometry: &TwoViewGeometry) -> Result<()> {
        let path = self.path.clone();
        let sql = |source| StoreError::Sqlite { path: path.clone(), source };
        let tx = self.conn.transaction().map_err(sql)?;
        insert_pair(&tx, record, matches, geometry, None).map_err(sql)?;
        tx.commit().map_err(sql)
    }

    /// Every pair record, ordered by pair id.
    pub fn pair_records(&self) -> Result<Vec<PairRecord>> {
        let mut stmt = self
            .conn
            .prepare(
                "SELECT p.image_id1, p.image_id2, p.kind, p.method, p.roll_deg, p.num_matches, p.num_inliers, \
                 r.predicted_roll_deg FROM revisit_pairs p \
                 LEFT JOIN revisit_roll_predictions r ON r.pair_id = p.pair_id ORDER BY p.pair_id",
            )
            .map_err(|e| self.sql(e))?;
        let rows = stmt
            .query_map([], |r| {
                let kind: String = r.get(2)?;
                Ok(PairRecord {
                    image_id1: r.get(0)?,
                    image_id2: r.get(1)?,
                    kind: PairKind::parse(&kind).unwrap_or(PairKind::Intra),
                    method: r.get(3)?,
                    roll_deg: r.get(4)?,
                    predicted_roll_deg: r.get(7)?,
                    num_matches: count(r.get(5)?),
                    num_inliers: count(r.get(6)?),
                })
            })
            .map_err(|e| self.sql(e))?;
        rows.collect::<std::result::Result<_, _>>().map_err(|e| self.sql(e))
    }

    /// Sets a verified pair's two-view geometry aside (COLMAP no longer sees
    /// it), with the reason; its matches and record stay. One transaction.
    pub fn set_aside(&mut self, pair: u64, reason: &str) -> Result<()> {
        self.move_geometry(
            "INSERT OR REPLACE INTO revisit_set_aside \
             SELECT pair_id, ?2, rows, cols, data, config, F, E, H, qvec, tvec FROM two_view_geometries WHERE pair_id = ?1",
            params![pair as i64, reason],
            "DELETE FROM two_view_geometries WHERE pair_id = ?1",
            pair,
        )
    }

    /// Puts a pair set aside back where COLMAP reads it. One transaction.
    pub fn restore_set_aside(&mut self, pair: u64) -> Result<()> {
        self.move_geometry(
            // Columns named: pycolmap adds its own to COLMAP's table when it maps.
            "INSERT OR REPLACE INTO two_view_geometries (pair_id, rows, cols, data, config, F, E, H, qvec, tvec) \
             SELECT pair_id, rows, cols, data, config, F, E, H, qvec, tvec FROM revisit_set_aside WHERE pair_id = ?1",
            params![pair as i64],
            "DELETE FROM revisit_set_aside WHERE pair_id = ?1",
            pair,
        )
    }

    /// Runs `copy` (with `copy_params`), then `delete` (with `pair`), in one transaction.
    fn move_geometry(
        &mut self,
        copy: &str,
        copy_params: &[&dyn rusqlite::ToSql],
        delete: &str,
        pair: u64,
    ) -> Result<()> {
        let path = self.path.clone();
        let sql = |source| StoreError::Sqlite { path: path.clone(), source };
        let tx = self.conn.transaction().map_err(sql)?;
        tx.execute(copy, copy_params).map_err(sql)?;
        tx.execute(delete, params![pair as i64]).map_err(sql)?;
        tx.commit().map_err(sql)
    }

    /// The pairs set aside, with their reasons.
    pub fn set_aside_pairs(&self) -> Result<BTreeMap<u64, String>> {
        let mut stmt = self.conn.prepare("SELECT pair_id, reason FROM revisit_set_aside").map_err(|e| self.sql(e))?;
        let rows = stmt.query_map([], |r| Ok((r.get::<_, i64>(0)? as u64, r.get(1)?))).map_err(|e| self.sql(e))?;
        rows.collect::<std::result::Result<_, _>>().map_err(|e| self.sql(e))
    }

    /// Puts a confident pair's confident geometry where COLMAP reads it (`true`), or its verified
    /// geometry back (`false`): the two change places, the other kept aside. Nothing is done to a
    /// pair without a confident geometry or set aside (COLMAP does not see it). Returns whether the
    /// geometries changed places. One transaction.
    pub fn use_confident(&mut self, pair: u64, yes: bool) -> Result<bool> {
        const COLUMNS: &str = "rows, cols, data, config, F, E, H, qvec, tvec";
        let path = self.path.clone();
        let sql = |source| StoreError::Sqlite { path: path.clone(), source };
        let tx = self.conn.transaction().map_err(sql)?;
        let row = |table: &str| -> rusqlite::Result<Option<Vec<rusqlite::types::Value>>> {
            let query = format!("SELECT {COLUMNS} FROM {table} WHERE pair_id = ?1");
            tx.query_row(&query, [pair as i64], |r| (0..9).map(|i| r.get(i)).collect()).optional()
        };
        let in_use: Option<bool> = tx
            .query_row("SELECT in_use FROM revisit_confident_geometries WHERE pair_id = ?1", [pair as i64], |r| {
                r.get(0)
            })
            .optional()
            .map_err(sql)?;
        let (Some(in_use), Some(seen), Some(kept)) =
            (in_use, row("two_view_geometries").map_err(sql)?, row("revisit_confident_geometries").map_err(sql)?)
        else {
            return Ok(false);
        };
        if in_use == yes {
            return Ok(false);
        }
        let update = |table: &str, values: Vec<rusqlite::types::Value>| -> rusqlite::Result<usize> {
            let set = "rows = ?2, cols = ?3, data = ?4, config = ?5, F = ?6, E = ?7, H = ?8, qvec = ?9, tvec = ?10";
            let mut values: Vec<rusqlite::types::Value> = values;
            values.insert(0, rusqlite::types::Value::Integer(pair as i64));
            tx.execute(&format!("UPDATE {table} SET {set} WHERE pair_id = ?1"), rusqlite::params_from_iter(values))
        };
        update("two_view_geometries", kept).map_err(sql)?;
        update("revisit_confident_geometries", seen).map_err(sql)?;
        tx.execute("UPDATE revisit_confident_geometries SET in_use = ?2 WHERE pair_id = ?1", params![pair as i64, yes])
            .map_err(sql)?;
        tx.commit().map_err(sql)?;
        Ok(true)
    }

    /// The confident pairs whose confident geometry COLMAP reads ([`Store::use_confident`]).
    pub fn confident_in_use(&self) -> Result<BTreeSet<u64>> {
        let mut stmt = self
            .conn
            .prepare("SELECT pair_id FROM revisit_confident_geometries WHERE in_use = 1")
            .map_err(|e| self.sql(e))?;
        let rows = stmt.query_map([], |r| Ok(r.get::<_, i64>(0)? as u64)).map_err(|e| self.sql(e))?;
        rows.collect::<std::result::Result<_, _>>().map_err(|e| self.sql(e))
    }

    /// The pairs stored with a confident geometry (`revisit_matching::cross`'s rule).
    pub fn confident_pairs(&self) -> Result<BTreeSet<u64>> {
        let mut stmt =
            self.conn.prepare("SELECT pair_id FROM revisit_confident_geometries").map_err(|e| self.sql(e))?;
        let rows = stmt.query_map([], |r| Ok(r.get::<_, i64>(0)? as u64)).map_err(|e| self.sql(e))?;
        rows.collect::<std::result::Result<_, _>>().map_err(|e| self.sql(e))
    }

    /// The verified inlier matches of a pair, indexed (smaller id, larger id),
    /// whether COLMAP sees them, its confident ones ([`Store::use_confident`]) or
    /// none (set aside).
    pub fn verified_matches(&self, pair: u64) -> Result<Vec<[u32; 2]>> {
        let kept_aside = |query: &str| -> Result<Option<Option<Vec<u8>>>> {
            self.conn.query_row(query, [pair as i64], |r| r.get(0)).optional().map_err(|e| self.sql(e))
        };
        let data = match kept_aside("SELECT data FROM revisit_confident_geometries WHERE pair_id = ?1 AND in_use = 1")?
        {
            Some(data) => data,
            None => match kept_aside("SELECT data FROM revisit_set_aside WHERE pair_id = ?1")? {
                Some(data) => data,
                None => return Ok(self.two_view_geometry(pair)?.map(|(_, matches)| matches).unwrap_or_default()),
            },
        };
        let values = blob::to_u32s(&data.unwrap_or_default())
            .ok_or_else(|| self.corrupt(format!("set-aside geometry of pair {pair}"), "blob length"))?;
        Ok(values.chunks_exact(2).map(|c| [c[0], c[1]]).collect())
    }

    /// The verified inlier matches of a pair, indexed (smaller id, larger id).
    pub fn two_view_geometry(&self, pair: u64) -> Result<Option<(TwoViewConfig, Vec<[u32; 2]>)>> {
        let (a, b) = pair_from_id(pair);
        let row: Option<(i64, Option<Vec<u8>>)> = self
            .conn
            .query_row("SELECT config, data FROM two_view_geometries WHERE pair_id = ?1", [pair as i64], |r| {
                Ok((r.get(0)?, r.get(1)?))
            })
            .optional()
            .map_err(|e| self.sql(e))?;
        let Some((config, data)) = row else { return Ok(None) };
        let values = blob::to_u32s(&data.unwrap_or_default())
            .ok_or_else(|| self.corrupt(format!("two-view geometry of images {a} and {b}"), "blob length"))?;
        let matches = values.chunks_exact(2).map(|c| [c[0], c[1]]).collect();
        Ok(Some((TwoViewConfig::from_code(config), matches)))
    }
}

/// Writes a pair's matches, two-view geometry (and its confident geometry, if any) and record
/// inside `tx`.
fn insert_pair(
    tx: &rusqlite::Transaction<'_>,
    record: &PairRecord,
    matches: &[[u32; 2]],
    geometry: &TwoViewGeometry,
    confident: Option<&TwoViewGeometry>,
) -> rusqlite::Result<()> {
    let id = pair_id(record.image_id1, record.image_id2);
    let swapped = record.image_id1 > record.image_id2;
    tx.execute(
        "INSERT OR REPLACE INTO matches (pair_id, rows, cols, data) VALUES (?1, ?2, 2, ?3)",
        params![id as i64, matches.len() as i64, blob::u32s(&ordered(matches, swapped))],
    )?;
    insert_geometry(tx, "two_view_geometries", id, swapped, geometry)?;
    // A pair matched again is judged afresh.
    tx.execute("DELETE FROM revisit_set_aside WHERE pair_id = ?1", [id as i64])?;
    tx.execute(
        "INSERT OR REPLACE INTO revisit_pairs (pair_id, image_id1, image_id2, kind, method, roll_deg, \
         num_matches, num_inliers) VALUES (?1, ?2, ?3, ?4, ?5, ?6, ?7, ?8)",
        params![
            id as i64,
            record.image_id1.min(record.image_id2),
            record.image_id1.max(record.image_id2),
            record.kind.as_str(),
            record.method,
            record.roll_deg,
            record.num_matches as i64,
            record.num_inliers as i64
        ],
    )?;
    tx.execute("DELETE FROM revisit_roll_predictions WHERE pair_id = ?1", [id as i64])?;
    if let Some(predicted) = record.predicted_roll_deg {
        tx.execute(
            "INSERT INTO revisit_roll_predictions (pair_id, predicted_roll_deg) VALUES (?1, ?2)",
            params![id as i64, predicted],
        )?;
    }
    tx.execute("DELETE FROM revisit_confident_geometries WHERE pair_id = ?1", [id as i64])?;
    if let Some(confident) = confident {
        insert_geometry(tx, "revisit_confident_geometries", id, swapped, confident)?;
    }
    Ok(())
}

/// Match index pairs flattened, (image 1, image 2) swapped when `swapped` (COLMAP keeps a pair by
/// its smaller image id first).
fn ordered(matches: &[[u32; 2]], swapped: bool) -> Vec<u32> {
    matches.iter().flat_map(|&[a, b]| if swapped { [b, a] } else { [a, b] }).collect()
}

/// Writes `geometry` of pair `id` into `table` (COLMAP's `two_view_geometries` or a table of its
/// columns), seen from the smaller image id when `swapped`.
fn insert_geometry(
    tx: &rusqlite::Transaction<'_>,
    table: &str,
    id: u64,
    swapped: bool,
    geometry: &TwoViewGeometry,
) -> rusqlite::Result<usize> {
    let transpose = |m: &nalgebra::Matrix3<f64>| if swapped { m.transpose() } else { *m };
    let matrix = |m: Option<nalgebra::Matrix3<f64>>| m.map(|m| blob::matrix_row_major(&transpose(&m)));
    let pose = geometry.cam2_from_cam1.map(|p| if swapped { p.inverse() } else { p });
    tx.execute(
        &format!(
            "INSERT OR REPLACE INTO {table} (pair_id, rows, cols, data, config, F, E, H, qvec, tvec) \
             VALUES (?1, ?2, 2, ?3, ?4, ?5, ?6, ?7, ?8, ?9)"
        ),
        params![
            id as i64,
            geometry.inlier_matches.len() as i64,
            blob::u32s(&ordered(&geometry.inlier_matches, swapped)),
            geometry.config as i32,
            matrix(geometry.f),
            matrix(geometry.e),
            matrix(geometry.h),
            pose.map(|p| blob::f64s(&p.wxyz())),
            pose.map(|p| blob::f64s(p.translation.as_slice())),
        ],
    )
}

/// A row or match count as stored (SQLite integers are i64).
fn count(value: i64) -> usize {
    usize::try_from(value).unwrap_or(0)
}

#[cfg(test)]
mod tests;
