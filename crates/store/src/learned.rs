//! What cross-visit matching keeps: learned features per image, method and
//! roll; the keypoints it added to COLMAP's keypoint lists; global
//! descriptors for place recognition and their vocabularies.
//!
//! Cross-visit keypoints: COLMAP's matches index each image's one keypoint
//! list. A learned keypoint used by a cross-visit match is either anchored to
//! one of the image's own keypoints (the caller decides) or appended to the
//! list once and remembered by (image, method, roll, learned index), so every
//! pair that uses it shares one index and tracks chain across pairs. Appending
//! never moves an existing keypoint, so matches already stored stay valid.

use std::collections::{BTreeMap, BTreeSet, HashMap};

use revisit_core::{CrossKey, ImageId, Keypoint, LearnedFeatures, TwoViewGeometry};
use rusqlite::{params, OptionalExtension};

use crate::{blob, count, insert_pair, PairRecord, Result, Store, StoreError};

/// One image of a cross-visit pair: which learned features its keys refer to.
#[derive(Clone, Copy, Debug)]
pub struct CrossSide<'a> {
    pub image_id: ImageId,
    pub method: &'a str,
    pub roll_deg: u32,
    /// Learned keypoints in the image's own (unrolled) frame, by learned index.
    pub positions: &'a [[f32; 2]],
}

impl Store {
    /// (image, roll in degrees) of every learned feature set stored for `method`.
    pub fn learned_feature_keys(&self, method: &str) -> Result<BTreeSet<(ImageId, u32)>> {
        let mut stmt = self
            .conn
            .prepare("SELECT image_id, roll_deg FROM revisit_learned_features WHERE method = ?1")
            .map_err(|e| self.sql(e))?;
        let rows = stmt.query_map([method], |r| Ok((r.get(0)?, r.get(1)?))).map_err(|e| self.sql(e))?;
        rows.collect::<std::result::Result<_, _>>().map_err(|e| self.sql(e))
    }

    pub fn write_learned_features(
        &mut self,
        image_id: ImageId,
        method: &str,
        roll_deg: u32,
        features: &LearnedFeatures,
    ) -> Result<()> {
        let keypoints: Vec<f32> = features.keypoints.iter().flatten().copied().collect();
        self.conn
            .execute(
                "INSERT OR REPLACE INTO revisit_learned_features (image_id, method, roll_deg, width, height, rows, \
                 dim, keypoints, descriptors, scores) VALUES (?1, ?2, ?3, ?4, ?5, ?6, ?7, ?8, ?9, ?10)",
                params![
                    image_id,
                    method,
                    roll_deg,
                    features.width,
                    features.height,
                    features.len() as i64,
                    features.descriptor_dim as i64,
                    blob::f32s(&keypoints),
                    blob::f32s(&features.descriptors),
                    blob::f32s(&features.scores),
                ],
            )
            .map_err(|e| self.sql(e))?;
        Ok(())
    }

    pub fn read_learned_features(&self, image_id: ImageId, method: &str, roll_deg: u32) -> Result<LearnedFeatures> {
        let what = || format!("{method} features of image {image_id} at roll {roll_deg}");
        type Row = (u32, u32, i64, i64, Vec<u8>, Vec<u8>, Vec<u8>);
        let row: Option<Row> = self
            .conn
            .query_row(
                "SELECT width, height, rows, dim, keypoints, descriptors, scores FROM revisit_learned_features \
                 WHERE image_id = ?1 AND method = ?2 AND roll_deg = ?3",
                params![image_id, method, roll_deg],
                |r| Ok((r.get(0)?, r.get(1)?, r.get(2)?, r.get(3)?, r.get(4)?, r.get(5)?, r.get(6)?)),
            )
            .optional()
            .map_err(|e| self.sql(e))?;
        let Some((width, height, rows, dim, keypoints, descriptors, scores)) = row else {
            return Err(self.corrupt(what(), "missing"));
        };
        let (rows, dim) = (count(rows), count(dim));
        let decode = |bytes: &[u8], len: usize, name: &str| {
            blob::to_f32s(bytes).filter(|v| v.len() == len).ok_or_else(|| self.corrupt(what(), format!("{name} blob")))
        };
        let keypoints = decode(&keypoints, rows * 2, "keypoint")?;
        Ok(LearnedFeatures {
            keypoints: keypoints.chunks_exact(2).map(|p| [p[0], p[1]]).collect(),
            descriptors: decode(&descriptors, rows * dim, "descriptor")?,
            descriptor_dim: dim,
            scores: decode(&scores, rows, "score")?,
            width,
            height,
        })
    }

    /// Stores a cross-visit pair in one transaction: appends the learned
    /// keypoints its matches use that are not yet in the images' keypoint
    /// lists, then writes matches, geometry and record with the final indices.
    /// `matches` and the inliers are (side 1, side 2) keys; each geometry's
    /// own inlier list is ignored. `confident`: the inliers and geometry of
    /// its confident matches, when they verified alone.
    pub fn write_cross_pair(
        &mut self,
        record: &PairRecord,
        sides: [CrossSide<'_>; 2],
        matches: &[[CrossKey; 2]],
        (inliers, geometry): (&[[CrossKey; 2]], &TwoViewGeometry),
        confident: Option<(&[[CrossKey; 2]], &TwoViewGeometry)>,
    ) -> Result<()> {
        let path = self.path.clone();
        let sql = |source| StoreError::Sqlite { path: path.clone(), source };
        let tx = self.conn.transaction().map_err(sql)?;
        let mut resolved: [HashMap<u32, u32>; 2] = [HashMap::new(), HashMap::new()];
        for (s, side) in sides.iter().enumerate() {
            let keys: BTreeSet<u32> = matches
                .iter()
                .chain(inliers)
                .chain(confident.into_iter().flat_map(|(sure, _)| sure))
                .filter_map(|m| match m[s] {
                    CrossKey::Learned(l) => Some(l),
                    CrossKey::Own(_) => None,
                })
                .collect();
            resolved[s] = keypoint_indices(&tx, &path, side, &keys)?;
        }
        let index = |s: usize, key: CrossKey| match key {
            CrossKey::Own(i) => i,
            CrossKey::Learned(l) => resolved[s][&l],
        };
        let translate =
            |m: &[[CrossKey; 2]]| -> Vec<[u32; 2]> { m.iter().map(|&[a, b]| [index(0, a), index(1, b)]).collect() };
        let verified = TwoViewGeometry { inlier_matches: translate(inliers), ..geometry.clone() };
        let confident =
            confident.map(|(inliers, g)| TwoViewGeometry { inlier_matches: translate(inliers), ..g.clone() });
        insert_pair(&tx, record, &translate(matches), &verified, confident.as_ref()).map_err(sql)?;
        tx.commit().map_err(sql)
    }

    /// Adds every learned keypoint of `side` to the image's keypoint list (the
    /// ones not there yet), so that matches within a visit can use them and
    /// chain with the cross-visit matches that use them. One transaction.
    pub fn register_learned_keypoints(&mut self, side: CrossSide<'_>) -> Result<()> {
        let path = self.path.clone();
        let sql = |source| StoreError::Sqlite { path: path.clone(), source };
        let tx = self.conn.transaction().map_err(sql)?;
        let all: BTreeSet<u32> = (0..side.positions.len() as u32).collect();
        keypoint_indices(&tx, &path, &side, &all)?;
        tx.commit().map_err(sql)
    }

    /// The keypoint index of every registered learned keypoint of (image,
    /// method, roll), by learned index.
    pub fn learned_keypoint_indices(
        &self,
        image_id: ImageId,
        method: &str,
        roll_deg: u32,
    ) -> Result<HashMap<u32, u32>> {
        let mut stmt = self
            .conn
            .prepare(
                "SELECT learned_index, keypoint_index FROM revisit_cross_keypoints \
                 WHERE image_id = ?1 AND method = ?2 AND roll_deg = ?3",
            )
            .map_err(|e| self.sql(e))?;
        let rows = stmt
            .query_map(params![image_id, method, roll_deg], |r| Ok((r.get(0)?, r.get(1)?)))
            .map_err(|e| self.sql(e))?;
        rows.collect::<std::result::Result<_, _>>().map_err(|e| self.sql(e))
    }

    /// Global descriptors of `method`, by (image, roll in degrees).
    pub fn global_descriptors(&self, method: &str) -> Result<BTreeMap<(ImageId, u32), Vec<f32>>> {
        let mut stmt = self
            .conn
            .prepare("SELECT image_id, roll_deg, data FROM revisit_global_descriptors WHERE method = ?1")
            .map_err(|e| self.sql(e))?;
        let rows = stmt
            .query_map([method], |r| Ok((r.get::<_, ImageId>(0)?, r.get::<_, u32>(1)?, r.get::<_, Vec<u8>>(2)?)))
            .map_err(|e| self.sql(e))?;
        let mut out = BTreeMap::new();
        for row in rows {
            let (image_id, roll, data) = row.map_err(|e| self.sql(e))?;
            let values = blob::to_f32s(&data)
                .ok_or_else(|| self.corrupt(format!("global descriptor of image {image_id}"), "blob length"))?;
            out.insert((image_id, roll), values);
        }
        Ok(out)
    }

    pub fn write_global_descriptor(
        &mut self,
        image_id: ImageId,
        method: &str,
        roll_deg: u32,
        data: &[f32],
    ) -> Result<()> {
        self.conn
            .execute(
                "INSERT OR REPLACE INTO revisit_global_descriptors (image_id, method, roll_deg, data) \
                 VALUES (?1, ?2, ?3, ?4)",
                params![image_id, method, roll_deg, blob::f32s(data)],
            )
            .map_err(|e| self.sql(e))?;
        Ok(())
    }

    /// A stored vocabulary: `rows` x `dim` floats.
    pub fn vocabulary(&self, name: &str) -> Result<Option<(usize, Vec<f32>)>> {
        let row: Option<(i64, i64, Vec<u8>)> = self
            .conn
            .query_row("SELECT rows, dim, data FROM revisit_vocabularies WHERE name = ?1", [name], |r| {
                Ok((r.get(0)?, r.get(1)?, r.get(2)?))
            })
            .optional()
            .map_err(|e| self.sql(e))?;
        let Some((rows, dim, data)) = row else { return Ok(None) };
        let values = blob::to_f32s(&data)
            .filter(|v| v.len() == count(rows) * count(dim))
            .ok_or_else(|| self.corrupt(format!("vocabulary {name}"), "blob length"))?;
        Ok(Some((count(dim), values)))
    }

    pub fn write_vocabulary(&mut self, name: &str, dim: usize, data: &[f32]) -> Result<()> {
        let rows = data.len() / dim.max(1);
        self.conn
            .execute(
                "INSERT INTO revisit_vocabularies (name, rows, dim, data) VALUES (?1, ?2, ?3, ?4)",
                params![name, rows as i64, dim as i64, blob::f32s(data)],
            )
            .map_err(|e| self.sql(e))?;
        Ok(())
    }
}

/// The keypoint index of each learned keypoint in `keys` of `side`, appending
/// to the image's keypoint list (in learned order) those it does not hold yet.
fn keypoint_indices(
    tx: &rusqlite::Transaction<'_>,
    path: &std::path::Path,
    side: &CrossSide<'_>,
    keys: &BTreeSet<u32>,
) -> Result<HashMap<u32, u32>> {
    let sql = |source| StoreError::Sqlite { path: path.to_path_buf(), source };
    let mut known: HashMap<u32, u32> = {
        let mut stmt = tx
            .prepare(
                "SELECT learned_index, keypoint_index FROM revisit_cross_keypoints \
                 WHERE image_id = ?1 AND method = ?2 AND roll_deg = ?3",
            )
            .map_err(sql)?;
        let rows = stmt
            .query_map(params![side.image_id, side.method, side.roll_deg], |r| Ok((r.get(0)?, r.get(1)?)))
            .map_err(sql)?;
        rows.collect::<std::result::Result<_, _>>().map_err(sql)?
    };
    let (rows, mut data): (i64, Vec<u8>) = tx
        .query_row("SELECT rows, data FROM keypoints WHERE image_id = ?1 AND cols = 6", [side.image_id], |r| {
            Ok((r.get(0)?, r.get::<_, Option<Vec<u8>>>(1)?.unwrap_or_default()))
        })
        .optional()
        .map_err(sql)?
        .ok_or_else(|| StoreError::UnknownImage { path: path.to_path_buf(), image_id: side.image_id })?;
    let mut next = u32::try_from(rows).unwrap_or(0);
    let mut appended = false;
    let mut out = HashMap::with_capacity(keys.len());
    for &learned in keys {
        let index = match known.get(&learned) {
            Some(&index) => index,
            None => {
                let Some(&[x, y]) = side.positions.get(learned as usize) else {
                    return Err(StoreError::Corrupt {
                        path: path.to_path_buf(),
                        what: format!("learned match of image {}", side.image_id),
                        reason: format!("learned keypoint {learned} does not exist"),
                    });
                };
                let keypoint = Keypoint { x, y, scale: 1.0, orientation: 0.0 };
                data.extend(blob::f32s(&keypoint.to_affine()));
                tx.execute(
                    "INSERT INTO revisit_cross_keypoints (image_id, method, roll_deg, learned_index, \
                     keypoint_index) VALUES (?1, ?2, ?3, ?4, ?5)",
                    params![side.image_id, side.method, side.roll_deg, learned, next],
                )
                .map_err(sql)?;
                known.insert(learned, next);
                appended = true;
                next += 1;
                next - 1
            }
        };
        out.insert(learned, index);
    }
    if appended {
        tx.execute("UPDATE keypoints SET rows = ?1, data = ?2 WHERE image_id = ?3", params![next, data, side.image_id])
            .map_err(sql)?;
    }
    Ok(out)
}
