//! Images in and out of rosbag2 bags: the frames of an image topic, exporting them to a folder,
//! and packing image folders into a bag. The ingest node and `revisit bag` call these.

use std::{
    fs,
    path::{Path, PathBuf},
};

use image::{DynamicImage, ImageFormat};
use nalgebra::{Point3, Vector3};
use revisit_bag::{Bag, BagError, BagWriter, QosProfile, RawMessage, WrittenBag};
use revisit_core::NavigationFix;
use revisit_msgs::{
    builtin_interfaces::Time,
    geometry_msgs::{PoseWithCovariance, PoseWithCovarianceStamped},
    nav_msgs::Odometry,
    revisit_msgs::SessionControl,
    sensor_msgs::{CameraInfo, CompressedImage, Image},
    std_msgs::Header,
    Message,
};

use serde::{Deserialize, Serialize};

use crate::{
    images,
    ingest::{SessionImages, SessionSpec},
    keyframes::{KeyframeOptions, VisitEvent, VisitStream, PREVIEW_WIDTH_PX},
    navigation::write_navigation_csv,
    odometry::OdometryTrack,
    Cancel, PipelineError, Progress,
};

/// The topic of visit markers ([`SessionControl`]) in bags Revisit writes.
pub const SESSION_TOPIC: &str = "/revisit/session";

/// One image message of a topic.
pub struct Frame {
    /// When the recorder received it, nanoseconds since the epoch.
    pub log_time_ns: u64,
    /// The header's stamp (capture time).
    pub stamp: Time,
    pub image: FrameImage,
}

/// A frame as it came: pixels (`sensor_msgs/Image`) or an image file's bytes
/// (`sensor_msgs/CompressedImage`, kept as is so that exporting never re-encodes).
pub enum FrameImage {
    Raw(Image),
    File { bytes: Vec<u8>, format: ImageFormat },
}

impl FrameImage {
    /// As an image file: compressed frames as they came, raw ones as PNG (lossless).
    pub fn into_file(self, origin: &Path) -> Result<(ImageFormat, Vec<u8>), PipelineError> {
        match self {
            FrameImage::File { bytes, format } => Ok((format, bytes)),
            FrameImage::Raw(message) => Ok((ImageFormat::Png, png(&images::from_raw(&message, origin)?, origin)?)),
        }
    }
}

impl Frame {
    /// A `sensor_msgs/Image` received at `log_time_ns`.
    pub fn raw(image: Image, log_time_ns: u64) -> Frame {
        Frame { log_time_ns, stamp: image.header.stamp, image: FrameImage::Raw(image) }
    }

    /// A `sensor_msgs/CompressedImage` received at `log_time_ns`: PNG or JPEG, else an error.
    pub fn compressed(image: CompressedImage, log_time_ns: u64) -> Result<Frame, String> {
        let format = image::guess_format(&image.data)
            .ok()
            .filter(|f| matches!(f, ImageFormat::Png | ImageFormat::Jpeg))
            .ok_or_else(|| format!("compressed image format {:?} is not jpeg or png", image.format))?;
        Ok(Frame { log_time_ns, stamp: image.header.stamp, image: FrameImage::File { bytes: image.data, format } })
    }

    /// When it was taken: the header's stamp, or the log time when the stamp is zero.
    pub fn time_ns(&self, log_time_ns: u64) -> u64 {
        stamp_or_log_ns(self.stamp, log_time_ns)
    }

    pub fn decode(&self, origin: &Path) -> Result<DynamicImage, PipelineError> {
        match &self.image {
            FrameImage::Raw(message) => images::from_raw(message, origin),
            FrameImage::File { bytes, .. } => images::decode(bytes, origin),
        }
    }

    /// A small grey copy, at least `min_width_px` wide where the frame is, for looking at every
    /// frame of a video (keyframe selection) without decoding each in full.
    pub fn preview(&self, origin: &Path, min_width_px: u32) -> Result<DynamicImage, PipelineError> {
        match &self.image {
            FrameImage::Raw(message) => Ok(images::from_raw(message, origin)?),
            FrameImage::File { bytes, .. } => {
                Ok(DynamicImage::ImageLuma8(images::preview(bytes, origin, min_width_px)?))
            }
        }
    }
}

fn bag_error(error: BagError) -> PipelineError {
    PipelineError::Bag(error.to_string())
}

/// Names a message in errors: `BAG topic TOPIC at LOG_TIME_NS`.
pub fn origin(bag: &Bag, message: &RawMessage) -> PathBuf {
    PathBuf::from(format!("{} topic {} at {} ns", bag.path().display(), message.topic.name, message.log_time_ns))
}

/// The frames of `topic`, in storage order. A message that does not decode is skipped and
/// counted in `skipped` with its error; an unreadable bag is an error.
pub fn frames<'a>(
    bag: &'a Bag,
    topic: &'a str,
    skipped: &'a mut Vec<String>,
) -> impl Iterator<Item = Result<Frame, PipelineError>> + 'a {
    bag.messages().filter_map(move |message| {
        let message = match message {
            Ok(message) if message.topic.name == topic => message,
            Ok(_) => return None,
            Err(error @ BagError::BadMessage { .. }) => {
                skipped.push(error.to_string());
                return None;
            }
            Err(error) => return Some(Err(bag_error(error))),
        };
        let frame = frame_of(&message).map_err(|why| format!("{}: {why}", origin(bag, &message).display()));
        match frame {
            Ok(frame) => Some(Ok(frame)),
            Err(why) if message.topic.type_name.ends_with("Image") => {
                skipped.push(why);
                None
            }
            Err(why) => Some(Err(PipelineError::Bag(why))),
        }
    })
}

/// A bag's image message as a frame (received at its log time).
pub fn frame_of(message: &RawMessage) -> Result<Frame, String> {
    let type_name = message.topic.type_name.as_str();
    if type_name == Image::DEFINITION.name {
        let image: Image = revisit_msgs::decode(&message.data).map_err(|e| e.to_string())?;
        return Ok(Frame::raw(image, message.log_time_ns));
    }
    if type_name == CompressedImage::DEFINITION.name {
        let image: CompressedImage = revisit_msgs::decode(&message.data).map_err(|e| e.to_string())?;
        return Frame::compressed(image, message.log_time_ns);
    }
    Err(format!("type {type_name} is not sensor_msgs/msg/Image or sensor_msgs/msg/CompressedImage"))
}

/// What [`export`] wrote.
#[derive(Debug, Default)]
pub struct Exported {
    pub images: usize,
    /// Messages that did not decode, each with its error.
    pub skipped: Vec<String>,
}

/// Writes the frames of `topic` to `out` as `NNNNNN.png` (raw images, lossless) or the
/// compressed image's own file (`.jpg`, `.png`, never re-encoded), with `timestamps.csv`
/// (`file,stamp_ns,log_time_ns`). A frame already written is not written again.
pub fn export(
    bag: &Bag,
    topic: &str,
    out: &Path,
    progress: &dyn Progress,
    cancel: &Cancel,
) -> Result<Exported, PipelineError> {
    let io = |path: &Path| {
        let path = path.to_owned();
        move |source| PipelineError::Io { path, source }
    };
    fs::create_dir_all(out).map_err(io(out))?;
    let mut exported = Exported::default();
    let mut rows = String::from("file,stamp_ns,log_time_ns\n");
    let (mut skipped, mut undecodable) = (Vec::new(), Vec::new());
    progress.start("export", 0);
    for frame in frames(bag, topic, &mut skipped) {
        cancel.check()?;
        let frame = frame?;
        let index = exported.images;
        let (file, bytes) = match &frame.image {
            FrameImage::File { bytes, format } => (format!("{index:06}.{}", extension(*format)), bytes.clone()),
            FrameImage::Raw(_) => {
                let origin = PathBuf::from(format!("{} topic {topic} frame {index}", bag.path().display()));
                match frame.decode(&origin).and_then(|image| png(&image, &origin)) {
                    Ok(png) => (format!("{index:06}.png"), png),
                    Err(error) => {
                        undecodable.push(error.to_string());
                        continue;
                    }
                }
            }
        };
        let path = out.join(&file);
        if !path.is_file() {
            write_atomically(&path, &bytes)?;
        }
        rows.push_str(&format!("{file},{},{}\n", frame.stamp.as_nanos(), frame.log_time_ns));
        exported.images += 1;
        progress.advance();
    }
    progress.finish();
    skipped.append(&mut undecodable);
    exported.skipped = skipped;
    if exported.images == 0 {
        return Err(no_frames(bag, topic));
    }
    write_atomically(&out.join("timestamps.csv"), rows.as_bytes())?;
    Ok(exported)
}

fn no_frames(bag: &Bag, topic: &str) -> PipelineError {
    let topics = bag
        .info()
        .map(|info| {
            let images: Vec<String> = info
                .topics
                .iter()
                .filter(|t| t.topic.type_name.ends_with("Image"))
                .map(|t| format!("{} ({})", t.topic.name, t.topic.type_name))
                .collect();
            if images.is_empty() {
                "none".to_owned()
            } else {
                images.join(", ")
            }
        })
        .unwrap_or_else(|e| e.to_string());
    PipelineError::Bag(format!("{}: topic {topic} has no images; image topics: {topics}", bag.path().display()))
}

/// The file extension of an image format Revisit reads.
fn extension(format: ImageFormat) -> &'static str {
    if format == ImageFormat::Jpeg {
        "jpg"
    } else {
        "png"
    }
}

/// A decoded image as a PNG file's bytes (lossless).
fn png(image: &DynamicImage, origin: &Path) -> Result<Vec<u8>, PipelineError> {
    let mut png = Vec::new();
    image
        .write_to(&mut std::io::Cursor::new(&mut png), ImageFormat::Png)
        .map_err(|e| PipelineError::BadImage { path: origin.to_owned(), reason: e.to_string() })?;
    Ok(png)
}

fn write_atomically(path: &Path, bytes: &[u8]) -> Result<(), PipelineError> {
    let partial = path.with_extension("partial");
    fs::write(&partial, bytes)
        .and_then(|()| fs::rename(&partial, path))
        .map_err(|source| PipelineError::Io { path: path.to_owned(), source })
}

/// How [`pack`] writes images.
#[derive(Debug, Clone, Copy)]
pub struct PackOptions {
    /// Frames per second of each visit's timeline.
    pub rate_hz: f64,
    /// `sensor_msgs/CompressedImage` holding each file's bytes (lossless, small) instead of
    /// decoded `sensor_msgs/Image`.
    pub compressed: bool,
}

/// Log time of the first visit's first frame (2026-01-01T00:00:00Z); visits follow a day apart.
pub const PACK_START_NS: u64 = 1_767_225_600_000_000_000;
const DAY_NS: u64 = 86_400_000_000_000;

/// The topic token of a camera name (ROS names are letters, digits and `_`, not starting with a
/// digit): `640x480` becomes `camera_640x480`.
pub fn camera_topic(camera: &str) -> String {
    let token: String = camera.chars().map(|c| if c.is_ascii_alphanumeric() { c } else { '_' }).collect();
    if token.starts_with(|c: char| c.is_ascii_alphabetic()) {
        format!("/{token}")
    } else {
        format!("/camera_{token}")
    }
}

/// Writes image folders as one bag: per visit, a [`SessionControl`] START on [`SESSION_TOPIC`],
/// each camera's frames on `/CAMERA/image_raw` (or `/CAMERA/image_raw/compressed`) with its
/// `/CAMERA/camera_info` (frame id = the camera's name; uncalibrated: zero K), then END. Visits
/// start a day apart; frames are `1 / rate_hz` apart, cameras of one instant together.
pub fn pack(
    sessions: &[SessionImages],
    out: &Path,
    options: PackOptions,
    progress: &dyn Progress,
    cancel: &Cancel,
) -> Result<WrittenBag, PipelineError> {
    if !(options.rate_hz.is_finite() && options.rate_hz > 0.0) {
        return Err(PipelineError::Bag(format!(
            "--rate {} must be a positive number of frames per second",
            options.rate_hz
        )));
    }
    let frame_ns = (1e9 / options.rate_hz).round() as u64;
    let mut writer = BagWriter::create(out).map_err(bag_error)?;
    let control = writer.add_topic::<SessionControl>(SESSION_TOPIC, QosProfile::LATCHED).map_err(bag_error)?;
    let mut camera_topics = std::collections::BTreeMap::new();
    progress.start("pack", sessions.iter().map(|s| s.len() as u64).sum());
    for (visit, session) in sessions.iter().enumerate() {
        let start_ns = PACK_START_NS + visit as u64 * DAY_NS;
        let marker = |command, time_ns| SessionControl {
            header: Header { stamp: Time::from_nanos(time_ns as i64), frame_id: String::new() },
            command,
            session: session.name.clone(),
            source: session.dir.display().to_string(),
            ..SessionControl::default()
        };
        writer.write(control, start_ns, &marker(SessionControl::START, start_ns)).map_err(bag_error)?;
        let mut last_ns = start_ns;
        let mut instant = 0u64;
        let mut previous_base = None;
        for (camera, name) in session.images() {
            cancel.check()?;
            let base = name.file().rsplit('/').next().unwrap_or_default().to_owned();
            if previous_base.as_ref().is_some_and(|b| *b != base) {
                instant += 1;
            }
            previous_base = Some(base);
            let time_ns = start_ns + (instant + 1) * frame_ns;
            last_ns = time_ns;
            let topic = camera_topic(&camera.name);
            if !camera_topics.contains_key(&topic) {
                let image = if options.compressed {
                    writer.add_raw_topic(
                        &format!("{topic}/image_raw/compressed"),
                        CompressedImage::DEFINITION,
                        QosProfile::SENSOR_DATA,
                    )
                } else {
                    writer.add_raw_topic(&format!("{topic}/image_raw"), Image::DEFINITION, QosProfile::SENSOR_DATA)
                };
                let info = writer.add_topic::<CameraInfo>(&format!("{topic}/camera_info"), QosProfile::SENSOR_DATA);
                camera_topics.insert(topic.clone(), (image.map_err(bag_error)?, info.map_err(bag_error)?));
            }
            let (image_topic, info_topic) = camera_topics[&topic];
            let header = Header { stamp: Time::from_nanos(time_ns as i64), frame_id: camera.name.clone() };
            let path = session.dir.join(name.file());
            let bytes = fs::read(&path).map_err(|source| PipelineError::Io { path: path.clone(), source })?;
            let decoded = images::decode(&bytes, &path)?;
            let data = if options.compressed {
                let format = if image::guess_format(&bytes).ok() == Some(ImageFormat::Jpeg) { "jpeg" } else { "png" };
                revisit_msgs::encode(&CompressedImage { header: header.clone(), format: format.into(), data: bytes })
            } else {
                revisit_msgs::encode(&raw_image(header.clone(), &decoded))
            }
            .map_err(|e| PipelineError::Bag(format!("{}: {e}", path.display())))?;
            writer.write_raw(image_topic, time_ns, &data).map_err(bag_error)?;
            let info = CameraInfo { header, width: decoded.width(), height: decoded.height(), ..CameraInfo::default() };
            writer.write(info_topic, time_ns, &info).map_err(bag_error)?;
            progress.advance();
        }
        writer
            .write(control, last_ns + frame_ns, &marker(SessionControl::END, last_ns + frame_ns))
            .map_err(bag_error)?;
    }
    progress.finish();
    writer.finish().map_err(bag_error)
}

/// A decoded image as `mono8` (grey sources) or `rgb8`.
pub fn raw_image(header: Header, image: &DynamicImage) -> Image {
    let (encoding, channels, data) = match image {
        DynamicImage::ImageLuma8(grey) => ("mono8", 1, grey.as_raw().clone()),
        other => ("rgb8", 3, other.to_rgb8().into_raw()),
    };
    Image {
        header,
        height: image.height(),
        width: image.width(),
        encoding: encoding.into(),
        is_bigendian: 0,
        step: image.width() * channels,
        data,
    }
}

/// How [`ingest`] turns a bag into visits.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct IngestOptions {
    /// The image topic; `None`: the bag's only image topic.
    pub topic: Option<String>,
    /// Split the bag into visits where frames are more than this many seconds apart.
    pub split_gap_s: Option<f64>,
    pub keyframes: KeyframeOptions,
    /// The vehicle's georeferenced navigation (`geometry_msgs/PoseWithCovarianceStamped` or
    /// `nav_msgs/Odometry`, one frame for every visit): each keyframe takes the position at its
    /// stamp, and its deviations from the covariance, as the visit's navigation.
    pub navigation_topic: Option<String>,
}

/// What [`ingest`] found and kept; stored beside the frames, so that running again with the same
/// bag and options reads nothing.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Ingested {
    pub bag: PathBuf,
    /// The bag's storage size: a bag rewritten in place is read again.
    pub bag_bytes: u64,
    pub options: IngestOptions,
    pub topic: String,
    /// The visits, in time order, each with its folder of keyframes.
    pub visits: Vec<IngestedVisit>,
    /// Messages of the topic that did not decode, each with its error.
    pub skipped: Vec<String>,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct IngestedVisit {
    pub name: String,
    pub dir: PathBuf,
    /// Frames of the topic in this visit, and those kept as keyframes.
    pub frames: usize,
    pub keyframes: usize,
    /// The visit's navigation CSV (`IngestOptions::navigation_topic`), when any keyframe has a
    /// position.
    #[serde(default)]
    pub navigation: Option<PathBuf>,
    /// Each keyframe's file and stamp (ns), while the bag is read.
    #[serde(skip)]
    stamps_ns: Vec<(String, u64)>,
}

impl Ingested {
    pub fn sessions(&self) -> Vec<SessionSpec> {
        self.visits.iter().map(|v| SessionSpec { name: v.name.clone(), dir: v.dir.clone() }).collect()
    }

    /// Each visit's navigation CSV, as NAME=CSV, for the visits that have one.
    pub fn navigation(&self) -> Vec<SessionSpec> {
        let with_navigation = self.visits.iter().filter_map(|v| Some((v, v.navigation.as_ref()?)));
        with_navigation.map(|(v, csv)| SessionSpec { name: v.name.clone(), dir: csv.clone() }).collect()
    }
}

/// The file of the `index`-th frame (counting every frame, kept or not) of a visit: the name
/// `revisit synth` gives its images, so that a synthetic survey's truth names a bag's keyframes.
pub fn frame_file(visit: &str, index: usize, format: ImageFormat) -> String {
    format!("{visit}_{index:04}.{}", extension(format))
}

/// Reads a visit's bag (`spec.dir` is the bag) into folders of keyframes under `out`
/// (`out/VISIT/`), one visit, or one per gap of `split_gap_s` (named `NAME-1`, `NAME-2`, ...).
/// Compressed frames are kept as their own files, raw frames written as PNG. The position for
/// keyframe selection by distance is the last `nav_msgs/Odometry` before each frame.
pub fn ingest(
    spec: &SessionSpec,
    options: &IngestOptions,
    out: &Path,
    progress: &dyn Progress,
    cancel: &Cancel,
) -> Result<Ingested, PipelineError> {
    options.keyframes.check().map_err(PipelineError::Bag)?;
    if options.split_gap_s.is_some_and(|gap| !(gap.is_finite() && gap > 0.0)) {
        return Err(PipelineError::Bag("--split-gap must be a positive number of seconds".into()));
    }
    let bag = Bag::open(&spec.dir).map_err(bag_error)?;
    let bag_path =
        fs::canonicalize(&spec.dir).map_err(|source| PipelineError::Io { path: spec.dir.clone(), source })?;
    let bag_bytes = bag.files().iter().filter_map(|f| fs::metadata(f).ok()).map(|m| m.len()).sum();
    let marker = out.join(format!("{}.ingested.json", spec.name));
    if let Ok(text) = fs::read_to_string(&marker) {
        if let Ok(done) = serde_json::from_str::<Ingested>(&text) {
            if done.bag == bag_path && done.bag_bytes == bag_bytes && done.options == *options {
                return Ok(done);
            }
        }
    }
    let topic = match &options.topic {
        Some(topic) => topic.clone(),
        None => only_image_topic(&bag)?,
    };
    if let Some(navigation) = &options.navigation_topic {
        check_navigation_topic(&bag, navigation)?;
    }
    let mut navigation = OdometryTrack::whole();

    let mut visits: Vec<IngestedVisit> = Vec::new();
    let mut stream: VisitStream<Keyframe> = VisitStream::new(&spec.name, options.split_gap_s, options.keyframes);
    let mut skipped = Vec::new();
    progress.start(&format!("keyframes {}", spec.name), 0);
    for message in bag.messages() {
        cancel.check()?;
        let message = match message {
            Ok(message) => message,
            Err(error @ BagError::BadMessage { .. }) => {
                skipped.push(error.to_string());
                continue;
            }
            Err(error) => return Err(bag_error(error)),
        };
        if Some(&message.topic.name) == options.navigation_topic.as_ref() {
            if let Some((stamp_ns, pose)) = navigation_pose(&message) {
                navigation.push(stamp_ns, pose);
            }
        }
        if message.topic.type_name == Odometry::DEFINITION.name {
            if let Ok(odometry) = revisit_msgs::decode::<Odometry>(&message.data) {
                let p = odometry.pose.pose.position;
                stream.position([p.x, p.y, p.z]);
            }
            continue;
        }
        if message.topic.name != topic {
            continue;
        }
        let origin = origin(&bag, &message);
        let decoded = frame_of(&message)
            .map_err(|why| PipelineError::Bag(format!("{}: {why}", origin.display())))
            .and_then(|frame| frame.preview(&origin, PREVIEW_WIDTH_PX).map(|image| (frame, image)));
        let (frame, image) = match decoded {
            Ok(decoded) => decoded,
            Err(error) => {
                skipped.push(error.to_string());
                continue;
            }
        };
        let time_ns = frame.time_ns(message.log_time_ns);
        let events = stream.frame(Keyframe { source: frame.image, origin, time_ns }, time_ns, &image);
        apply(events, &mut visits, out, progress)?;
    }
    apply(stream.end(), &mut visits, out, progress)?;
    progress.finish();
    if visits.is_empty() {
        return Err(no_frames(&bag, &topic));
    }
    if options.navigation_topic.is_some() {
        for visit in &mut visits {
            write_visit_navigation(visit, &navigation, out)?;
        }
    }
    let ingested = Ingested { bag: bag_path, bag_bytes, options: options.clone(), topic, visits, skipped };
    let text = serde_json::to_string_pretty(&ingested).map_err(|e| PipelineError::Bag(e.to_string()))?;
    write_atomically(&marker, text.as_bytes())?;
    Ok(ingested)
}

/// A frame waiting for the keyframe decision: the image as it came (decoded again only if kept,
/// so that a pending frame holds no pixels twice).
struct Keyframe {
    source: FrameImage,
    origin: PathBuf,
    time_ns: u64,
}

/// Carries out a visit stream's decisions: a folder per visit, a file per keyframe.
fn apply(
    events: Vec<VisitEvent<Keyframe>>,
    visits: &mut Vec<IngestedVisit>,
    out: &Path,
    progress: &dyn Progress,
) -> Result<(), PipelineError> {
    for event in events {
        match event {
            VisitEvent::Started { visit } => {
                let dir = out.join(&visit);
                fs::create_dir_all(&dir).map_err(|source| PipelineError::Io { path: dir.clone(), source })?;
                let (navigation, stamps_ns) = (None, Vec::new());
                visits.push(IngestedVisit { name: visit, dir, frames: 0, keyframes: 0, navigation, stamps_ns });
            }
            VisitEvent::Keyframe { index, frame, .. } => {
                if let Some(visit) = visits.last_mut() {
                    write_keyframe(visit, index, frame)?;
                    progress.advance();
                }
            }
            VisitEvent::Ended { frames, .. } => {
                if let Some(visit) = visits.last_mut() {
                    visit.frames = frames;
                }
            }
        }
    }
    Ok(())
}

/// Writes a kept frame into its visit's folder: compressed frames as their own file, raw ones as
/// PNG.
fn write_keyframe(visit: &mut IngestedVisit, index: usize, keyframe: Keyframe) -> Result<(), PipelineError> {
    let (format, bytes) = keyframe.source.into_file(&keyframe.origin)?;
    let file = frame_file(&visit.name, index, format);
    write_atomically(&visit.dir.join(&file), &bytes)?;
    visit.stamps_ns.push((file, keyframe.time_ns));
    visit.keyframes += 1;
    Ok(())
}

/// The navigation topic's message types: a pose with its covariance, stamped.
const NAVIGATION_TYPES: [&str; 2] = [PoseWithCovarianceStamped::DEFINITION.name, Odometry::DEFINITION.name];

/// Fails, naming the topic, unless the bag has `topic` with a navigation type.
fn check_navigation_topic(bag: &Bag, topic: &str) -> Result<(), PipelineError> {
    let info = bag.info().map_err(bag_error)?;
    match info.topics.iter().find(|t| t.topic.name == topic) {
        Some(t) if NAVIGATION_TYPES.contains(&t.topic.type_name.as_str()) => Ok(()),
        Some(t) => Err(PipelineError::Bag(format!(
            "--nav-topic {topic} is {}; expected {}",
            t.topic.type_name,
            NAVIGATION_TYPES.join(" or ")
        ))),
        None => Err(PipelineError::Bag(format!("--nav-topic {topic}: no such topic in {}", bag.path().display()))),
    }
}

/// A navigation message's stamp (the header's, else when it was recorded) and pose.
fn navigation_pose(message: &RawMessage) -> Option<(u64, PoseWithCovariance)> {
    let (header, pose) = match message.topic.type_name.as_str() {
        name if name == Odometry::DEFINITION.name => {
            let odometry = revisit_msgs::decode::<Odometry>(&message.data).ok()?;
            (odometry.header, odometry.pose)
        }
        _ => {
            let stamped = revisit_msgs::decode::<PoseWithCovarianceStamped>(&message.data).ok()?;
            (stamped.header, stamped.pose)
        }
    };
    Some((stamp_or_log_ns(header.stamp, message.log_time_ns), pose))
}

/// A message's time: its header's stamp, or when it was recorded if it has none.
fn stamp_or_log_ns(stamp: Time, log_time_ns: u64) -> u64 {
    match stamp.as_nanos() {
        0 => log_time_ns,
        stamp => u64::try_from(stamp).unwrap_or(log_time_ns),
    }
}

/// Writes `visit`'s navigation CSV beside its folder (`out/VISIT.nav.csv`): each keyframe's
/// position at its stamp, with the deviations the covariance gives (none when it is unknown,
/// all zeros in ROS). A visit no navigation reaches gets none.
fn write_visit_navigation(visit: &mut IngestedVisit, track: &OdometryTrack, out: &Path) -> Result<(), PipelineError> {
    let fixes: Vec<NavigationFix> = visit
        .stamps_ns
        .iter()
        .filter_map(|(file, stamp_ns)| {
            let pose = track.at(*stamp_ns)?;
            let p = pose.pose.position;
            let variance_m2 = Vector3::new(pose.covariance[0], pose.covariance[7], pose.covariance[14]);
            let sigma_m = variance_m2.iter().all(|v| *v > 0.0).then(|| variance_m2.map(f64::sqrt));
            Some(NavigationFix {
                image: format!("{}/{file}", visit.name),
                position_m: Point3::new(p.x, p.y, p.z),
                sigma_m,
            })
        })
        .collect();
    if fixes.is_empty() {
        return Ok(());
    }
    let path = out.join(format!("{}.nav.csv", visit.name));
    write_navigation_csv(&path, &fixes, &visit.name)?;
    visit.navigation = Some(path);
    Ok(())
}

/// The bag's image topic (`sensor_msgs/Image` or `CompressedImage`) when it has exactly one.
pub fn only_image_topic(bag: &Bag) -> Result<String, PipelineError> {
    let info = bag.info().map_err(bag_error)?;
    let images: Vec<&str> = info
        .topics
        .iter()
        .filter(|t| [Image::DEFINITION.name, CompressedImage::DEFINITION.name].contains(&t.topic.type_name.as_str()))
        .map(|t| t.topic.name.as_str())
        .collect();
    match images[..] {
        [topic] => Ok(topic.to_owned()),
        [] => Err(PipelineError::Bag(format!("{}: no image topic", bag.path().display()))),
        _ => Err(PipelineError::Bag(format!(
            "{}: several image topics ({}); choose one with --topic",
            bag.path().display(),
            images.join(", ")
        ))),
    }
}
