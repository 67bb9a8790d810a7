//! The features node: keyframes in (`keyframes`), features out (`features`, one message per
//! method and roll): SIFT for matching within a visit and, unless `learned:=none`, the learned
//! method's features at each roll the cross-visit search needs: roll 0 for the reference visit (the
//! first this node ever saw), every searched roll for later visits. Thin over
//! `stages::sift_features` and `Learned::extract`, the functions `revisit reconstruct` runs, so a
//! keyframe's features are the same bytes either way.
//!
//! Parameters: `options_file` and `cross` (the reconstruction's options, as the mapper's: they
//! choose the learned method, none unless visits are linked by a learned strategy, and the rolls
//! the search needs), `state_dir` (the node's memory: the order of visits and the keyframes done; default
//! `revisit-state/features`), `models` (the ONNX models' folder; default as `revisit` finds it),
//! `onnx_threads` (0: ONNX Runtime's choice).
//!
//! Restartable: a keyframe is journalled only after its features are published, so a node killed
//! mid-way and restarted (it receives the ingest node's backlog again) publishes each keyframe's
//! features at least once and describes none twice.

use std::collections::BTreeSet;
use std::path::{Path, PathBuf};
use std::time::Instant;

use futures::StreamExt;
use revisit_core::Roll;
use revisit_msgs::revisit_msgs::{Features, Keyframe};
use revisit_node::{Journal, LogLevel, Node, NodeError, Publisher, WORK_QUEUE};
use revisit_pipeline::learned::Learned;
use revisit_pipeline::locate::Tools;
use revisit_pipeline::messages;
use revisit_pipeline::options::FeatureOptions;
use revisit_pipeline::ReconstructOptions;

/// The node's name unless remapped.
pub const NAME: &str = "features";

/// What a run did.
#[derive(Debug, Default, Clone, PartialEq, Eq)]
pub struct Summary {
    pub described: u64,
    pub dropped: u64,
}

impl std::fmt::Display for Summary {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "{} keyframes described, {} dropped", self.described, self.dropped)
    }
}

/// The node's memory: visits in the order first seen (the first is the reference) and the
/// keyframes whose features were published.
struct State {
    journal: Journal,
    visits: Vec<String>,
    done: BTreeSet<String>,
}

impl State {
    fn open(dir: &Path) -> Result<State, NodeError> {
        let (journal, lines) = Journal::open(&dir.join("journal"))?;
        let (mut visits, mut done) = (Vec::new(), BTreeSet::new());
        for line in lines {
            match line.split_once(' ') {
                Some(("visit", name)) => visits.push(name.to_owned()),
                Some(("done", key)) => {
                    done.insert(key.to_owned());
                }
                _ => return Err(NodeError::State(format!("{}: unknown line {line:?}", dir.join("journal").display()))),
            }
        }
        Ok(State { journal, visits, done })
    }

    /// The visit's place in the order (a new visit goes last, and is remembered).
    fn visit_index(&mut self, session: &str) -> Result<usize, NodeError> {
        if let Some(at) = self.visits.iter().position(|v| v == session) {
            return Ok(at);
        }
        self.journal.append(&format!("visit {session}"))?;
        self.visits.push(session.to_owned());
        Ok(self.visits.len() - 1)
    }
}

/// The reconstruction's options from the `options_file` and `cross` parameters.
pub fn node_options(node: &Node) -> Result<ReconstructOptions, NodeError> {
    let file: Option<PathBuf> = node.param("options_file", None)?;
    let cross: Option<String> = node.param("cross", None)?;
    ReconstructOptions::for_node(file.as_deref(), cross.as_deref())
        .map_err(|reason| NodeError::Parameter { name: "options_file".into(), reason })
}

/// The learned method's models and the rolls later visits need.
struct LearnedSide {
    learned: Learned,
    later_rolls: &'static [Roll],
}

/// Runs the features node until SIGINT or SIGTERM (the keyframe in flight is finished).
pub async fn run(node: &mut Node) -> Result<Summary, NodeError> {
    let options = node_options(node)?;
    let search = options.learned_matching.roll_search;
    let state_dir: PathBuf = node.param("state_dir", PathBuf::from("revisit-state/features"))?;
    let mut state = State::open(&state_dir)?;
    let method = options.learned.name();
    let mut learned = match options.cross.learned() {
        false => None,
        true => {
            let tools = Tools { models: node.param("models", None)?, ..Tools::default() };
            let threads: usize = node.param("onnx_threads", 0)?;
            let work = |e: String| NodeError::Work(e);
            let runtime = tools.onnxruntime(threads).map_err(|e| work(e.to_string()))?;
            let learned = Learned::open(&runtime, &tools.models(), options.learned, options.features.learned_input)
                .map_err(|e| work(e.to_string()))?;
            Some(LearnedSide { learned, later_rolls: search.rolls() })
        }
    };
    let sift = options.features.clone();

    let keyframes = node.subscription::<Keyframe>("keyframes", WORK_QUEUE)?;
    let features = node.publisher::<Features>("features", WORK_QUEUE)?;
    let stage = node.stage("keyframes");
    let mut summary = Summary::default();
    let stopped = node.stopped();
    let mut stopped = std::pin::pin!(stopped);
    let mut keyframes = std::pin::pin!(keyframes.async_stream());
    let learned_name = if learned.is_some() { method } else { "no learned method" };
    node.log(
        LogLevel::Info,
        &format!("describing keyframes with SIFT and {learned_name}; state in {}", state_dir.display()),
    );
    loop {
        let keyframe = tokio::select! {
            () = &mut stopped => break,
            Some(Ok((keyframe, _))) = keyframes.next() => keyframe,
        };
        stage.received();
        let key = format!("{}/{}", keyframe.session, keyframe.image_name);
        if state.done.contains(&key) {
            continue;
        }
        let started = Instant::now();
        let visit = state.visit_index(&keyframe.session)?;
        let messages = tokio::task::block_in_place(|| describe(&keyframe, visit, &sift, learned.as_mut()));
        match messages {
            Ok(messages) => {
                publish(&features, messages).await?;
                state.journal.append(&format!("done {key}"))?;
                state.done.insert(key);
                summary.described += 1;
                stage.done(started.elapsed());
            }
            Err(why) => {
                node.log(LogLevel::Warn, &format!("keyframe {key} dropped: {why}"));
                summary.dropped += 1;
                stage.dropped(1);
            }
        }
    }
    Ok(summary)
}

/// A keyframe's features messages: SIFT, then the learned method's at each roll its visit needs.
fn describe(
    keyframe: &Keyframe,
    visit: usize,
    sift: &FeatureOptions,
    learned: Option<&mut LearnedSide>,
) -> Result<Vec<Features>, String> {
    let origin = Path::new(&keyframe.session).join(&keyframe.image_name);
    let image = revisit_pipeline::images::from_compressed(&keyframe.image, &origin).map_err(|e| e.to_string())?;
    let header = keyframe.header.clone();
    let (session, name) = (keyframe.session.as_str(), keyframe.image_name.as_str());
    let size = [image.width(), image.height()];
    let mut out = vec![messages::sift_message(
        header.clone(),
        session,
        name,
        size,
        &revisit_pipeline::stages::sift_features(sift, &image)?,
    )];
    if let Some(side) = learned {
        let rgb = image.to_rgb8();
        let rolls: &[Roll] = if visit == 0 { &[Roll::R0] } else { side.later_rolls };
        let method = side.learned.method.name();
        for roll in rolls {
            let features = side.learned.extract(&rgb, *roll).map_err(|e| e.to_string())?;
            out.push(messages::learned_message(header.clone(), session, name, method, *roll, &features));
        }
    }
    Ok(out)
}

async fn publish(publisher: &Publisher<Features>, messages: Vec<Features>) -> Result<(), NodeError> {
    for message in messages {
        publisher.async_publish(message).await.map_err(|e| NodeError::Dds(format!("{e:?}")))?;
    }
    Ok(())
}
