//! The ingest node: camera topics in (`image` or `image/compressed`, `camera_info`, `odom`,
//! session control on `/revisit/session`), keyframes of visits out (`keyframes`, with START and
//! END on `visits`). Thin over the pipeline's [`VisitStream`], which `reconstruct --bag` drives
//! too.
//!
//! Parameters: `session` (the visit's name; when unset, visits start and end by session-control
//! messages and frames outside a visit are dropped, but for those that come just before their
//! visit's START and are stamped at or after it), `split_gap_s`, `keyframe.min_overlap`
//! (default 0.7; 0 or less keeps every frame), `keyframe.every_s`, `keyframe.distance_m`,
//! `camera` (default `cam0`). `/revisit/session` is read latched (transient local, as `bag pack`
//! and `synth --bag` record it); a volatile publisher needs
//! `-p qos_overrides./revisit/session.subscription.durability:=volatile`.
//!
//! Or from a bag: `bag` (a rosbag2 folder or file) is read first, its one image topic (or
//! `bag_topic`), camera info, odometry and visit markers taken in as if they came over the
//! topics, at the bag's pace times `bag_rate` (default 1; 0: as fast as it reads); then the
//! node goes on with its topics.
//!
//! Frames are judged on a preview (a JPEG decoded at a reduced scale), so a 1280x720 camera at
//! 30 Hz is kept up with; frames its publishers sent that never arrived are counted as `lost` on
//! `/diagnostics`. A keyframe waits for the odometry of its stamp and carries the pose
//! interpolated there.

use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use futures::StreamExt;
use revisit_bag::Bag;
use revisit_msgs::builtin_interfaces::Time;
use revisit_msgs::nav_msgs::Odometry;
use revisit_msgs::revisit_msgs::{Keyframe, SessionControl};
use revisit_msgs::sensor_msgs::{CameraInfo, CompressedImage, Image};
use revisit_msgs::Message;
use revisit_node::{
    History, LogLevel, MessageInfo, Node, NodeError, Publisher, Stage, LATCHED, SENSOR_DATA, WORK_QUEUE,
};
use revisit_pipeline::bags::{frame_file, frame_of, only_image_topic, Frame, SESSION_TOPIC};
use revisit_pipeline::keyframes::{KeyframeOptions, VisitEvent, VisitStream, DEFAULT_MIN_OVERLAP, PREVIEW_WIDTH_PX};
use revisit_pipeline::odometry::OdometryTrack;

/// The node's name unless remapped.
pub const NAME: &str = "ingest";

/// What a run did.
#[derive(Debug, Default, Clone, PartialEq, Eq)]
pub struct Summary {
    pub frames: u64,
    pub keyframes: u64,
    pub dropped: u64,
    /// Frames the camera sent that never arrived (lost in transport or in a full queue).
    pub lost: u64,
    pub visits: Vec<String>,
}

impl std::fmt::Display for Summary {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let Summary { frames, keyframes, dropped, lost, visits } = self;
        write!(
            f,
            "{frames} frames, {keyframes} keyframes, {dropped} dropped, {lost} lost before arriving, visits {visits:?}"
        )
    }
}

struct Pending {
    frame: Frame,
    /// When it was taken, ns (its stamp, or when it arrived).
    time_ns: u64,
    camera_info: CameraInfo,
}

struct Outputs {
    keyframes: Publisher<Keyframe>,
    visits: Publisher<SessionControl>,
    camera: String,
    /// Keyframes published in the visit in progress (said with its END).
    visit_keyframes: u32,
    odometry: OdometryTrack,
    /// Keyframes (with their times, ns) waiting for the odometry of their time to come.
    held: std::collections::VecDeque<(u64, Keyframe)>,
    summary: Summary,
}

/// Runs the ingest node until SIGINT or SIGTERM, then ends the visit in progress.
pub async fn run(node: &mut Node) -> Result<Summary, NodeError> {
    let session: Option<String> = node.param("session", None)?;
    let split_gap_s: Option<f64> = node.param("split_gap_s", None)?;
    let min_overlap: f64 = node.param("keyframe.min_overlap", DEFAULT_MIN_OVERLAP)?;
    let keyframes = KeyframeOptions {
        min_overlap: (min_overlap > 0.0).then_some(min_overlap),
        every_s: node.param("keyframe.every_s", None)?,
        distance_m: node.param("keyframe.distance_m", None)?,
    };
    keyframes.check().map_err(|reason| NodeError::Parameter { name: "keyframe.*".into(), reason })?;
    let bag = match node.param::<Option<PathBuf>>("bag", None)? {
        Some(path) => Some(BagInput::open(node, &path)?),
        None => None,
    };

    let images = node.subscription::<Image>("image", SENSOR_DATA)?;
    let compressed = node.subscription::<CompressedImage>("image/compressed", SENSOR_DATA)?;
    let infos = node.subscription::<CameraInfo>("camera_info", SENSOR_DATA)?;
    let odometry = node.subscription::<Odometry>("odom", SENSOR_DATA)?;
    // Latched, as `bag pack` and `synth --bag` record it: a START published before this node
    // started still arrives.
    let control =
        node.subscription::<SessionControl>("/revisit/session", LATCHED.history(History::KeepLast { depth: 10 }))?;
    let mut out = Outputs {
        keyframes: node.publisher::<Keyframe>("keyframes", WORK_QUEUE)?,
        visits: node.publisher::<SessionControl>("visits", WORK_QUEUE)?,
        camera: node.param("camera", "cam0".to_owned())?,
        visit_keyframes: 0,
        odometry: OdometryTrack::default(),
        held: Default::default(),
        summary: Summary::default(),
    };
    let mut ingest = Ingest {
        stream: VisitStream::new(session.as_deref().unwrap_or("visit"), split_gap_s, keyframes),
        driven_by_control: session.is_none(),
        early: Default::default(),
        stage: node.stage("frames"),
        last_stamp_ns: None,
    };
    let stopped = node.stopped();
    let mut stopped = std::pin::pin!(stopped);
    let (mut images, mut compressed) =
        (std::pin::pin!(images.async_stream()), std::pin::pin!(compressed.async_stream()));
    let (mut infos, mut odometry) = (std::pin::pin!(infos.async_stream()), std::pin::pin!(odometry.async_stream()));
    let mut control = std::pin::pin!(control.async_stream());
    let mut camera = Camera::default();
    if let Some(bag) = &bag {
        read_bag(node, &mut out, &mut ingest, &mut camera, bag).await?;
    }
    node.log(
        LogLevel::Info,
        &format!("ingesting {}", session.as_deref().unwrap_or("visits named by /revisit/session")),
    );
    loop {
        let input = tokio::select! {
            () = &mut stopped => break,
            Some(Ok((image, info))) = images.next() => {
                ingest.lost(&mut out, &info);
                Input::Frame(Ok(Frame::raw(image, received_ns(node))))
            }
            Some(Ok((image, info))) = compressed.next() => {
                ingest.lost(&mut out, &info);
                Input::Frame(Frame::compressed(image, received_ns(node)))
            }
            Some(Ok((info, _))) = infos.next() => Input::CameraInfo(Box::new(info)),
            Some(Ok((message, _))) = odometry.next() => Input::Odometry(Box::new(message)),
            Some(Ok((message, _))) = control.next() => Input::Control(message),
        };
        take(node, &mut out, &mut ingest, &mut camera, input).await?;
    }
    let frames = std::mem::take(&mut camera.waiting);
    offer(node, &mut out, &mut ingest, (frames, true), &camera.info).await?;
    let events = ingest.stream.end();
    publish(node, &mut out, events, ingest.last_stamp_ns).await?;
    ingest.drop_frames(&mut out, ingest.early.len());
    release(&mut out, true).await?;
    Ok(out.summary)
}

/// One input of the node, from its topics or from the bag it reads.
enum Input {
    Frame(Result<Frame, String>),
    CameraInfo(Box<CameraInfo>),
    Odometry(Box<Odometry>),
    Control(SessionControl),
}

/// The camera's calibration so far, and the frames that wait for it.
#[derive(Default)]
struct Camera {
    info: CameraInfo,
    /// Frames that came before the camera's first CameraInfo wait for it (a driver publishes
    /// both with one stamp, in either order), up to [`WAIT_FOR_INFO`] frames: a camera without
    /// CameraInfo is then taken as uncalibrated.
    waiting: Vec<Result<Frame, String>>,
}

const WAIT_FOR_INFO: usize = 5;

/// Takes one input in: frames to the visit stream, calibration, odometry, a visit's START or END.
async fn take(
    node: &Node,
    out: &mut Outputs,
    ingest: &mut Ingest,
    camera: &mut Camera,
    input: Input,
) -> Result<(), NodeError> {
    match input {
        Input::Frame(frame) => {
            camera.waiting.push(frame);
            if camera.info.k == [0.0; 9] && camera.waiting.len() <= WAIT_FOR_INFO {
                return Ok(());
            }
            let frames = std::mem::take(&mut camera.waiting);
            offer(node, out, ingest, (frames, true), &camera.info).await
        }
        Input::CameraInfo(info) => {
            camera.info = *info;
            let frames = std::mem::take(&mut camera.waiting);
            offer(node, out, ingest, (frames, true), &camera.info).await
        }
        Input::Odometry(message) => {
            let p = message.pose.pose.position;
            ingest.stream.position([p.x, p.y, p.z]);
            let stamp_ns = u64::try_from(message.header.stamp.as_nanos()).unwrap_or_default();
            out.odometry.push(stamp_ns, message.pose);
            release(out, false).await
        }
        Input::Control(message) => {
            let frames = std::mem::take(&mut camera.waiting);
            offer(node, out, ingest, (frames, true), &camera.info).await?;
            let events = match message.command {
                SessionControl::START => ingest.stream.start(&message.session),
                SessionControl::END => ingest.stream.end(),
                other => {
                    node.log(LogLevel::Warn, &format!("session control command {other} is neither START nor END"));
                    return Ok(());
                }
            };
            let start_ns = u64::try_from(message.header.stamp.as_nanos()).ok().filter(|&ns| ns > 0);
            let at_ns = if message.command == SessionControl::START { start_ns } else { None };
            publish(node, out, events, at_ns.or(ingest.last_stamp_ns)).await?;
            if message.command == SessionControl::START {
                let early = ingest.early_frames(out, message.header.stamp.as_nanos());
                offer(node, out, ingest, (early, false), &camera.info).await?;
            }
            Ok(())
        }
    }
}

/// A bag the node reads (parameter `bag`): its one image topic (or `bag_topic`), at the bag's pace
/// times `bag_rate` (0: as fast as it reads).
struct BagInput {
    bag: Bag,
    topic: String,
    rate: f64,
}

impl BagInput {
    fn open(node: &Node, path: &Path) -> Result<BagInput, NodeError> {
        let bad = |reason: String| NodeError::Parameter { name: "bag".into(), reason };
        let bag = Bag::open(path).map_err(|e| bad(e.to_string()))?;
        let topic = match node.param::<Option<String>>("bag_topic", None)? {
            Some(topic) => topic,
            None => only_image_topic(&bag).map_err(|e| bad(format!("{e} (parameter bag_topic)")))?,
        };
        let rate: f64 = node.param("bag_rate", 1.0)?;
        if !(rate.is_finite() && rate >= 0.0) {
            return Err(NodeError::Parameter { name: "bag_rate".into(), reason: format!("{rate} is not 0 or more") });
        }
        Ok(BagInput { bag, topic, rate })
    }
}

/// Takes in a bag's frames, camera info, odometry and visit markers, in the bag's order, as they
/// would come over the topics (a stop request ends it early).
async fn read_bag(
    node: &Node,
    out: &mut Outputs,
    ingest: &mut Ingest,
    camera: &mut Camera,
    input: &BagInput,
) -> Result<(), NodeError> {
    let bag_path = input.bag.path().display().to_string();
    node.log(LogLevel::Info, &format!("reading {bag_path} ({})", input.topic));
    let started = Instant::now();
    let mut first_ns = None;
    for message in input.bag.messages() {
        if node.stopping() {
            break;
        }
        let message = match message {
            Ok(message) => message,
            Err(error @ revisit_bag::BagError::BadMessage { .. }) => {
                node.log(LogLevel::Warn, &format!("skipped: {error}"));
                continue;
            }
            Err(error) => return Err(NodeError::Work(error.to_string())),
        };
        let type_name = message.topic.type_name.as_str();
        let decoded = if message.topic.name == input.topic {
            Input::Frame(frame_of(&message).map_err(|why| format!("{bag_path} at {} ns: {why}", message.log_time_ns)))
        } else if type_name == CameraInfo::DEFINITION.name {
            decode(&message).map(|info| Input::CameraInfo(Box::new(info)))?
        } else if type_name == Odometry::DEFINITION.name {
            decode(&message).map(|odometry| Input::Odometry(Box::new(odometry)))?
        } else if message.topic.name == SESSION_TOPIC {
            decode(&message).map(Input::Control)?
        } else {
            continue;
        };
        if input.rate > 0.0 {
            let first = *first_ns.get_or_insert(message.log_time_ns);
            let due = started + Duration::from_secs_f64((message.log_time_ns - first) as f64 * 1e-9 / input.rate);
            tokio::time::sleep_until(due.into()).await;
        }
        take(node, out, ingest, camera, decoded).await?;
    }
    node.log(LogLevel::Info, &format!("read {bag_path}"));
    Ok(())
}

/// A bag message decoded, or an error naming the bag, topic and time.
fn decode<M: revisit_msgs::Message>(message: &revisit_bag::RawMessage) -> Result<M, NodeError> {
    revisit_msgs::decode(&message.data)
        .map_err(|e| NodeError::Work(format!("topic {} at {} ns: {e}", message.topic.name, message.log_time_ns)))
}

/// Frames outside a visit kept, when visits are named by session control, in case their visit's
/// START is still on its way (topics are not ordered with each other).
const EARLY_FRAMES: usize = 30;

/// The visit stream and what it needs to judge frames.
struct Ingest {
    stream: VisitStream<Pending>,
    /// Frames outside a visit are dropped when visits are named by session control (after a
    /// moment in `early`).
    driven_by_control: bool,
    early: std::collections::VecDeque<Frame>,
    stage: Stage,
    last_stamp_ns: Option<u64>,
}

impl Ingest {
    /// Counts the frames the camera sent before this one that never arrived.
    fn lost(&self, out: &mut Outputs, info: &MessageInfo) {
        out.summary.lost += self.stage.sequenced(info);
    }

    fn drop_frames(&self, out: &mut Outputs, count: usize) {
        self.stage.dropped(count as u64);
        out.summary.dropped += count as u64;
    }

    /// The early frames stamped at or after a START stamped `start_ns` (none when it has no
    /// stamp); the others are dropped.
    fn early_frames(&mut self, out: &mut Outputs, start_ns: i64) -> Vec<Result<Frame, String>> {
        let early = std::mem::take(&mut self.early);
        let (kept, late): (Vec<Frame>, Vec<Frame>) = early
            .into_iter()
            .partition(|f| start_ns > 0 && f.time_ns(f.log_time_ns) >= u64::try_from(start_ns).unwrap_or(u64::MAX));
        self.drop_frames(out, late.len());
        kept.into_iter().map(Ok).collect()
    }
}

/// Offers frames to the visit stream, publishing the keyframes it keeps; `arrived`: the frames
/// have just arrived (counted as received), not kept from before their visit's START.
async fn offer(
    node: &Node,
    out: &mut Outputs,
    ingest: &mut Ingest,
    (frames, arrived): (Vec<Result<Frame, String>>, bool),
    camera_info: &CameraInfo,
) -> Result<(), NodeError> {
    if arrived {
        ingest.stage.received_many(frames.len() as u64);
        out.summary.frames += frames.len() as u64;
    }
    for frame in frames {
        let started = Instant::now();
        let frame = match frame {
            Ok(frame) if ingest.driven_by_control && ingest.stream.visit().is_none() => {
                if ingest.early.len() == EARLY_FRAMES {
                    ingest.early.pop_front();
                    ingest.drop_frames(out, 1);
                }
                ingest.early.push_back(frame);
                continue;
            }
            Ok(frame) => frame,
            Err(why) => {
                node.log(LogLevel::Warn, &format!("frame dropped: {why}"));
                ingest.drop_frames(out, 1);
                continue;
            }
        };
        let time_ns = frame.time_ns(frame.log_time_ns);
        if ingest.last_stamp_ns == Some(time_ns) {
            // The same frame delivered twice (RustDDS repeats a large fragmented sample now and
            // then): dropped.
            ingest.drop_frames(out, 1);
            continue;
        }
        ingest.last_stamp_ns = Some(time_ns);
        let image = match frame.preview(Path::new("image"), PREVIEW_WIDTH_PX) {
            Ok(image) => image,
            Err(error) => {
                node.log(LogLevel::Warn, &format!("frame dropped: {error}"));
                ingest.drop_frames(out, 1);
                continue;
            }
        };
        let pending = Pending { frame, time_ns, camera_info: camera_info.clone() };
        let events = ingest.stream.frame(pending, time_ns, &image);
        publish(node, out, events, Some(time_ns)).await?;
        ingest.stage.done(started.elapsed());
    }
    Ok(())
}

/// Publishes what the visit stream said: keyframes, and a visit's START and END stamped `at_ns`
/// (the frame or control message that caused them; the node's time when there is none: a
/// restarted node's `/clock` may not have come yet).
async fn publish(
    node: &Node,
    out: &mut Outputs,
    events: Vec<VisitEvent<Pending>>,
    at_ns: Option<u64>,
) -> Result<(), NodeError> {
    let stamp = || match at_ns {
        Some(ns) => Time::from_nanos(i64::try_from(ns).unwrap_or(i64::MAX)),
        None => node.now(),
    };
    for event in events {
        match event {
            VisitEvent::Started { visit } => {
                out.visit_keyframes = 0;
                say(node, &out.visits, stamp(), SessionControl::START, &visit, 0).await?;
                node.log(LogLevel::Info, &format!("visit {visit} started"));
                out.summary.visits.push(visit);
            }
            VisitEvent::Keyframe { visit, index, frame, .. } => {
                let Pending { frame, time_ns, camera_info } = frame;
                let stamp = frame.stamp;
                let (format, data) = match frame.image.into_file(Path::new(&visit)) {
                    Ok(file) => file,
                    Err(error) => {
                        node.log(LogLevel::Warn, &format!("keyframe {index} of {visit} dropped: {error}"));
                        continue;
                    }
                };
                let image_name = frame_file(&visit, index, format);
                let header = revisit_msgs::std_msgs::Header { stamp, frame_id: camera_info.header.frame_id.clone() };
                let image = CompressedImage {
                    header: header.clone(),
                    format: if image_name.ends_with(".png") { "png".into() } else { "jpeg".into() },
                    data,
                };
                let message = Keyframe {
                    header,
                    session: visit,
                    camera: out.camera.clone(),
                    image_name,
                    image,
                    camera_info,
                    has_prior: false,
                    prior: Default::default(),
                };
                out.held.push_back((time_ns, message));
                release(out, false).await?;
                out.summary.keyframes += 1;
                out.visit_keyframes += 1;
            }
            VisitEvent::Ended { visit, frames } => {
                release(out, true).await?;
                say(node, &out.visits, stamp(), SessionControl::END, &visit, out.visit_keyframes).await?;
                node.log(LogLevel::Info, &format!("visit {visit} ended after {frames} frames"));
            }
        }
    }
    Ok(())
}

/// Publishes the held keyframes, in order, each with the vehicle's pose at its time by odometry:
/// those whose odometry has come, or all of them (`all`: the visit ends; with the nearest pose
/// within half a second, if any). Without odometry, a keyframe goes at once, with no pose; one
/// waits for at most `HELD_KEYFRAMES` others.
async fn release(out: &mut Outputs, all: bool) -> Result<(), NodeError> {
    const HELD_KEYFRAMES: usize = 8;
    while let Some(time_ns) = out.held.front().map(|(time_ns, _)| *time_ns) {
        let ready = all || out.odometry.is_empty() || out.odometry.covers(time_ns) || out.held.len() > HELD_KEYFRAMES;
        if !ready {
            break;
        }
        let Some((_, mut message)) = out.held.pop_front() else { break };
        if let Some(pose) = out.odometry.at(time_ns) {
            (message.has_prior, message.prior) = (true, pose);
        }
        out.keyframes.async_publish(message).await.map_err(|e| NodeError::Dds(format!("{e:?}")))?;
    }
    Ok(())
}

/// Publishes a visit's START or END (with the visit's keyframe count).
async fn say(
    node: &Node,
    visits: &Publisher<SessionControl>,
    stamp: Time,
    command: u8,
    visit: &str,
    keyframes: u32,
) -> Result<(), NodeError> {
    let message = SessionControl {
        header: revisit_msgs::std_msgs::Header { stamp, frame_id: String::new() },
        command,
        session: visit.to_owned(),
        source: node.full_name(),
        keyframes,
    };
    visits.async_publish(message).await.map_err(|e| NodeError::Dds(format!("{e:?}")))
}

/// The node's time now (the bag's with `use_sim_time`), as a receive time.
fn received_ns(node: &Node) -> u64 {
    u64::try_from(node.now().as_nanos()).unwrap_or_default()
}
