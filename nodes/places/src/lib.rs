//! The places node: learned features in (`features`), each later visit's place-recognition
//! candidates out (`places/candidates`: one PlaceCandidates per keyframe, its nearest images of
//! earlier visits with their distances and the query's best roll). A visit is answered once its
//! END (`visits`) has come and every keyframe's features at every roll the search needs are in.
//! Thin over `cross::describe_places` and `cross::place_candidates`, the functions `reconstruct`
//! runs, on the node's own feature store, so its candidates are the pairs `reconstruct` would try
//! (the VLAD vocabulary is learned, as there, from the visits present when the second one ends).
//!
//! Parameters: `options_file` and `cross` (the reconstruction's options, as the mapper's),
//! `state_dir` (the place index: features, vocabulary, descriptors; default
//! `revisit-state/places`), `onnx_threads`.
//!
//! Restartable: the index is a store, and a visit is journalled as answered only after its
//! candidates are published.

use std::collections::{BTreeMap, BTreeSet};
use std::path::PathBuf;

use futures::StreamExt;
use revisit_core::Roll;
use revisit_msgs::revisit_msgs::{Features, PlaceCandidate, PlaceCandidates, SessionControl};
use revisit_msgs::std_msgs::Header;
use revisit_node::{Journal, LogLevel, Node, NodeError, Publisher, WORK_QUEUE};
use revisit_pipeline::cache::FeatureCache;
use revisit_pipeline::locate::Tools;
use revisit_pipeline::{cross, messages, Cancel, PipelineError, ReconstructOptions, Silent};

/// The node's name unless remapped.
pub const NAME: &str = "places";

/// What a run did.
#[derive(Debug, Default, Clone, PartialEq, Eq)]
pub struct Summary {
    /// Visits answered, in order.
    pub answered: Vec<String>,
    pub queries: u64,
}

impl std::fmt::Display for Summary {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "{} keyframes answered, visits {:?}", self.queries, self.answered)
    }
}

/// The reconstruction's options from the `options_file` and `cross` parameters.
pub fn node_options(node: &Node) -> Result<ReconstructOptions, NodeError> {
    let file: Option<PathBuf> = node.param("options_file", None)?;
    let cross: Option<String> = node.param("cross", None)?;
    ReconstructOptions::for_node(file.as_deref(), cross.as_deref())
        .map_err(|reason| NodeError::Parameter { name: "options_file".into(), reason })
}

struct Places {
    options: ReconstructOptions,
    cache: FeatureCache,
    runtime: revisit_onnx::Runtime,
    journal: Journal,
    /// Visits ended, with their keyframe counts.
    ended: BTreeMap<String, u32>,
    answered: BTreeSet<String>,
}

/// Runs the places node until SIGINT or SIGTERM.
pub async fn run(node: &mut Node) -> Result<Summary, NodeError> {
    let options = node_options(node)?;
    if !options.cross.places() {
        // A graph launched whole with another strategy: nothing to do here (not an error, so a
        // respawning launcher does not restart it again and again).
        node.log(LogLevel::Info, &format!("cross {} does not use place recognition: idle", options.cross.name()));
        node.stopped().await;
        return Ok(Summary::default());
    }
    let state_dir: PathBuf = node.param("state_dir", PathBuf::from("revisit-state/places"))?;
    let threads: usize = node.param("onnx_threads", 0)?;
    let work = |e: String| NodeError::Work(e);
    let runtime = Tools::default().onnxruntime(threads).map_err(|e| work(e.to_string()))?;
    let cache = FeatureCache::open(&state_dir.join("places.db"), "features").map_err(|e| work(e.to_string()))?;
    let (journal, lines) = Journal::open(&state_dir.join("journal"))?;
    let mut places = Places { options, cache, runtime, journal, ended: BTreeMap::new(), answered: BTreeSet::new() };
    for line in lines {
        match line.split_whitespace().collect::<Vec<_>>()[..] {
            ["end", session, count] => {
                places.ended.insert(session.to_owned(), count.parse().unwrap_or(0));
            }
            ["answered", session] => {
                places.answered.insert(session.to_owned());
            }
            _ => {
                return Err(NodeError::State(format!("{}: unknown line {line:?}", state_dir.join("journal").display())))
            }
        }
    }

    let features = node.subscription::<Features>("features", WORK_QUEUE)?;
    let visits = node.subscription::<SessionControl>("visits", WORK_QUEUE)?;
    let candidates = node.publisher::<PlaceCandidates>("places/candidates", WORK_QUEUE)?;
    let stage = node.stage("features");
    let mut summary = Summary::default();
    let stopped = node.stopped();
    let mut stopped = std::pin::pin!(stopped);
    let (mut features, mut visits) = (std::pin::pin!(features.async_stream()), std::pin::pin!(visits.async_stream()));
    node.log(LogLevel::Info, &format!("place index in {}", state_dir.display()));
    loop {
        let result = tokio::select! {
            () = &mut stopped => break,
            Some(Ok((message, _))) = features.next() => {
                stage.received();
                tokio::task::block_in_place(|| places.add(&message))
            }
            Some(Ok((message, _))) = visits.next() => match message.command {
                SessionControl::END => places.end(&message.session, message.keyframes),
                _ => Ok(()),
            },
        };
        if let Err(error) = result {
            node.log(LogLevel::Warn, &error.to_string());
            stage.dropped(1);
            continue;
        }
        while let Some(session) = tokio::task::block_in_place(|| places.ready()).map_err(|e| work(e.to_string()))? {
            let started = std::time::Instant::now();
            let header = node.header("");
            let answers =
                tokio::task::block_in_place(|| places.answer(&session, &header)).map_err(|e| work(e.to_string()))?;
            summary.queries += answers.len() as u64;
            publish(&candidates, answers).await?;
            places.journal.append(&format!("answered {session}"))?;
            places.answered.insert(session.clone());
            node.log(
                LogLevel::Info,
                &format!("visit {session}: candidates in {:.1} s", started.elapsed().as_secs_f64()),
            );
            summary.answered.push(session);
            stage.done(started.elapsed());
        }
    }
    Ok(summary)
}

impl Places {
    fn add(&mut self, message: &Features) -> Result<(), NodeError> {
        let record = messages::features_record(message)
            .map_err(|why| NodeError::Work(format!("features of {}/{}: {why}", message.session, message.image_name)))?;
        let learned = matches!(&record, messages::FeaturesRecord::Learned { method, .. } if method == self.options.learned.name());
        if learned {
            self.cache
                .add(&message.session, &message.image_name, &record)
                .map_err(|e| NodeError::Work(e.to_string()))?;
        }
        Ok(())
    }

    fn end(&mut self, session: &str, keyframes: u32) -> Result<(), NodeError> {
        self.journal.append(&format!("end {session} {keyframes}"))?;
        self.ended.insert(session.to_owned(), keyframes);
        Ok(())
    }

    /// The first visit, in visit order, that ended, is not answered, and has every keyframe's
    /// features at every roll it needs (the reference visit is answered by being complete: it has
    /// no earlier visit).
    fn ready(&mut self) -> Result<Option<String>, PipelineError> {
        let sessions = self.cache.sessions()?;
        let method = self.options.learned.name();
        let stored = self.cache.store().learned_feature_keys(method)?;
        for (k, session) in sessions.iter().enumerate() {
            if self.answered.contains(&session.name) {
                continue;
            }
            let Some(&keyframes) = self.ended.get(&session.name) else { return Ok(None) };
            let rolls: &[Roll] = if k == 0 { &[Roll::R0] } else { self.options.learned_matching.roll_search.rolls() };
            let complete = session.images.len() >= keyframes as usize
                && session.images.iter().all(|i| rolls.iter().all(|r| stored.contains(&(i.id, r.degrees()))));
            if !complete {
                return Ok(None);
            }
            return Ok(Some(session.name.clone()));
        }
        Ok(None)
    }

    /// The candidates of each keyframe of `session` among the visits before it.
    fn answer(&mut self, session: &str, header: &Header) -> Result<Vec<PlaceCandidates>, PipelineError> {
        let sessions = self.cache.sessions()?;
        let Some(k) = sessions.iter().position(|s| s.name == session) else { return Ok(Vec::new()) };
        if k == 0 {
            return Ok(Vec::new());
        }
        let present = &sessions[..=k];
        let options = &self.options;
        let method = options.learned.name();
        let search = options.learned_matching.roll_search;
        let store = self.cache.store_mut();
        let places = cross::describe_places(
            store,
            method,
            &options.places.source,
            &self.runtime,
            present,
            search,
            &Silent,
            &Cancel::new(),
        )?;
        let names: BTreeMap<_, _> = present.iter().flat_map(|s| &s.images).map(|i| (i.id, &i.name)).collect();
        let answers = cross::place_candidates(present, &places, &options.places.candidates, k)
            .into_iter()
            .filter_map(|(query, found)| {
                let query = names.get(&query)?;
                let candidates = found
                    .iter()
                    .filter_map(|(id, candidate)| {
                        let name = names.get(id)?;
                        Some(PlaceCandidate {
                            session: name.session().to_owned(),
                            image_name: name.file().to_owned(),
                            distance: candidate.distance,
                            roll_degrees: candidate.roll.degrees() as i32,
                        })
                    })
                    .collect();
                Some(PlaceCandidates {
                    header: header.clone(),
                    session: query.session().to_owned(),
                    image_name: query.file().to_owned(),
                    candidates,
                })
            })
            .collect();
        Ok(answers)
    }
}

async fn publish(publisher: &Publisher<PlaceCandidates>, messages: Vec<PlaceCandidates>) -> Result<(), NodeError> {
    for message in messages {
        publisher.async_publish(message).await.map_err(|e| NodeError::Dds(format!("{e:?}")))?;
    }
    Ok(())
}
