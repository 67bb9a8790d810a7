//! The mapper node: owns the store (a `revisit reconstruct` work folder) and runs the joint
//! reconstruction when a visit ends. Keyframes (`keyframes`), their features (`features`), the visits'
//! START/END (`visits`), place candidates (`places/candidates`) and what the matchers found
//! (`matches`) come in; the map goes out, latched for late subscribers such as Foxglove:
//! `map/cloud` (PointCloud2 with x, y, z, rgb and session), `map/cameras` (PoseArray),
//! `map/path/<visit>` (one nav_msgs/Path per visit) and `map/status` (MapStatus: what `report.json`
//! holds), each stamped with the newest keyframe in the map (the data's time: the bag's on a
//! replay, and the same after a restart). The work folder holds what `revisit reconstruct` writes
//! (model/, points.ply, poses.csv, report.json), so the map opens in COLMAP too.
//!
//! When keyframes came with odometry (the ingest node's `odom`), the published map is placed on
//! the newest such visit's odometry: scaled to metres by the similarity that best fits its
//! registered cameras to their odometry positions, and `map -> odom` (REP 105: the odometry
//! frame in the map frame) goes out on `/tf` once a second. The files keep COLMAP's own frame.
//!
//! A visit is mapped once its END has come (with its keyframe count) and everything it needs has:
//! every keyframe and its features and, with `places:=true` (the default when visits are linked by
//! place recognition), each keyframe's candidates and a matcher's answer for every candidate pair.
//! Then [`Workspace::add_cross_matches`] stores the answers as `reconstruct` would have, and
//! [`Workspace::run`] does the rest (matching within the visit, mapping, export), computing
//! nothing the graph already delivered. With `places:=false` the mapper finds and matches the
//! cross-visit pairs itself.
//!
//! Services: `~/save` (`revisit_msgs/srv/Save`) writes the map as `revisit reconstruct` does
//! (model/, points.ply, poses.csv, report.json) to the folder asked for (`save_dir` when the
//! request names none); `~/map` (`std_srvs/srv/Trigger`) maps now, without waiting for the visit
//! in progress to end: what has not arrived yet for its keyframes (features, place candidates,
//! matchers' answers) the mapper computes itself, and the visit is mapped again, extending the
//! model, when it ends. `revisit service save|map` calls them.
//!
//! Parameters: `work_dir` (default `revisit-state/mapper`), `options_file` (a JSON file of the
//! reconstruction's options, as `report.json` shows them; default the defaults), `cross` (the
//! strategy, overriding the file's), `places`, `frame_id` (the map's frame, default `map`),
//! `odom_frame_id` (default `odom`), `save_dir` (default `WORK_DIR/saved`), `python`, `models`.
//!
//! Restartable: keyframes are files in the work folder, features are in the store, and every
//! other input is journalled (`mapper.journal`) before it is acted on; a restarted mapper maps
//! what it would have mapped.

use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};

use futures::StreamExt;
use revisit_core::PairKind;
use revisit_msgs::geometry_msgs::{PoseArray, TransformStamped};
use revisit_msgs::nav_msgs::Path as PathMessage;
use revisit_msgs::revisit_msgs::{CrossVisitMatches, Features, Keyframe, MapStatus, PlaceCandidates, SessionControl};
use revisit_msgs::sensor_msgs::PointCloud2;
use revisit_msgs::services::{Save, SaveResponse, Trigger, TriggerResponse};
use revisit_msgs::std_msgs::Header;
use revisit_msgs::tf2_msgs::TFMessage;
use revisit_node::{History, Journal, LogLevel, Node, NodeError, Publisher, LATCHED, RELIABLE, WORK_QUEUE};
use revisit_pipeline::cross::LearnedPair;
use revisit_pipeline::ingest::{list_session, SessionSpec};
use revisit_pipeline::locate::Tools;
use revisit_pipeline::messages::{self, MapMessages};
use revisit_pipeline::{Cancel, ReconstructOptions, Report, Silent, Workspace};
use serde::{Deserialize, Serialize};

/// The node's name unless remapped.
pub const NAME: &str = "mapper";

/// What a run did.
#[derive(Debug, Default, Clone, PartialEq, Eq)]
pub struct Summary {
    pub keyframes: u64,
    /// Visits mapped, in order.
    pub mapped: Vec<String>,
}

impl std::fmt::Display for Summary {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "{} keyframes kept, visits mapped {:?}", self.keyframes, self.mapped)
    }
}

/// A journal line: an input the mapper acted on, or a visit it mapped.
#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "snake_case")]
enum Entry {
    /// A visit's first keyframe came.
    Visit {
        session: String,
    },
    End {
        session: String,
        keyframes: u32,
    },
    Candidates {
        image: String,
        candidates: Vec<String>,
    },
    Found(Box<CrossVisitMatches>),
    Mapped {
        session: String,
    },
    /// A visit's newest keyframe so far (its header stamp, ns): the map is stamped with the
    /// newest keyframe it holds.
    Newest {
        session: String,
        stamp_ns: i64,
    },
    /// A keyframe's camera position by the vehicle's odometry (in the odometry frame, metres).
    Prior {
        image: String,
        position_m: [f64; 3],
    },
}

/// What the journal says.
#[derive(Default)]
struct Inputs {
    /// Visits in the order their first keyframes came.
    visits: Vec<String>,
    /// Visits ended, with their keyframe counts.
    ended: BTreeMap<String, u32>,
    /// Each query image's candidates (`session/file` names).
    candidates: BTreeMap<String, Vec<String>>,
    /// Matchers' answers by (earlier image, later image).
    found: BTreeMap<(String, String), CrossVisitMatches>,
    mapped: BTreeSet<String>,
    /// Each visit's newest keyframe stamp, ns.
    newest_ns: BTreeMap<String, i64>,
    /// Keyframes' camera positions by odometry, metres.
    priors: BTreeMap<String, [f64; 3]>,
}

impl Inputs {
    fn apply(&mut self, entry: Entry) {
        match entry {
            Entry::Visit { session } => self.visits.push(session),
            Entry::End { session, keyframes } => {
                self.ended.insert(session, keyframes);
            }
            Entry::Candidates { image, candidates } => {
                self.candidates.insert(image, candidates);
            }
            Entry::Found(found) => {
                let key = (full(&found.session1, &found.image_name1), full(&found.session2, &found.image_name2));
                self.found.insert(key, *found);
            }
            Entry::Mapped { session } => {
                self.mapped.insert(session);
            }
            Entry::Newest { session, stamp_ns } => {
                self.newest_ns.insert(session, stamp_ns);
            }
            Entry::Prior { image, position_m } => {
                self.priors.insert(image, position_m);
            }
        }
    }

    /// The map's stamp: the newest keyframe of the visits in it (the data's time, the bag's on a
    /// replay, whatever the node's clock says; the same map gets the same stamp after a restart).
    fn map_stamp(&self, visits: &[String]) -> revisit_msgs::builtin_interfaces::Time {
        let newest = visits.iter().filter_map(|v| self.newest_ns.get(v)).max().copied().unwrap_or(0);
        revisit_msgs::builtin_interfaces::Time::from_nanos(newest)
    }
}

fn full(session: &str, file: &str) -> String {
    format!("{session}/{file}")
}

struct Outputs {
    /// The map's frame.
    frame_id: String,
    /// The odometry's frame.
    odom_frame_id: String,
    tf: Publisher<TFMessage>,
    /// `map -> odom`, when the map could be placed on the odometry: sent on `/tf` every second.
    map_to_odom: Option<TransformStamped>,
    cloud: Publisher<PointCloud2>,
    cameras: Publisher<PoseArray>,
    status: Publisher<MapStatus>,
    paths: BTreeMap<String, Publisher<PathMessage>>,
}

struct Mapper {
    workspace: Workspace,
    journal: Journal,
    inputs: Inputs,
    /// Features whose keyframe has not arrived or whose visit waits for the one before to be
    /// mapped (topics are not ordered with each other).
    waiting: BTreeMap<String, Vec<Features>>,
    /// Visits whose keyframes came while an earlier one was not mapped yet, in arrival order:
    /// their keyframes wait on disk, out of the store, so that each visit is mapped with the
    /// visits before it only (as `reconstruct` adding one visit at a time would).
    queued: Vec<String>,
    /// Whether cross-visit pairs come from the places and matcher nodes.
    places: bool,
    summary: Summary,
}

/// Runs the mapper node until SIGINT or SIGTERM (a mapping in progress is stopped; the next start
/// maps again).
pub async fn run(node: &mut Node) -> Result<Summary, NodeError> {
    let work_dir: PathBuf = node.param("work_dir", PathBuf::from("revisit-state/mapper"))?;
    let options = node_options(node)?;
    let places = node.param("places", options.cross.places())?;
    let tools = Tools { python: node.param("python", None)?, models: node.param("models", None)?, ..Tools::default() };
    let frame_id: String = node.param("frame_id", "map".to_owned())?;
    let save_dir: PathBuf = node.param("save_dir", work_dir.join("saved"))?;
    let work = |e: revisit_pipeline::PipelineError| NodeError::Work(e.to_string());

    let mut mapper = tokio::task::block_in_place(|| Mapper::open(&work_dir, options, tools, places))?;
    let keyframes = node.subscription::<Keyframe>("keyframes", WORK_QUEUE)?;
    let features = node.subscription::<Features>("features", WORK_QUEUE)?;
    let visits = node.subscription::<SessionControl>("visits", WORK_QUEUE)?;
    let candidates = node.subscription::<PlaceCandidates>("places/candidates", WORK_QUEUE)?;
    let found = node.subscription::<CrossVisitMatches>("matches", WORK_QUEUE)?;
    let (save, map_now) = (node.server::<Save>("~/save")?, node.server::<Trigger>("~/map")?);
    let mut out = Outputs {
        frame_id,
        odom_frame_id: node.param("odom_frame_id", "odom".to_owned())?,
        tf: node.publisher("/tf", RELIABLE.history(History::KeepLast { depth: 100 }))?,
        map_to_odom: None,
        cloud: node.publisher("map/cloud", LATCHED)?,
        cameras: node.publisher("map/cameras", LATCHED)?,
        status: node.publisher("map/status", LATCHED)?,
        paths: BTreeMap::new(),
    };
    let stage = node.stage("inputs");
    let cancel = Cancel::new();
    {
        let (cancel, stopped) = (cancel.clone(), node.stopped());
        tokio::spawn(async move {
            stopped.await;
            cancel.cancel();
        });
    }
    // A restarted mapper shows the map it has.
    if mapper.workspace.dir().join("report.json").exists() {
        let outputs = tokio::task::block_in_place(|| mapper.map_outputs(&out))?;
        publish_map(node, &mut out, outputs).await?;
    }
    let stopped = node.stopped();
    let mut stopped = std::pin::pin!(stopped);
    let (mut keyframes, mut features) =
        (std::pin::pin!(keyframes.async_stream()), std::pin::pin!(features.async_stream()));
    let (mut visits, mut candidates) =
        (std::pin::pin!(visits.async_stream()), std::pin::pin!(candidates.async_stream()));
    let mut found = std::pin::pin!(found.async_stream());
    let (mut saves, mut map_requests) = (std::pin::pin!(save.requests()), std::pin::pin!(map_now.requests()));
    let mut tf_tick = tokio::time::interval(std::time::Duration::from_secs(1));
    node.log(LogLevel::Info, &format!("mapping into {}", work_dir.display()));
    loop {
        let result = tokio::select! {
            () = &mut stopped => break,
            Some(Ok((keyframe, _))) = keyframes.next() => tokio::task::block_in_place(|| mapper.keyframe(&keyframe)),
            Some(Ok((message, _))) = features.next() => tokio::task::block_in_place(|| mapper.features(message)),
            Some(Ok((message, _))) = visits.next() => match message.command {
                SessionControl::END => mapper.record(Entry::End { session: message.session, keyframes: message.keyframes }),
                _ => Ok(()),
            },
            Some(Ok((message, _))) = candidates.next() => {
                let image = full(&message.session, &message.image_name);
                let candidates = message.candidates.iter().map(|c| full(&c.session, &c.image_name)).collect();
                mapper.record(Entry::Candidates { image, candidates })
            }
            Some(Ok((message, _))) = found.next() => mapper.record(Entry::Found(Box::new(message))),
            _ = tf_tick.tick() => {
                if let Some(transform) = &out.map_to_odom {
                    let mut transform = transform.clone();
                    transform.header.stamp = node.now();
                    out.tf.async_publish(TFMessage { transforms: vec![transform] }).await.map_err(dds)?;
                }
                continue;
            }
            Some(Ok((id, request))) = saves.next() => {
                let dir = match request.directory.as_str() {
                    "" => save_dir.clone(),
                    dir => PathBuf::from(dir),
                };
                let response = match tokio::task::block_in_place(|| mapper.workspace.save_outputs(&dir)) {
                    Ok(written) => SaveResponse { success: true, message: format!("wrote {} to {}", written.join(", "), dir.display()) },
                    Err(error) => SaveResponse { success: false, message: format!("nothing saved: {error}") },
                };
                node.log(if response.success { LogLevel::Info } else { LogLevel::Warn }, &response.message);
                save.respond(id, response).await?;
                continue;
            }
            Some(Ok((id, _))) = map_requests.next() => {
                let response = match mapper.unmapped() {
                    None => TriggerResponse { success: true, message: "the map holds every keyframe already".into() },
                    Some(session) => match map_and_publish(node, &mut out, &mut mapper, &session, &cancel, false).await? {
                        Ok(said) => TriggerResponse { success: true, message: said },
                        Err(error) => TriggerResponse { success: false, message: format!("mapping {session} failed: {error}") },
                    },
                };
                map_now.respond(id, response).await?;
                continue;
            }
        };
        stage.received();
        if let Err(error) = result {
            // A bad message is said and dropped; the store is untouched by it.
            node.log(LogLevel::Warn, &error.to_string());
            stage.dropped(1);
            continue;
        }
        while let Some(session) = tokio::task::block_in_place(|| mapper.ready()).map_err(work)? {
            node.log(LogLevel::Info, &format!("visit {session} is complete: mapping"));
            match map_and_publish(node, &mut out, &mut mapper, &session, &cancel, true).await? {
                Ok(_) => {}
                Err(revisit_pipeline::PipelineError::Cancelled) => break,
                Err(error) => return Err(work(error)),
            }
        }
    }
    Ok(mapper.summary)
}

/// Maps (the visit `session` complete when `complete`, else as far as it has come) and publishes
/// the map: what was said, or the mapping's error (said on `map/status` as FAILED).
async fn map_and_publish(
    node: &mut Node,
    out: &mut Outputs,
    mapper: &mut Mapper,
    session: &str,
    cancel: &Cancel,
    complete: bool,
) -> Result<Result<String, revisit_pipeline::PipelineError>, NodeError> {
    let header = mapper.header(&out.frame_id);
    let _ = out.status.async_publish(status(&header, MapStatus::MAPPING, &format!("mapping {session}"))).await;
    let mapped = tokio::task::block_in_place(|| match complete {
        true => mapper.map(session, cancel),
        false => mapper.reconstruct(cancel),
    });
    match mapped {
        Ok(report) => {
            let outputs = tokio::task::block_in_place(|| mapper.map_outputs(out))?;
            publish_map(node, out, outputs).await?;
            let (models, unlinked) = (report.models, report.unlinked_sessions);
            let registered = report.sessions.get(session).map_or(0, |s| s.registered);
            let so_far = if complete { "" } else { " as far as it has come" };
            let said = format!(
                "visit {session} mapped{so_far} and published: {registered} of its images registered, {models} model(s), unlinked {unlinked:?}"
            );
            node.log(LogLevel::Info, &said);
            Ok(Ok(said))
        }
        Err(error) => {
            if !matches!(error, revisit_pipeline::PipelineError::Cancelled) {
                node.log(LogLevel::Error, &format!("mapping {session} failed: {error}"));
                let header = mapper.header(&out.frame_id);
                let _ = out.status.async_publish(status(&header, MapStatus::FAILED, &error.to_string())).await;
            }
            Ok(Err(error))
        }
    }
}

fn status(header: &Header, state: u8, message: &str) -> MapStatus {
    MapStatus { header: header.clone(), state, message: message.to_owned(), ..MapStatus::default() }
}

impl Mapper {
    fn open(dir: &Path, options: ReconstructOptions, tools: Tools, places: bool) -> Result<Mapper, NodeError> {
        let work = |e: revisit_pipeline::PipelineError| NodeError::Work(e.to_string());
        let mut workspace = Workspace::open(dir, options, tools).map_err(work)?;
        let (journal, lines) = Journal::open(&dir.join("mapper.journal"))?;
        let mut inputs = Inputs::default();
        for line in lines {
            let entry: Entry = serde_json::from_str(&line)
                .map_err(|e| NodeError::State(format!("{}: {e}", dir.join("mapper.journal").display())))?;
            inputs.apply(entry);
        }
        // Every visit's calibration, then the visits stored, in their order, with the keyframes on
        // disk; the others wait their turn.
        for session in &inputs.visits {
            if let Ok(spec) = std::fs::read_to_string(calibration_file(dir, session)) {
                if let Ok(spec) = spec.trim().parse() {
                    workspace.calibrate(session, spec);
                }
            }
        }
        let stored: Vec<String> =
            workspace.store().sessions().map_err(|e| work(e.into()))?.into_iter().map(|s| s.name).collect();
        for session in &stored {
            let images =
                list_session(&SessionSpec { name: session.clone(), dir: frames_dir(dir, session) }).map_err(work)?;
            workspace.add_session(images).map_err(work)?;
        }
        let queued = inputs.visits.iter().filter(|v| !stored.contains(v)).cloned().collect();
        Ok(Mapper { workspace, journal, inputs, waiting: BTreeMap::new(), queued, places, summary: Summary::default() })
    }

    /// Journals an input, then takes it in.
    fn record(&mut self, entry: Entry) -> Result<(), NodeError> {
        let line = serde_json::to_string(&entry).map_err(|e| NodeError::State(e.to_string()))?;
        self.journal.append(&line)?;
        self.inputs.apply(entry);
        Ok(())
    }

    /// Keeps a keyframe: its image as a file of the visit's folder (the camera's calibration beside
    /// it), the visit and image in the store, then any features that came first.
    fn keyframe(&mut self, keyframe: &Keyframe) -> Result<(), NodeError> {
        let dir = self.workspace.dir().to_path_buf();
        let name = full(&keyframe.session, &keyframe.image_name);
        let bad = |why: String| NodeError::Work(format!("keyframe {name}: {why}"));
        revisit_core::ImageName::new(&keyframe.session, &keyframe.image_name).map_err(|e| bad(e.to_string()))?;
        if keyframe.image_name.contains('/') {
            return Err(bad("image names must not hold '/'".into()));
        }
        let frames = frames_dir(&dir, &keyframe.session);
        let path = frames.join(&keyframe.image_name);
        if !path.exists() {
            revisit_pipeline::images::from_compressed(&keyframe.image, Path::new(&name))
                .map_err(|e| bad(e.to_string()))?;
            std::fs::create_dir_all(&frames).map_err(|e| bad(e.to_string()))?;
            write_atomically(&path, &keyframe.image.data).map_err(|e| bad(e.to_string()))?;
        }
        // The visit's calibration is its first keyframe's that has one, kept beside its frames.
        let calibration = calibration_file(&dir, &keyframe.session);
        let kept = std::fs::read_to_string(&calibration).ok().and_then(|text| text.trim().parse().ok());
        let spec = match (kept, messages::camera_spec(&keyframe.camera_info)) {
            (Some(kept), _) => Some(kept),
            (None, Some(spec)) => {
                write_atomically(&calibration, String::from(spec.clone()).as_bytes())
                    .map_err(|e| bad(e.to_string()))?;
                Some(spec)
            }
            (None, None) => None,
        };
        if let Some(spec) = spec {
            self.workspace.calibrate(&keyframe.session, spec);
        }
        self.summary.keyframes += 1;
        if !self.inputs.visits.contains(&keyframe.session) {
            self.record(Entry::Visit { session: keyframe.session.clone() })?;
        }
        if keyframe.has_prior {
            let p = keyframe.prior.pose.position;
            self.record(Entry::Prior { image: name.clone(), position_m: [p.x, p.y, p.z] })?;
        }
        let stamp_ns = keyframe.header.stamp.as_nanos();
        if self.inputs.newest_ns.get(&keyframe.session).is_none_or(|newest| stamp_ns > *newest) {
            self.record(Entry::Newest { session: keyframe.session.clone(), stamp_ns })?;
        }
        let known = self.workspace.sessions().iter().any(|s| s.name == keyframe.session);
        let all_mapped = self.workspace.sessions().iter().all(|s| self.inputs.mapped.contains(&s.name));
        // A new visit enters the store once every visit in it is mapped and none waits before it.
        let may_enter = known || (all_mapped && self.queued.is_empty());
        if !may_enter {
            if !self.queued.contains(&keyframe.session) {
                self.queued.push(keyframe.session.clone());
            }
            return Ok(());
        }
        self.admit(&keyframe.session)
    }

    /// Adds (or updates) a visit from its keyframes on disk, then stores the features that waited.
    fn admit(&mut self, session: &str) -> Result<(), NodeError> {
        let frames = frames_dir(self.workspace.dir(), session);
        let work = |e: revisit_pipeline::PipelineError| NodeError::Work(format!("visit {session}: {e}"));
        let images = list_session(&SessionSpec { name: session.to_owned(), dir: frames }).map_err(work)?;
        let names: Vec<String> = images.images().iter().map(|(_, name)| name.to_string()).collect();
        self.workspace.add_session(images).map_err(work)?;
        for name in names {
            for message in self.waiting.remove(&name).unwrap_or_default() {
                self.features(message)?;
            }
        }
        Ok(())
    }

    /// Stores a keyframe's features (or keeps them until the keyframe's visit is in the store).
    fn features(&mut self, message: Features) -> Result<(), NodeError> {
        let name = full(&message.session, &message.image_name);
        let record =
            messages::features_record(&message).map_err(|why| NodeError::Work(format!("features of {name}: {why}")))?;
        let admitted = self.workspace.sessions().iter().any(|s| s.name == message.session);
        let stored =
            admitted && self.workspace.add_features(&name, &record).map_err(|e| NodeError::Work(e.to_string()))?;
        if !stored {
            self.waiting.entry(name).or_default().push(message);
        }
        Ok(())
    }

    /// The visit last admitted, if it ended, is not mapped, and has everything it needs.
    fn ready(&self) -> Result<Option<String>, revisit_pipeline::PipelineError> {
        let store = self.workspace.store();
        let options = self.workspace.options();
        let with_sift = store.images_with_features()?;
        let method = options.learned.name();
        let learned = match options.cross.learned() {
            true => store.learned_feature_keys(method)?,
            false => BTreeSet::new(),
        };
        for session in self.workspace.sessions() {
            if self.inputs.mapped.contains(&session.name) {
                continue;
            }
            let Some(&keyframes) = self.inputs.ended.get(&session.name) else { return Ok(None) };
            if session.images.len() < keyframes as usize || !session.images.iter().all(|i| with_sift.contains(&i.id)) {
                return Ok(None);
            }
            if options.cross.learned() {
                let rolls = match session.visit {
                    0 => revisit_matching::RollSearch::Off.rolls(),
                    _ => options.learned_matching.roll_search.rolls(),
                };
                let all = session.images.iter().all(|i| rolls.iter().all(|r| learned.contains(&(i.id, r.degrees()))));
                if !all {
                    return Ok(None);
                }
            }
            if self.places && session.visit > 0 {
                for image in &session.images {
                    let name = image.name.to_string();
                    let Some(candidates) = self.inputs.candidates.get(&name) else { return Ok(None) };
                    if !candidates.iter().all(|c| self.inputs.found.contains_key(&(c.clone(), name.clone()))) {
                        return Ok(None);
                    }
                }
            }
            return Ok(Some(session.name.clone()));
        }
        Ok(None)
    }

    /// A header in the map's frame stamped as the map is ([`Inputs::map_stamp`]).
    fn header(&self, frame_id: &str) -> Header {
        let visits: Vec<String> = self.workspace.sessions().iter().map(|s| s.name.clone()).collect();
        Header { stamp: self.inputs.map_stamp(&visits), frame_id: frame_id.to_owned() }
    }

    /// The work folder's map (its `report.json` and chosen model) as messages (`None`: COLMAP
    /// registered no model), and their header. When keyframes of a visit came with odometry, the
    /// map is placed on the newest such visit's odometry: scaled to metres, with the `map -> odom`
    /// transform (REP 105) that goes with it.
    fn map_outputs(&self, out: &Outputs) -> Result<MapOutputs, NodeError> {
        let work = |e: String| NodeError::Work(e);
        let header = self.header(&out.frame_id);
        let report = Report::read(&self.workspace.dir().join("report.json")).map_err(|e| work(e.to_string()))?;
        let Some(model_dir) = &report.chosen_model else { return Ok(MapOutputs { header, ..MapOutputs::default() }) };
        let mut model = revisit_colmap::read_model(model_dir).map_err(|e| work(e.to_string()))?;
        let visits: Vec<String> = self.workspace.sessions().iter().map(|s| s.name.clone()).collect();
        let placed = visits.iter().rev().find_map(|visit| {
            let prefix = format!("{visit}/");
            let priors = self.inputs.priors.iter().filter(|(image, _)| image.starts_with(&prefix));
            messages::odom_from_map(&model, &priors.map(|(k, v)| (k.clone(), *v)).collect())
        });
        let map_to_odom = placed.map(|odom_from_map| {
            model.transform(odom_from_map.scale, &revisit_core::Rigid3::identity());
            let odom_from_metric_map = revisit_core::Similarity { scale: 1.0, ..odom_from_map };
            messages::map_to_odom(&header, &out.odom_frame_id, &odom_from_metric_map)
        });
        let messages = Some(messages::map_messages(&header, &model, &report, &visits));
        Ok(MapOutputs { messages, header, map_to_odom })
    }

    /// The first visit in the store not mapped complete (the one in progress), if any.
    fn unmapped(&self) -> Option<String> {
        self.workspace.sessions().iter().map(|s| s.name.clone()).find(|name| !self.inputs.mapped.contains(name))
    }

    /// Maps a complete visit ([`Mapper::reconstruct`]), records it mapped, and lets the next visit
    /// waiting into the store.
    fn map(&mut self, session: &str, cancel: &Cancel) -> Result<Report, revisit_pipeline::PipelineError> {
        let report = self.reconstruct(cancel)?;
        let entry = Entry::Mapped { session: session.to_owned() };
        self.record(entry).map_err(|e| revisit_pipeline::PipelineError::Name(e.to_string()))?;
        self.summary.mapped.push(session.to_owned());
        if !self.queued.is_empty() {
            let next = self.queued.remove(0);
            self.admit(&next).map_err(|e| revisit_pipeline::PipelineError::Name(e.to_string()))?;
        }
        Ok(report)
    }

    /// Stores the matchers' answers, then runs the reconstruction on every keyframe in the store
    /// (computing what has not come for them).
    fn reconstruct(&mut self, cancel: &Cancel) -> Result<Report, revisit_pipeline::PipelineError> {
        let ids = self.workspace.store().image_ids()?;
        let mut found = Vec::new();
        for ((image1, image2), message) in &self.inputs.found {
            let (Some(&id1), Some(&id2)) = (ids.get(image1), ids.get(image2)) else { continue };
            if message.method != self.workspace.options().learned.name() {
                continue;
            }
            let answer = messages::cross_match(message)
                .map_err(|why| revisit_pipeline::PipelineError::Name(format!("matches {image1} - {image2}: {why}")))?;
            found.push((
                LearnedPair { image_id1: id1, image_id2: id2, kind: PairKind::Cross, rank: 0, place_roll: None },
                answer,
            ));
        }
        if !found.is_empty() {
            self.workspace.add_cross_matches(found)?;
        }
        self.workspace.run(&Silent, cancel)
    }
}

/// The map as the node publishes it.
#[derive(Default)]
struct MapOutputs {
    /// `None`: COLMAP registered no model.
    messages: Option<MapMessages>,
    header: Header,
    map_to_odom: Option<TransformStamped>,
}

/// Publishes the map on the map topics (and `map -> odom` on `/tf` from now on).
async fn publish_map(node: &mut Node, out: &mut Outputs, outputs: MapOutputs) -> Result<(), NodeError> {
    let MapOutputs { messages, header, map_to_odom } = outputs;
    out.map_to_odom = map_to_odom;
    let Some(MapMessages { cloud, paths, cameras, status: map_status }) = messages else {
        let message = status(&header, MapStatus::FAILED, "COLMAP registered no model");
        return out.status.async_publish(message).await.map_err(dds);
    };
    out.cloud.async_publish(cloud).await.map_err(dds)?;
    out.cameras.async_publish(cameras).await.map_err(dds)?;
    for (session, path) in paths {
        if !out.paths.contains_key(&session) {
            let topic = format!("map/path/{}", topic_safe(&session));
            out.paths.insert(session.clone(), node.publisher(&topic, LATCHED)?);
        }
        if let Some(publisher) = out.paths.get(&session) {
            publisher.async_publish(path).await.map_err(dds)?;
        }
    }
    out.status.async_publish(map_status).await.map_err(dds)
}

/// The reconstruction's options from the `options_file` and `cross` parameters.
pub fn node_options(node: &Node) -> Result<ReconstructOptions, NodeError> {
    let file: Option<PathBuf> = node.param("options_file", None)?;
    let cross: Option<String> = node.param("cross", None)?;
    ReconstructOptions::for_node(file.as_deref(), cross.as_deref())
        .map_err(|reason| NodeError::Parameter { name: "options_file".into(), reason })
}

/// A visit's name as a ROS topic name token: letters, digits and `_` (others become `_`).
pub fn topic_safe(session: &str) -> String {
    let name: String = session.chars().map(|c| if c.is_ascii_alphanumeric() { c } else { '_' }).collect();
    match name.starts_with(|c: char| c.is_ascii_digit()) {
        true => format!("v{name}"),
        false => name,
    }
}

fn dds(error: impl std::fmt::Debug) -> NodeError {
    NodeError::Dds(format!("{error:?}"))
}

fn frames_dir(work: &Path, session: &str) -> PathBuf {
    work.join("frames").join(session)
}

fn calibration_file(work: &Path, session: &str) -> PathBuf {
    work.join("frames").join(format!("{session}.camera"))
}

fn write_atomically(path: &Path, bytes: &[u8]) -> std::io::Result<()> {
    let partial = path.with_extension("partial");
    std::fs::write(&partial, bytes)?;
    std::fs::rename(&partial, path)
}
