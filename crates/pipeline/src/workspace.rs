//! The reconstruction job: a work folder, its store and its options.

use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};
use std::time::Instant;

use revisit_core::{Camera, CameraId, CameraModel, ImageId, ImageName, NavigationFix};
use revisit_store::{PosePrior, Store};

use revisit_matching::cross::judge;
use revisit_matching::CrossMatch;

use crate::cross::{self, LearnedPair, Places};
use crate::export;
use crate::ingest::SessionImages;
use crate::learned::{self, Learned};
use crate::locate::Tools;
use crate::mapping::{self, io, MappingOutcome};
use crate::memory;
use crate::messages::FeaturesRecord;
use crate::options::{CameraSpec, ReconstructOptions};
use crate::report::{CameraReport, CrossReport, MappingReport, ModelFrame, Report};
use crate::stages::{self, LearnedKeypoints};
use crate::{workers, Cancel, PipelineError, Progress, StageCounts};

/// An image of a session in a workspace.
#[derive(Clone, Debug, PartialEq)]
pub struct SessionImage {
    pub name: ImageName,
    pub id: ImageId,
    /// The camera's name within the session.
    pub camera: String,
    /// The file on disk.
    pub path: PathBuf,
}

/// A session added to a workspace: its images in time order, with their
/// store ids and cameras.
#[derive(Clone, Debug, PartialEq)]
pub struct Session {
    pub name: String,
    /// Place in the order of visits, as stored (0 = the reference).
    pub visit: usize,
    pub dir: PathBuf,
    pub images: Vec<SessionImage>,
    /// Cameras by name, as stored.
    pub cameras: BTreeMap<String, Camera>,
    /// Cameras whose intrinsics were given (held fixed in mapping).
    pub calibrated: BTreeSet<String>,
}

impl Session {
    /// The report's view of the cameras.
    pub fn camera_reports(&self) -> BTreeMap<String, CameraReport> {
        self.cameras
            .iter()
            .map(|(name, camera)| {
                let report = CameraReport {
                    camera_id: camera.camera_id,
                    width: camera.width,
                    height: camera.height,
                    images: self.images.iter().filter(|i| &i.camera == name).count(),
                    calibrated: self.calibrated.contains(name),
                };
                (name.clone(), report)
            })
            .collect()
    }
}

/// A reconstruction job over one work folder: the store (`database.db`),
/// the image links COLMAP reads (`images/`), the models and exports.
///
/// ```no_run
/// # use revisit_pipeline::{Workspace, ReconstructOptions, Cancel, Silent, locate::Tools, ingest};
/// # fn main() -> Result<(), revisit_pipeline::PipelineError> {
/// let mut workspace = Workspace::open("work".as_ref(), ReconstructOptions::default(), Tools::default())?;
/// for spec in ["2019=/data/2019", "2020=/data/2020"] {
///     let spec: ingest::SessionSpec = spec.parse().map_err(revisit_pipeline::PipelineError::Name)?;
///     workspace.add_session(ingest::scan_session(&spec)?)?;
/// }
/// let report = workspace.run(&Silent, &Cancel::new())?;
/// println!("{} models", report.models);
/// # Ok(()) }
/// ```
pub struct Workspace {
    dir: PathBuf,
    store: Store,
    options: ReconstructOptions,
    tools: Tools,
    python: PathBuf,
    /// Sessions added, in visit order.
    sessions: Vec<Session>,
}

/// Seconds and peak resident memory of each stage of a run.
#[derive(Default)]
struct StageFigures {
    seconds: BTreeMap<String, f64>,
    peak_rss_mib: BTreeMap<String, f64>,
}

impl StageFigures {
    /// Runs `f` and records its seconds and this process's peak memory during it under `stage`.
    fn run<T>(&mut self, stage: &str, f: impl FnOnce() -> Result<T, PipelineError>) -> Result<T, PipelineError> {
        memory::reset_peak();
        let start = Instant::now();
        let out = f()?;
        self.seconds.insert(stage.to_owned(), start.elapsed().as_secs_f64());
        if let Some(peak) = memory::peak_rss_mib() {
            self.peak_rss_mib.insert(stage.to_owned(), peak);
        }
        Ok(out)
    }
}

impl Workspace {
    /// Checks `options`, finds Python with pycolmap, and opens (or creates)
    /// the work folder `dir` and its store. Options that shape stored work
    /// (features, shared cameras) are pinned: a store holds one kind only.
    pub fn open(dir: &Path, options: ReconstructOptions, tools: Tools) -> Result<Workspace, PipelineError> {
        options.check()?;
        let python = tools.python()?;
        std::fs::create_dir_all(dir).map_err(|source| PipelineError::Io { path: dir.to_path_buf(), source })?;
        let store = Store::open(&dir.join("database.db"))?;
        let pin = |key: &str, value: Result<String, serde_json::Error>| -> Result<(), PipelineError> {
            let value = value.map_err(|e| PipelineError::Name(e.to_string()))?;
            Ok(store.pin_setting(key, &value)?)
        };
        pin("features", serde_json::to_string(&options.features))?;
        // Whether visits share cameras decides which camera an image joins.
        pin("shared_camera", serde_json::to_string(&options.cameras.shared))?;
        Ok(Workspace { dir: dir.to_path_buf(), store, options, tools, python, sessions: Vec::new() })
    }

    pub fn dir(&self) -> &Path {
        &self.dir
    }

    pub fn options(&self) -> &ReconstructOptions {
        &self.options
    }

    pub fn store(&self) -> &Store {
        &self.store
    }

    /// Sessions added so far, in visit order.
    pub fn sessions(&self) -> &[Session] {
        &self.sessions
    }

    /// Adds a session (a new visit goes after every stored one; a stored
    /// one keeps its place), its cameras and its images to the store.
    /// Adding a session again with more images (a visit still coming in, as
    /// the mapper node sees it) adds those; it must come from the same folder.
    pub fn add_session(&mut self, images: SessionImages) -> Result<&Session, PipelineError> {
        if let Some(at) = self.sessions.iter().position(|s| s.name == images.name) {
            if self.sessions[at].dir != images.dir {
                return Err(PipelineError::DuplicateSession(images.name));
            }
            self.sessions.remove(at);
        }
        let record = self.store.ensure_session(&images.name, &images.dir.display().to_string())?;
        let mut cameras = BTreeMap::new();
        let mut calibrated = BTreeSet::new();
        let mut camera_ids = BTreeMap::new();
        for group in &images.cameras {
            let spec = self.options.cameras.calibration(&images.name, &group.name);
            let camera_error = |reason: String| PipelineError::Camera {
                session: images.name.clone(),
                camera: group.name.clone(),
                reason,
            };
            let (camera, prior_focal_length) = initial_camera(spec, group.width, group.height, group.exif_focal_px)
                .map_err(|e| camera_error(e.to_string()))?;
            let key = if self.options.cameras.shared {
                group.name.clone()
            } else {
                format!("{}/{}", images.name, group.name)
            };
            let stored =
                self.store.ensure_camera(&key, &camera, prior_focal_length).map_err(|e| camera_error(e.to_string()))?;
            camera_ids.insert(group.name.clone(), stored.camera_id);
            if spec.is_some() {
                calibrated.insert(group.name.clone());
            }
            cameras.insert(group.name.clone(), stored);
        }
        let mut ids = BTreeMap::new();
        for group in &images.cameras {
            let Some(&camera_id) = camera_ids.get(&group.name) else { continue };
            let names: Vec<String> = group.files.iter().map(|f| revisit_core::image_name(&images.name, f)).collect();
            ids.extend(self.store.ensure_images(&names, camera_id)?);
        }
        let session_images = images
            .images()
            .into_iter()
            .filter_map(|(group, name)| {
                let id = *ids.get(&name.to_string())?;
                let path = images.dir.join(name.file());
                Some(SessionImage { name, id, camera: group.name.clone(), path })
            })
            .collect();
        link_images(&self.dir, &images.name, &images.dir)?;
        let session = Session {
            name: images.name,
            visit: record.visit,
            dir: images.dir,
            images: session_images,
            cameras,
            calibrated,
        };
        let at = self.sessions.partition_point(|s| s.visit < session.visit);
        self.sessions.insert(at, session);
        Ok(&self.sessions[at])
    }

    /// Stores the navigation of an added session as COLMAP pose priors (replacing any stored
    /// for the same images), so that mapping places the visit on it: metric scale, in the
    /// navigation frame. Fixes for images the session does not hold are skipped (a navigation
    /// log may cover more than the keyframes); none matching is an error. Returns how many of
    /// the session's images have a prior now.
    pub fn add_navigation(&mut self, session: &str, fixes: &[NavigationFix]) -> Result<usize, PipelineError> {
        let Some(stored) = self.sessions.iter().find(|s| s.name == session) else {
            return Err(PipelineError::Name(format!("navigation for session {session}, which was not added")));
        };
        let images: BTreeMap<String, &SessionImage> = stored.images.iter().map(|i| (i.name.to_string(), i)).collect();
        let priors: Vec<PosePrior> = fixes
            .iter()
            .filter_map(|fix| {
                let image = images.get(&fix.image)?;
                Some(PosePrior {
                    image_id: image.id,
                    camera_id: stored.cameras.get(&image.camera)?.camera_id,
                    position_m: fix.position_m,
                    covariance_m2: fix.covariance_m2(),
                })
            })
            .collect();
        if priors.is_empty() {
            return Err(PipelineError::NavigationUnmatched {
                session: session.to_owned(),
                rows: fixes.len(),
                first: fixes.first().map(|f| f.image.clone()).unwrap_or_default(),
            });
        }
        self.store.write_pose_priors(&priors)?;
        let ids: BTreeSet<ImageId> = stored.images.iter().map(|i| i.id).collect();
        Ok(self.store.pose_priors()?.iter().filter(|p| ids.contains(&p.image_id)).count())
    }

    /// Holds the cameras under `key` (`SESSION/CAMERA`, `SESSION` or `""`, as
    /// [`crate::options::CameraOptions::calibrated`]) at `spec`'s intrinsics:
    /// for cameras that say their calibration as their images arrive (a
    /// `CameraInfo`). Applies to cameras stored from now on.
    pub fn calibrate(&mut self, key: &str, spec: CameraSpec) {
        self.options.cameras.calibrated.insert(key.to_owned(), spec);
    }

    /// Stores one image's features (SIFT, or learned at one roll) computed
    /// elsewhere (the features node), unless the store has them. `Ok(false)`:
    /// no image `session/file` is stored yet.
    pub fn add_features(&mut self, image: &str, record: &FeaturesRecord) -> Result<bool, PipelineError> {
        let Some(&id) = self.store.image_ids()?.get(image) else { return Ok(false) };
        match record {
            FeaturesRecord::Sift(features) => {
                if !self.store.images_with_features()?.contains(&id) {
                    self.store.write_features(id, features)?;
                }
            }
            FeaturesRecord::Learned { method, roll, features } => {
                if !self.store.learned_feature_keys(method)?.contains(&(id, roll.degrees())) {
                    self.store.write_learned_features(id, method, roll.degrees(), features)?;
                }
            }
        }
        Ok(true)
    }

    /// Judges and stores what the learned matcher found for cross-visit pairs
    /// elsewhere (a matcher node), in pair order, skipping stored pairs: the
    /// same acceptance, anchoring and writes as [`Workspace::match_learned`],
    /// so the store ends as if matched here. Every image's learned keypoints
    /// at roll 0 must be stored. Returns how many pairs were stored.
    pub fn add_cross_matches(&mut self, mut found: Vec<(LearnedPair, CrossMatch)>) -> Result<usize, PipelineError> {
        let method = self.options.learned.name();
        cross::register_learned_keypoints(&mut self.store, method, &self.sessions)?;
        found.sort_by_key(|(pair, _)| *pair);
        let finished = self.store.matched_pairs()?;
        let mut stored = 0;
        for (pair, found) in found {
            if finished.contains(&revisit_core::pair_id(pair.image_id1, pair.image_id2)) {
                continue;
            }
            let a = self.store.read_learned_features(pair.image_id1, method, 0)?;
            let b = [(found.roll, self.store.read_learned_features(pair.image_id2, method, found.roll.degrees())?)];
            let own_a = self.store.read_keypoints(pair.image_id1)?;
            let own_b = self.store.read_keypoints(pair.image_id2)?;
            let judged = judge(&found, (&a, &own_a), (&b, &own_b), &self.options.learned_matching);
            cross::write_learned_pair(&mut self.store, &pair, method, &judged)?;
            stored += 1;
        }
        Ok(stored)
    }

    /// Runs every stage the options ask for, then maps, exports and writes
    /// `report.json`. Each stage resumes from what the store holds.
    pub fn run(&mut self, progress: &dyn Progress, cancel: &Cancel) -> Result<Report, PipelineError> {
        let mut figures = StageFigures::default();
        let strategy = self.options.cross;
        // Visits are linked only when there are several.
        let learned_strategy = strategy.learned() && self.sessions.len() >= 2;
        // Open the learned models before any work, so a missing model fails fast.
        let mut learned = match learned_strategy {
            true => Some(self.open_learned()?),
            false => None,
        };
        let features = figures.run("features", || {
            stages::extract_features(&mut self.store, &self.sessions, &self.options.features, progress, cancel)
        })?;
        let mut cross_report = CrossReport::default();
        // Learned features come before matching within visits: their keypoints
        // join the SIFT ones there, so cross-visit tracks continue inside visits.
        let learned_keypoints = match learned.as_mut() {
            Some((_, learned)) => Some(figures.run("learned_features", || {
                cross_report.learned_features = Some(self.extract_learned(learned, progress, cancel)?);
                cross::register_learned_keypoints(&mut self.store, learned.method.name(), &self.sessions)
            })?),
            None => None,
        };
        let matching = figures.run("matching", || self.match_sift(learned_keypoints.as_ref(), progress, cancel))?;
        drop(learned_keypoints);
        if let Some((runtime, learned)) = learned.as_mut() {
            let places = match strategy.places() {
                true => Some(figures.run("places", || self.describe_places(runtime, learned, progress, cancel))?),
                false => None,
            };
            cross_report.places = places.as_ref().map(|p| p.counts);
            cross_report.learned_matching = Some(
                figures.run("learned_matching", || self.match_learned(learned, places.as_ref(), progress, cancel))?,
            );
        }
        let mut confirmed = Vec::new();
        if self.sessions.len() >= 2 {
            let options = &self.options.learned_matching;
            let consistency =
                figures.run("consistency", || cross::check_consistency(&mut self.store, &self.sessions, options))?;
            cross_report.consistency = Some(consistency.counts);
            confirmed = consistency.confirmed;
        }
        let outcome = figures.run("mapping", || self.map(cancel))?;
        // COLMAP maps in its own process.
        if let (Some(colmap), Some(peak)) = (outcome.peak_rss_mib, figures.peak_rss_mib.get_mut("mapping")) {
            *peak = peak.max(colmap);
        }
        let chosen = export::chosen_model(&outcome.models, &self.sessions);
        figures.run("export", || self.export(&outcome, chosen))?;

        let records = self.store.pair_records()?;
        let mut sessions = export::session_reports(&self.sessions, &outcome.models, chosen);
        let priors: BTreeSet<ImageId> = self.store.pose_priors()?.iter().map(|p| p.image_id).collect();
        for session in &self.sessions {
            if let Some(report) = sessions.get_mut(&session.name) {
                report.navigation = session.images.iter().filter(|i| priors.contains(&i.id)).count();
            }
        }
        let chosen_model = chosen.and_then(|k| outcome.models.get(k));
        let placement = match chosen_model.filter(|_| self.sessions.len() >= 2) {
            Some(model) => {
                let model = revisit_colmap::read_model(&model.path)?;
                cross::check_placement(&self.store, &self.sessions, &model, &records, &confirmed)?
            }
            None => BTreeMap::new(),
        };
        let report = Report {
            unlinked_sessions: export::unlinked_sessions(&sessions),
            sessions,
            models: outcome.models.len(),
            model_sizes: outcome.models.iter().map(|m| m.registered_images.len()).collect(),
            chosen_model: chosen_model.map(|m| m.path.clone()),
            registered_rule: export::REGISTERED_RULE.to_owned(),
            pairs: export::pair_reports(&records),
            rolls: export::roll_histogram(&records),
            features,
            matching,
            cross: cross_report,
            mapping: MappingReport {
                reused: outcome.reused,
                extended: outcome.extended,
                mean_reprojection_error_px: chosen_model.map(|m| m.mean_reprojection_error_px),
                frame: match outcome.on_navigation {
                    true => ModelFrame::Navigation,
                    false => ModelFrame::Arbitrary,
                },
                navigation_rms_m: chosen_model.and_then(|m| m.navigation_rms_m),
                navigation_offsets: chosen_model.map(|m| m.navigation_offsets.clone()).unwrap_or_default(),
                change_aware: outcome.change_aware.clone(),
                placement,
            },
            seconds: figures.seconds,
            peak_rss_mib: figures.peak_rss_mib,
            options: self.options.clone(),
        };
        report.write(&self.dir.join("report.json"))?;
        Ok(report)
    }

    /// ONNX Runtime and the learned method's models.
    fn open_learned(&self) -> Result<(revisit_onnx::Runtime, Learned), PipelineError> {
        let runtime = self.tools.onnxruntime(0)?;
        let learned =
            Learned::open(&runtime, &self.tools.models(), self.options.learned, self.options.features.learned_input)?;
        Ok((runtime, learned))
    }

    /// The learned models the `learned_workers` work with: `own` (on every core) for one worker,
    /// else one each, opened by `open` into `pool` on a one-thread runtime. A model takes about
    /// `mib_each` of memory as it runs.
    fn workers<'a, T>(
        &self,
        own: &'a mut T,
        pool: &'a mut Vec<T>,
        mib_each: f64,
        open: impl Fn(&revisit_onnx::Runtime, &Path) -> Result<T, revisit_onnx::OnnxError>,
    ) -> Result<&'a mut [T], PipelineError> {
        let workers = workers::count(self.options.learned_workers, mib_each);
        if workers == 1 {
            return Ok(std::slice::from_mut(own));
        }
        let runtime = self.tools.onnxruntime(1)?;
        for _ in 0..workers {
            pool.push(open(&runtime, &self.tools.models())?);
        }
        Ok(pool)
    }

    /// Stage: learned features at the rolls each image needs.
    pub fn extract_learned(
        &mut self,
        learned: &mut Learned,
        progress: &dyn Progress,
        cancel: &Cancel,
    ) -> Result<StageCounts, PipelineError> {
        let search = self.options.learned_matching.roll_search;
        let (Learned { method, extractor, .. }, mut pool) = (learned, Vec::new());
        let input = self.options.features.learned_input;
        let open = |runtime: &_, models: &_| learned::open_extractor(runtime, models, *method, input);
        // ALIKED at 640x480: 1.3 GiB a run, measured.
        let extractors = self.workers(extractor, &mut pool, 1400.0, open)?;
        let method = *method;
        cross::extract_learned(&mut self.store, method, extractors, &self.sessions, search, progress, cancel)
    }

    /// Stage: SIFT matching and verification of the pairs within visits (and
    /// across, for `--cross sift`), with the learned keypoints alongside.
    pub fn match_sift(
        &mut self,
        learned: Option<&LearnedKeypoints>,
        progress: &dyn Progress,
        cancel: &Cancel,
    ) -> Result<StageCounts, PipelineError> {
        let options = &self.options;
        let pairs = match options.cross.sift_within() || self.sessions.len() < 2 {
            true => stages::plan_pairs(&self.sessions, options.cross.sift_across(), &options.pairs),
            false => Vec::new(),
        };
        let ids = self.sessions.iter().flat_map(|s| &s.images).map(|i| i.id);
        let features = stages::load_features(&self.store, ids)?;
        stages::match_pairs(
            &mut self.store,
            &pairs,
            &features,
            learned,
            &options.matching,
            &options.verify,
            progress,
            cancel,
        )
    }

    /// Stage: global descriptors for place recognition.
    pub fn describe_places(
        &mut self,
        runtime: &revisit_onnx::Runtime,
        learned: &Learned,
        progress: &dyn Progress,
        cancel: &Cancel,
    ) -> Result<Places, PipelineError> {
        let search = self.options.learned_matching.roll_search;
        let method = learned.method.name();
        let source = &self.options.places.source;
        cross::describe_places(&mut self.store, method, source, runtime, &self.sessions, search, progress, cancel)
    }

    /// Stage: the learned matcher on the pairs the strategy picks.
    pub fn match_learned(
        &mut self,
        learned: &mut Learned,
        places: Option<&Places>,
        progress: &dyn Progress,
        cancel: &Cancel,
    ) -> Result<cross::LearnedMatchingCounts, PipelineError> {
        let options = &self.options;
        let nearby = match options.places.navigation_radius_m {
            Some(radius_m) => {
                let positions_m = self.store.pose_priors()?.into_iter().map(|p| (p.image_id, p.position_m)).collect();
                Some(cross::Nearby { positions_m, radius_m })
            }
            None => None,
        };
        let candidates = &options.places.candidates;
        let pairs = cross::plan_learned_pairs(options.cross, &self.sessions, places, candidates, nearby.as_ref());
        let (Learned { method, extractor, matcher }, mut pool) = (learned, Vec::new());
        let dim = extractor.descriptor_dim();
        let open = |runtime: &_, models: &_| learned::open_matcher(runtime, models, *method, dim);
        // LightGlue on 1024 keypoints a side: under 0.2 GiB a run, measured.
        let matchers = self.workers(matcher, &mut pool, 400.0, open)?;
        let method = *method;
        cross::match_learned_pairs(
            &mut self.store,
            method,
            matchers,
            &pairs,
            &self.sessions,
            &options.learned_matching,
            progress,
            cancel,
        )
    }

    /// Stage: one COLMAP run over the store (kept if the store did not
    /// change, extended if images were added).
    pub fn map(&mut self, cancel: &Cancel) -> Result<MappingOutcome, PipelineError> {
        let records = self.store.pair_records()?;
        let constant: Vec<CameraId> = self
            .sessions
            .iter()
            .flat_map(|s| s.calibrated.iter().filter_map(|name| s.cameras.get(name)).map(|c| c.camera_id))
            .collect::<BTreeSet<_>>()
            .into_iter()
            .collect();
        let aside: Vec<u64> = self.store.set_aside_pairs()?.into_keys().collect();
        let confident: Vec<u64> = self.store.confident_in_use()?.into_iter().collect();
        let priors = self.store.pose_priors()?;
        let priors_fingerprint = mapping::priors_fingerprint(&priors);
        let fingerprint = {
            let inliers: usize = records.iter().map(|r| r.num_inliers).sum();
            let names: Vec<String> = self.sessions.iter().flat_map(|s| &s.images).map(|i| i.name.to_string()).collect();
            let cameras: Vec<&Camera> = self.sessions.iter().flat_map(|s| s.cameras.values()).collect();
            format!(
                "{} images {names:?}; cameras {cameras:?}, constant {constant:?}; {} pairs, {inliers} inliers, \
                 set aside {aside:?}, confident {confident:?}; priors {priors_fingerprint}; {:?}",
                names.len(),
                records.len(),
                self.options.mapper
            )
        };
        let inputs = mapping::MappingInputs {
            fingerprint: &fingerprint,
            set_aside: &aside,
            priors: &priors_fingerprint,
            pose_priors: priors.len(),
            constant_cameras: &constant,
        };
        let database = self.dir.join("database.db");
        let image_root = self.dir.join("images");
        mapping::map(&self.python, &database, &image_root, &self.dir, &inputs, &self.options.mapper, cancel)
    }

    /// Writes what this folder hands to users (the COLMAP model(s) `model/`, `points.ply`,
    /// `poses.csv`, `report.json`, as `revisit reconstruct` leaves them) to the folder `to`, the
    /// report's model path pointing at the copy. Everything is written beside, in `to/.saving`,
    /// then moved into place: a failed save leaves what `to` held. Returns the names written.
    pub fn save_outputs(&self, to: &Path) -> Result<Vec<String>, PipelineError> {
        let mut report = Report::read(&self.dir.join("report.json"))?;
        std::fs::create_dir_all(to).map_err(io(to))?;
        let to = std::fs::canonicalize(to).map_err(io(to))?;
        let work = std::fs::canonicalize(&self.dir).map_err(io(&self.dir))?;
        if to == work {
            return Err(PipelineError::Io {
                path: to,
                source: std::io::Error::other("is the work folder itself, which holds the map already"),
            });
        }
        let staging = to.join(".saving");
        if staging.exists() {
            std::fs::remove_dir_all(&staging).map_err(io(&staging))?;
        }
        std::fs::create_dir_all(&staging).map_err(io(&staging))?;
        let model = mapping::model_root(&self.dir);
        let mut written = Vec::new();
        if model.is_dir() {
            copy_dir(&model, &staging.join("model"))?;
            written.push("model".to_owned());
        }
        for name in ["points.ply", "poses.csv"] {
            let from = self.dir.join(name);
            if from.exists() {
                std::fs::copy(&from, staging.join(name)).map_err(io(&from))?;
                written.push(name.to_owned());
            }
        }
        report.chosen_model = report.chosen_model.map(|m| match m.strip_prefix(&work).or(m.strip_prefix(&self.dir)) {
            Ok(inside) => to.join(inside),
            Err(_) => m,
        });
        report.write(&staging.join("report.json"))?;
        written.push("report.json".to_owned());
        for name in &written {
            let target = to.join(name);
            if target.is_dir() {
                std::fs::remove_dir_all(&target).map_err(io(&target))?;
            }
            std::fs::rename(staging.join(name), &target).map_err(io(&target))?;
        }
        std::fs::remove_dir(&staging).map_err(io(&staging))?;
        Ok(written)
    }

    /// Stage: `poses.csv` and `points.ply` of the chosen model.
    pub fn export(&self, outcome: &MappingOutcome, chosen: Option<usize>) -> Result<(), PipelineError> {
        let Some(model) = chosen.and_then(|k| outcome.models.get(k)) else {
            tracing::warn!("COLMAP registered no model: no poses.csv or points.ply");
            return Ok(());
        };
        let reconstruction = revisit_colmap::read_model(&model.path)?;
        let poses = self.dir.join("poses.csv");
        let csv = export::poses_csv(&reconstruction)
            .map_err(|e| PipelineError::Io { path: poses.clone(), source: std::io::Error::other(e) })?;
        std::fs::write(&poses, csv).map_err(|source| PipelineError::Io { path: poses.clone(), source })?;
        revisit_colmap::write_ply(&reconstruction, &self.dir.join("points.ply"), self.options.ply_colors)?;
        Ok(())
    }
}

/// The camera a group of images starts from: the given calibration, else
/// COLMAP's default model with the EXIF focal length, else COLMAP's default
/// guess. The flag says whether the focal length is known (COLMAP's
/// `prior_focal_length`).
fn initial_camera(
    spec: Option<&CameraSpec>,
    width: u32,
    height: u32,
    exif_focal_px: Option<f64>,
) -> Result<(Camera, bool), revisit_core::CameraModelError> {
    match (spec, exif_focal_px) {
        (Some(spec), _) => Ok((Camera::new(0, spec.model, width, height, spec.params.clone())?, true)),
        (None, Some(focal_px)) => {
            let params = vec![focal_px, f64::from(width) / 2.0, f64::from(height) / 2.0, 0.0];
            Ok((Camera::new(0, CameraModel::SimpleRadial, width, height, params)?, true))
        }
        (None, None) => Ok((Camera::default_for_size(0, width, height), false)),
    }
}

/// `WORK/images/<session>` links to the session's folder, so that COLMAP
/// finds `session/file` under one root.
fn link_images(work: &Path, session: &str, dir: &Path) -> Result<(), PipelineError> {
    let root = work.join("images");
    std::fs::create_dir_all(&root).map_err(io(&root))?;
    let link = root.join(session);
    if std::fs::read_link(&link).is_ok_and(|target| target == dir) {
        return Ok(());
    }
    if link.symlink_metadata().is_ok() {
        std::fs::remove_file(&link).map_err(io(&link))?;
    }
    std::os::unix::fs::symlink(dir, &link).map_err(io(&link))
}

/// Copies a folder tree (files and folders; a COLMAP model is no deeper than that).
fn copy_dir(from: &Path, to: &Path) -> Result<(), PipelineError> {
    std::fs::create_dir_all(to).map_err(io(to))?;
    for entry in std::fs::read_dir(from).map_err(io(from))? {
        let path = entry.map_err(io(from))?.path();
        let Some(name) = path.file_name() else { continue };
        if path.is_dir() {
            copy_dir(&path, &to.join(name))?;
        } else {
            std::fs::copy(&path, to.join(name)).map_err(io(&path))?;
        }
    }
    Ok(())
}
