//! A node's own store of the learned features it was sent (the places and matcher nodes): a
//! store like the mapper's, holding only what those nodes need, so that the cross-visit stages
//! run on it unchanged and a restarted node still has everything it was sent.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use revisit_core::{Camera, ImageId, ImageName, LearnedFeatures, Roll};
use revisit_store::Store;

use crate::messages::FeaturesRecord;
use crate::{PipelineError, Session, SessionImage};

pub struct FeatureCache {
    store: Store,
    /// Where the visits came from, for the record: the topic.
    source: String,
}

impl FeatureCache {
    /// Opens (or creates) the cache at `path`; `source` names where its features come from.
    pub fn open(path: &Path, source: &str) -> Result<FeatureCache, PipelineError> {
        if let Some(dir) = path.parent() {
            std::fs::create_dir_all(dir).map_err(|source| PipelineError::Io { path: dir.to_path_buf(), source })?;
        }
        Ok(FeatureCache { store: Store::open(path)?, source: source.to_owned() })
    }

    pub fn store(&self) -> &Store {
        &self.store
    }

    pub fn store_mut(&mut self) -> &mut Store {
        &mut self.store
    }

    /// Keeps one image's learned features (a new visit goes after the ones seen before; SIFT
    /// features are not kept). Returns the image's id, `None` for SIFT.
    pub fn add(
        &mut self,
        session: &str,
        file: &str,
        record: &FeaturesRecord,
    ) -> Result<Option<ImageId>, PipelineError> {
        let FeaturesRecord::Learned { method, roll, features } = record else { return Ok(None) };
        let name = ImageName::new(session, file).map_err(|e| PipelineError::Name(e.to_string()))?;
        self.store.ensure_session(session, &self.source)?;
        // The features' size is the rolled image's; the camera's is the image's.
        let (width, height) = roll.rolled_size(features.width, features.height);
        let camera = Camera::default_for_size(0, width, height);
        let camera = self.store.ensure_camera(session, &camera, false)?;
        let ids = self.store.ensure_images(&[name.to_string()], camera.camera_id)?;
        let id = ids[&name.to_string()];
        if !self.store.learned_feature_keys(method)?.contains(&(id, roll.degrees())) {
            self.store.write_learned_features(id, method, roll.degrees(), features)?;
        }
        Ok(Some(id))
    }

    /// One image's learned features at `roll`, if held.
    pub fn learned(&self, image: &str, method: &str, roll: Roll) -> Result<Option<LearnedFeatures>, PipelineError> {
        let Some(&id) = self.store.image_ids()?.get(image) else { return Ok(None) };
        if !self.store.learned_feature_keys(method)?.contains(&(id, roll.degrees())) {
            return Ok(None);
        }
        Ok(Some(self.store.read_learned_features(id, method, roll.degrees())?))
    }

    /// The visits held, in order, each image in name (time) order: what the cross-visit stages
    /// take (no files: images are not kept).
    pub fn sessions(&self) -> Result<Vec<Session>, PipelineError> {
        let ids = self.store.image_ids()?;
        let mut by_session: BTreeMap<String, Vec<SessionImage>> = BTreeMap::new();
        for (name, id) in ids {
            let Some((session, file)) = name.split_once('/') else { continue };
            let Ok(name) = ImageName::new(session, file) else { continue };
            let image = SessionImage { name, id, camera: String::new(), path: PathBuf::new() };
            by_session.entry(session.to_owned()).or_default().push(image);
        }
        let records = self.store.sessions()?;
        Ok(records
            .into_iter()
            .map(|record| Session {
                images: by_session.remove(&record.name).unwrap_or_default(),
                name: record.name,
                visit: record.visit,
                dir: PathBuf::new(),
                cameras: BTreeMap::new(),
                calibrated: Default::default(),
            })
            .collect())
    }
}
