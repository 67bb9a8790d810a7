//! The matcher node: place candidates in (`places/candidates`), what the learned matcher finds for
//! each candidate pair out (`matches`: CrossVisitMatches, the roll search's winner and its
//! matches; the mapper applies the acceptance rule where the store is). The learned features come
//! from `features` into the node's own feature store. Thin over `Learned::match_rolls`, the roll
//! search `reconstruct` runs.
//!
//! Several matchers share the pairs through DDS, with no scheme of their own: each subscribes
//! `/revisit/matchers`, so every matcher sees the others as readers of that topic; the pairs are
//! dealt among the matchers alive (by a hash of the pair's names over the sorted reader ids), and a
//! pair any matcher answered on `matches` is not matched again. A matcher that stops leaves its
//! unanswered pairs to the others, who see it go.
//!
//! Parameters: `options_file` and `cross` (the reconstruction's options, as the mapper's),
//! `state_dir` (default `revisit-state/matcher`), `models`, `onnx_threads`.
//!
//! Restartable: features are kept in a store, the pairs asked for are journalled when they come,
//! and a pair is journalled as done only after its answer is published.

use std::collections::{BTreeMap, BTreeSet};
use std::path::PathBuf;
use std::time::{Duration, Instant};

use futures::StreamExt;
use revisit_core::Roll;
use revisit_msgs::diagnostic_msgs::KeyValue;
use revisit_msgs::revisit_msgs::{CrossVisitMatches, Features, PlaceCandidates};
use revisit_node::{Guid, Journal, LogLevel, Node, NodeError, Stage, WORK_QUEUE};
use revisit_pipeline::cache::FeatureCache;
use revisit_pipeline::learned::Learned;
use revisit_pipeline::locate::Tools;
use revisit_pipeline::{messages, ReconstructOptions};

/// The node's name unless remapped.
pub const NAME: &str = "matcher";

/// The topic every matcher reads, so that the matchers see each other.
pub const MEMBERS_TOPIC: &str = "/revisit/matchers";

/// What a run did.
#[derive(Debug, Default, Clone, PartialEq, Eq)]
pub struct Summary {
    /// Pairs this matcher matched.
    pub matched: u64,
    /// Pairs it saw answered by another matcher.
    pub by_others: u64,
}

impl std::fmt::Display for Summary {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "{} pairs matched, {} answered by other matchers", self.matched, self.by_others)
    }
}

/// The reconstruction's options from the `options_file` and `cross` parameters.
pub fn node_options(node: &Node) -> Result<ReconstructOptions, NodeError> {
    let file: Option<PathBuf> = node.param("options_file", None)?;
    let cross: Option<String> = node.param("cross", None)?;
    ReconstructOptions::for_node(file.as_deref(), cross.as_deref())
        .map_err(|reason| NodeError::Parameter { name: "options_file".into(), reason })
}

/// A candidate pair: (earlier image, later image), `session/file` names.
type Pair = (String, String);

struct Matcher {
    options: ReconstructOptions,
    learned: Learned,
    cache: FeatureCache,
    journal: Journal,
    /// (image, roll degrees) held in the cache.
    held: BTreeSet<(String, u32)>,
    /// Pairs asked for and not yet answered.
    pending: BTreeSet<Pair>,
    /// Each pair's place roll (the later image's roll place recognition found nearest): where
    /// its roll search begins.
    place_rolls: BTreeMap<Pair, Roll>,
    answered: BTreeSet<Pair>,
    /// The matchers alive, this one's id among them.
    members: Vec<Guid>,
    me: Guid,
    summary: Summary,
}

/// Runs the matcher node until SIGINT or SIGTERM (the pair in flight is finished).
pub async fn run(node: &mut Node) -> Result<Summary, NodeError> {
    let options = node_options(node)?;
    if !options.cross.places() {
        // A graph launched whole with another strategy: no candidates will come.
        node.log(LogLevel::Info, &format!("cross {} does not use place recognition: idle", options.cross.name()));
        node.stopped().await;
        return Ok(Summary::default());
    }
    let state_dir: PathBuf = node.param("state_dir", PathBuf::from("revisit-state/matcher"))?;
    let tools = Tools { models: node.param("models", None)?, ..Tools::default() };
    let threads: usize = node.param("onnx_threads", 0)?;
    let work = |e: String| NodeError::Work(e);
    let runtime = tools.onnxruntime(threads).map_err(|e| work(e.to_string()))?;
    let learned = Learned::open(&runtime, &tools.models(), options.learned, options.features.learned_input)
        .map_err(|e| work(e.to_string()))?;
    let cache = FeatureCache::open(&state_dir.join("matcher.db"), "features").map_err(|e| work(e.to_string()))?;
    let (journal, lines) = Journal::open(&state_dir.join("journal"))?;
    let names: BTreeMap<_, _> =
        cache.store().image_ids().map_err(|e| work(e.to_string()))?.into_iter().map(|(name, id)| (id, name)).collect();
    let keys = cache.store().learned_feature_keys(options.learned.name()).map_err(|e| work(e.to_string()))?;
    let held = keys.into_iter().filter_map(|(id, roll)| Some((names.get(&id)?.clone(), roll))).collect();
    let (mut asked, mut answered, mut place_rolls) = (BTreeSet::new(), BTreeSet::new(), BTreeMap::new());
    for line in lines {
        match line.split('\t').collect::<Vec<_>>()[..] {
            ["asked", a, b] => {
                asked.insert((a.to_owned(), b.to_owned()));
            }
            ["asked", a, b, roll] => {
                let pair = (a.to_owned(), b.to_owned());
                if let Some(roll) = roll.parse().ok().and_then(Roll::from_degrees) {
                    place_rolls.insert(pair.clone(), roll);
                }
                asked.insert(pair);
            }
            ["done" | "answered", a, b] => {
                answered.insert((a.to_owned(), b.to_owned()));
            }
            _ => {
                return Err(NodeError::State(format!("{}: unknown line {line:?}", state_dir.join("journal").display())))
            }
        }
    }

    let features = node.subscription::<Features>("features", WORK_QUEUE)?;
    let candidates = node.subscription::<PlaceCandidates>("places/candidates", WORK_QUEUE)?;
    let answers = node.subscription::<CrossVisitMatches>("matches", WORK_QUEUE)?;
    let members = node.subscription::<KeyValue>(MEMBERS_TOPIC, WORK_QUEUE)?;
    let publisher = node.publisher::<CrossVisitMatches>("matches", WORK_QUEUE)?;
    let me = members.guid();
    let mut matcher = Matcher {
        options,
        learned,
        cache,
        journal,
        held,
        pending: asked.difference(&answered).cloned().collect(),
        place_rolls,
        answered,
        members: vec![me],
        me,
        summary: Summary::default(),
    };
    let stage = node.stage("pairs");
    let stopped = node.stopped();
    let mut stopped = std::pin::pin!(stopped);
    let (mut features, mut candidates) =
        (std::pin::pin!(features.async_stream()), std::pin::pin!(candidates.async_stream()));
    let mut answers = std::pin::pin!(answers.async_stream());
    let mut tick = tokio::time::interval(Duration::from_millis(500));
    node.log(
        LogLevel::Info,
        &format!("matching with {}; state in {}", matcher.options.learned.name(), state_dir.display()),
    );
    loop {
        let next = matcher.next_pair();
        let result = tokio::select! {
            biased;
            () = &mut stopped => break,
            Some(Ok((message, _))) = features.next() => tokio::task::block_in_place(|| matcher.add(&message)),
            Some(Ok((message, _))) = candidates.next() => matcher.ask(&message, &stage),
            Some(Ok((message, _))) = answers.next() => {
                let pair = (format!("{}/{}", message.session1, message.image_name1), format!("{}/{}", message.session2, message.image_name2));
                matcher.answered_by_another(pair)
            }
            _ = tick.tick() => {
                let mut members = node.other_readers(MEMBERS_TOPIC);
                members.push(matcher.me);
                members.sort();
                members.dedup();
                matcher.members = members;
                Ok(())
            }
            () = std::future::ready(()), if next.is_some() => {
                let Some(pair) = next else { continue };
                let started = Instant::now();
                let header = node.header("");
                match tokio::task::block_in_place(|| matcher.match_pair(&pair, header)) {
                    Ok(answer) => {
                        publisher.async_publish(answer).await.map_err(|e| NodeError::Dds(format!("{e:?}")))?;
                        matcher.journal.append(&format!("done\t{}\t{}", pair.0, pair.1))?;
                        matcher.pending.remove(&pair);
                        matcher.answered.insert(pair);
                        matcher.summary.matched += 1;
                        stage.done(started.elapsed());
                        Ok(())
                    }
                    Err(error) => {
                        matcher.pending.remove(&pair);
                        stage.dropped(1);
                        Err(error)
                    }
                }
            }
        };
        stage.queue_depth(matcher.pending.len());
        if let Err(error) = result {
            node.log(LogLevel::Warn, &error.to_string());
        }
    }
    Ok(matcher.summary)
}

/// A deterministic hash of a pair (FNV-1a), the same in every matcher.
fn pair_hash((a, b): &Pair) -> u64 {
    let mut hash: u64 = 0xcbf2_9ce4_8422_2325;
    for byte in a.bytes().chain([0]).chain(b.bytes()) {
        hash = (hash ^ u64::from(byte)).wrapping_mul(0x0100_0000_01b3);
    }
    hash
}

impl Matcher {
    /// Takes a keyframe's candidate pairs as work, journalled first: a restarted matcher still has
    /// the pairs it was asked for (the places node answers a visit once).
    fn ask(&mut self, message: &PlaceCandidates, stage: &Stage) -> Result<(), NodeError> {
        let later = format!("{}/{}", message.session, message.image_name);
        for candidate in &message.candidates {
            let pair = (format!("{}/{}", candidate.session, candidate.image_name), later.clone());
            if !self.answered.contains(&pair) && !self.pending.contains(&pair) {
                let roll = u32::try_from(candidate.roll_degrees).ok().and_then(Roll::from_degrees);
                let journalled = roll.map_or(String::new(), |r| format!("\t{}", r.degrees()));
                self.journal.append(&format!("asked\t{}\t{}{journalled}", pair.0, pair.1))?;
                if let Some(roll) = roll {
                    self.place_rolls.insert(pair.clone(), roll);
                }
                self.pending.insert(pair);
                stage.received();
            }
        }
        Ok(())
    }

    fn add(&mut self, message: &Features) -> Result<(), NodeError> {
        let name = format!("{}/{}", message.session, message.image_name);
        let record =
            messages::features_record(message).map_err(|why| NodeError::Work(format!("features of {name}: {why}")))?;
        if let messages::FeaturesRecord::Learned { method, roll, .. } = &record {
            if method == self.options.learned.name() {
                self.cache
                    .add(&message.session, &message.image_name, &record)
                    .map_err(|e| NodeError::Work(e.to_string()))?;
                self.held.insert((name, roll.degrees()));
            }
        }
        Ok(())
    }

    /// Notes a pair answered on `matches` (journalled when it was this matcher's work to do).
    fn answered_by_another(&mut self, pair: Pair) -> Result<(), NodeError> {
        if self.pending.remove(&pair) {
            self.journal.append(&format!("answered\t{}\t{}", pair.0, pair.1))?;
            self.summary.by_others += 1;
        }
        self.answered.insert(pair);
        Ok(())
    }

    /// The first pending pair dealt to this matcher whose features are all here.
    fn next_pair(&self) -> Option<Pair> {
        let index = self.members.iter().position(|m| *m == self.me).unwrap_or(0);
        let n = self.members.len().max(1) as u64;
        let rolls = self.options.learned_matching.roll_search.rolls();
        self.pending
            .iter()
            .filter(|pair| !self.answered.contains(*pair))
            .filter(|pair| pair_hash(pair) % n == index as u64)
            .find(|(a, b)| {
                self.held.contains(&(a.clone(), 0))
                    && rolls.iter().all(|r| self.held.contains(&(b.clone(), r.degrees())))
            })
            .cloned()
    }

    /// Runs the roll search on one pair, as `reconstruct` does.
    fn match_pair(
        &mut self,
        (a, b): &Pair,
        header: revisit_msgs::std_msgs::Header,
    ) -> Result<CrossVisitMatches, NodeError> {
        let method = self.options.learned.name();
        let options = &self.options.learned_matching;
        let work = |e: String| NodeError::Work(format!("pair {a} - {b}: {e}"));
        let read = |name: &str, roll: Roll| -> Result<_, NodeError> {
            self.cache
                .learned(name, method, roll)
                .map_err(|e| work(e.to_string()))?
                .ok_or_else(|| work(format!("no features of {name} at roll {}", roll.degrees())))
        };
        let features_a = read(a, Roll::R0)?;
        let b_by_roll = options
            .roll_search
            .rolls()
            .iter()
            .map(|r| Ok((*r, read(b, *r)?)))
            .collect::<Result<Vec<_>, NodeError>>()?;
        let search = (options.roll_search, self.place_rolls.get(&(a.clone(), b.clone())).copied());
        let found =
            self.learned.match_rolls(&features_a, &b_by_roll, search, options).map_err(|e| work(e.to_string()))?;
        let split = |name: &str| -> (String, String) {
            let (session, file) = name.split_once('/').unwrap_or(("", name));
            (session.to_owned(), file.to_owned())
        };
        let ((sa, fa), (sb, fb)) = (split(a), split(b));
        Ok(messages::cross_match_message(header, (&sa, &fa), (&sb, &fb), method, &found))
    }
}
