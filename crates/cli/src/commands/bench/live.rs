//! `revisit bench live`: the node graph under a live camera's load. A camera (this process, as a
//! driver would: best effort, `--rate-hz`) publishes a synthetic visit at `--size` for `--seconds`,
//! as CompressedImage (JPEG) and then as raw Image, into the graph's nodes (each its own process,
//! on loopback, in their own domain). Printed beside the camera's own figures: frames received,
//! dropped (as the nodes count them on `/diagnostics`) and lost before the ingest node, keyframes
//! kept, each node's sustained rate and peak resident memory, and the delay from a keyframe's
//! arrival to its registered pose on the map.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::process::{Child, Command};
use std::time::{Duration, Instant};

use anyhow::{bail, ensure, Context, Result};
use futures::StreamExt;
use revisit_bag::Bag;
use revisit_msgs::diagnostic_msgs::DiagnosticArray;
use revisit_msgs::revisit_msgs::{Keyframe, MapStatus, SessionControl};
use revisit_msgs::sensor_msgs::{CameraInfo, CompressedImage, Image};
use revisit_node::{Domain, Node, RosArgs, LATCHED, RELIABLE, SENSOR_DATA};

#[derive(clap::Args)]
pub struct Args {
    /// How long the camera publishes, seconds.
    #[arg(long, default_value_t = 60.0)]
    seconds: f64,
    /// The camera's frame rate.
    #[arg(long, default_value_t = 30.0)]
    rate_hz: f64,
    /// Image size WxH.
    #[arg(long, default_value = "1280x720")]
    size: String,
    /// Distinct views over the run (the camera moves to the next every seconds/views; each is a
    /// keyframe at the ingest node's default overlap).
    #[arg(long, default_value_t = 30)]
    views: u32,
    /// What the camera publishes: compressed (JPEG), raw (rgb8), or both one after the other.
    #[arg(long, default_value = "both", value_parser = ["compressed", "raw", "both"])]
    encoding: String,
    /// The graph's cross-visit strategy (the nodes' `cross` parameter).
    #[arg(long, default_value = "vpr")]
    cross: String,
    /// The DDS domain the benchmark's graph runs in (loopback only).
    #[arg(long, default_value_t = 91)]
    domain: u16,
    /// Working folder (the visit, the nodes' state, their logs); default a temporary one.
    #[arg(long)]
    out: Option<PathBuf>,
}

/// One node process of the graph under test.
struct Running {
    name: &'static str,
    child: Child,
    peak_rss_kib: u64,
}

impl Running {
    /// Resident memory now and at its peak (kB, from /proc).
    fn sample_memory(&mut self) {
        let status = std::fs::read_to_string(format!("/proc/{}/status", self.child.id())).unwrap_or_default();
        let field = |key: &str| {
            status.lines().find_map(|l| l.strip_prefix(key)).and_then(|v| v.split_whitespace().next()?.parse().ok())
        };
        self.peak_rss_kib = self.peak_rss_kib.max(field("VmHWM:").unwrap_or(0));
    }
}

/// What one stage of a node said last on `/diagnostics`, and when its work was last seen moving.
#[derive(Default, Clone)]
struct StageSeen {
    received: u64,
    dropped: u64,
    lost: u64,
    done: u64,
    seconds_per_item: f64,
    first_done: Option<Instant>,
    last_done: Option<Instant>,
}

/// One run's figures.
struct Figures {
    encoding: &'static str,
    published: u64,
    publish_s: f64,
    stages: BTreeMap<String, StageSeen>,
    keyframes: usize,
    registered: u32,
    delays_s: Vec<f64>,
    memory: Vec<(&'static str, u64)>,
}

pub fn run(args: Args) -> Result<()> {
    ensure!(args.seconds > 0.0 && args.rate_hz > 0.0, "--seconds and --rate-hz must be positive");
    ensure!(args.views >= 2, "--views must be at least 2");
    let (width, height) = args
        .size
        .split_once('x')
        .and_then(|(w, h)| Some((w.parse::<u32>().ok()?, h.parse::<u32>().ok()?)))
        .with_context(|| format!("--size {}: expected WxH, e.g. 1280x720", args.size))?;
    let out = match &args.out {
        Some(out) => out.clone(),
        None => std::env::temp_dir().join(format!("revisit-bench-live-{}", std::process::id())),
    };
    std::fs::create_dir_all(&out).with_context(|| format!("{}", out.display()))?;

    eprintln!("bench live: rendering {} views at {width}x{height}", args.views);
    let visit = out.join("visit");
    let exe = std::env::current_exe()?;
    let status = Command::new(&exe)
        .args(["synth", "--out", &visit.display().to_string(), "--sessions", "1", "--bag"])
        .args(["--images-per-session", &args.views.to_string(), "--size", &format!("{width}x{height}")])
        .status()?;
    ensure!(status.success(), "revisit synth failed");
    let (views, camera_info) = read_views(&visit.join("bags/s1"))?;

    let encodings: &[&'static str] = match args.encoding.as_str() {
        "both" => &["compressed", "raw"],
        "raw" => &["raw"],
        _ => &["compressed"],
    };
    let mut all = Vec::new();
    for encoding in encodings {
        all.push(run_once(&args, &out.join(encoding), encoding, &views, &camera_info)?);
    }
    print_figures(&args, width, height, &all);
    if args.out.is_none() {
        let _ = std::fs::remove_dir_all(&out);
    }
    Ok(())
}

/// The visit's distinct views (decoded) and its camera's calibration.
fn read_views(bag: &Path) -> Result<(Vec<image::RgbImage>, CameraInfo)> {
    let (mut views, mut info) = (Vec::new(), None);
    for message in Bag::open(bag)?.messages() {
        let message = message?;
        match message.topic.name.as_str() {
            "/camera/image_raw/compressed" => {
                let image: CompressedImage = revisit_msgs::decode(&message.data)?;
                views.push(image::load_from_memory(&image.data)?.to_rgb8());
            }
            "/camera/camera_info" if info.is_none() => info = Some(revisit_msgs::decode(&message.data)?),
            _ => {}
        }
    }
    Ok((views, info.context("the visit's bag has no CameraInfo")?))
}

/// The frames as the camera sends them: JPEG (quality 90, as camera drivers compress) or raw rgb8.
enum Frames {
    Compressed(Vec<Vec<u8>>),
    Raw(Vec<image::RgbImage>),
}

fn run_once(
    args: &Args,
    dir: &Path,
    encoding: &'static str,
    views: &[image::RgbImage],
    camera_info: &CameraInfo,
) -> Result<Figures> {
    if dir.exists() {
        std::fs::remove_dir_all(dir)?;
    }
    std::fs::create_dir_all(dir)?;
    let frames = match encoding {
        "raw" => Frames::Raw(views.to_vec()),
        _ => {
            let mut jpegs = Vec::new();
            for view in views {
                let mut bytes = Vec::new();
                image::codecs::jpeg::JpegEncoder::new_with_quality(&mut bytes, 90).encode_image(view)?;
                jpegs.push(bytes);
            }
            Frames::Compressed(jpegs)
        }
    };
    let mut nodes = start_graph(args, dir)?;
    let runtime = tokio::runtime::Runtime::new()?;
    let domain = Domain { id: args.domain, localhost_only: true };
    let result = runtime.block_on(async {
        let mut camera = Node::start_in(domain, "bench_camera", &RosArgs::default())?;
        let figures = drive(args, &mut camera, &frames, camera_info, &mut nodes, encoding).await;
        camera.shutdown().await;
        figures
    });
    for node in &mut nodes {
        node.sample_memory();
        let _ = Command::new("kill").args(["-INT", &node.child.id().to_string()]).status();
        let _ = node.child.wait();
    }
    let mut figures = result?;
    figures.memory = nodes.iter().map(|n| (n.name, n.peak_rss_kib)).collect();
    Ok(figures)
}

/// The graph's nodes as processes of this executable, logging to DIR/NAME.log.
fn start_graph(args: &Args, dir: &Path) -> Result<Vec<Running>> {
    let exe = std::env::current_exe()?;
    let mut nodes = Vec::new();
    for name in ["ingest", "features", "places", "matcher", "mapper"] {
        let state = dir.join(name);
        let mut ros_args = vec!["-p".to_owned(), format!("cross:={}", args.cross)];
        ros_args.extend(["-p".to_owned(), format!("state_dir:={}", state.display())]);
        ros_args.extend(["-p".to_owned(), format!("work_dir:={}", state.display())]);
        if name == "ingest" {
            ros_args.extend(
                ["-r", "image:=/camera/image_raw", "-r", "image/compressed:=/camera/image_raw/compressed"]
                    .map(String::from),
            );
            ros_args.extend(["-r", "camera_info:=/camera/camera_info"].map(String::from));
        }
        let log = std::fs::File::create(dir.join(format!("{name}.log")))?;
        let child = Command::new(&exe)
            .args(["node", name, "--ros-args"])
            .args(&ros_args)
            .env("ROS_DOMAIN_ID", args.domain.to_string())
            .env("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
            .stderr(log)
            .spawn()
            .with_context(|| format!("starting node {name}"))?;
        nodes.push(Running { name, child, peak_rss_kib: 0 });
    }
    Ok(nodes)
}

async fn drive(
    args: &Args,
    camera: &mut Node,
    frames: &Frames,
    camera_info: &CameraInfo,
    nodes: &mut [Running],
    encoding: &'static str,
) -> Result<Figures> {
    let compressed = camera.publisher::<CompressedImage>("/camera/image_raw/compressed", SENSOR_DATA)?;
    let raw = camera.publisher::<Image>("/camera/image_raw", SENSOR_DATA)?;
    let infos = camera.publisher::<CameraInfo>("/camera/camera_info", SENSOR_DATA)?;
    let control = camera.publisher::<SessionControl>("/revisit/session", LATCHED)?;
    let diagnostics = camera.subscription::<DiagnosticArray>("/diagnostics", RELIABLE)?;
    let keyframes = camera.subscription::<Keyframe>("/keyframes", RELIABLE)?;
    let status = camera.subscription::<MapStatus>("/map/status", LATCHED)?;
    let (mut diagnostics, mut keyframes) =
        (std::pin::pin!(diagnostics.async_stream()), std::pin::pin!(keyframes.async_stream()));
    let mut status = std::pin::pin!(status.async_stream());

    // The graph is up when ingest reads the camera and features and mapper read its keyframes.
    let topic = if encoding == "raw" { "/camera/image_raw" } else { "/camera/image_raw/compressed" };
    let started = Instant::now();
    while camera.readers_of(topic) == 0 || camera.readers_of("/keyframes") < 2 {
        ensure!(started.elapsed() < Duration::from_secs(120), "the graph did not come up in 120 s");
        for node in nodes.iter_mut() {
            if let Some(status) = node.child.try_wait()? {
                bail!("node {} exited ({status}) while starting", node.name);
            }
        }
        tokio::time::sleep(Duration::from_millis(200)).await;
    }
    tokio::time::sleep(Duration::from_secs(2)).await;

    let session = "live";
    let say = |command| SessionControl {
        header: camera.header(""),
        command,
        session: session.into(),
        source: "revisit bench live".into(),
        keyframes: 0,
    };
    control.async_publish(say(SessionControl::START)).await.map_err(dds)?;
    tokio::time::sleep(Duration::from_millis(500)).await;

    let total = (args.seconds * args.rate_hz).round() as u64;
    let views = match frames {
        Frames::Compressed(f) => f.len(),
        Frames::Raw(f) => f.len(),
    };
    let mut figures = Figures {
        encoding,
        published: 0,
        publish_s: 0.0,
        stages: BTreeMap::new(),
        keyframes: 0,
        registered: 0,
        delays_s: Vec::new(),
        memory: Vec::new(),
    };
    let mut arrivals: Vec<Instant> = Vec::new();
    let mut tick = tokio::time::interval(Duration::from_secs_f64(1.0 / args.rate_hz));
    tick.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Skip);
    let mut memory_tick = tokio::time::interval(Duration::from_secs(1));
    let bar = crate::progress::bar(total, &format!("camera ({encoding})"));
    let publishing = Instant::now();
    let mut mapped_at: Option<Instant> = None;
    // The visit ends a second after the last frame.
    let mut end_at: Option<tokio::time::Instant> = None;
    let mut ended = false;
    loop {
        tokio::select! {
            _ = tick.tick(), if figures.published < total => {
                let view = (figures.published as usize * views / total as usize).min(views - 1);
                let header = camera.header("camera");
                let info = CameraInfo { header: header.clone(), ..camera_info.clone() };
                match frames {
                    Frames::Compressed(jpegs) => {
                        let image = CompressedImage { header, format: "jpeg".into(), data: jpegs[view].clone() };
                        compressed.async_publish(image).await.map_err(dds)?;
                    }
                    Frames::Raw(images) => {
                        let rgb = &images[view];
                        let image = Image {
                            header,
                            height: rgb.height(),
                            width: rgb.width(),
                            encoding: "rgb8".into(),
                            is_bigendian: 0,
                            step: 3 * rgb.width(),
                            data: rgb.as_raw().clone(),
                        };
                        raw.async_publish(image).await.map_err(dds)?;
                    }
                }
                infos.async_publish(info).await.map_err(dds)?;
                figures.published += 1;
                bar.set_position(figures.published);
                if figures.published == total {
                    figures.publish_s = publishing.elapsed().as_secs_f64();
                    end_at = Some(tokio::time::Instant::now() + Duration::from_secs(1));
                }
            }
            () = tokio::time::sleep_until(end_at.unwrap_or_else(tokio::time::Instant::now)), if end_at.is_some() && !ended => {
                bar.finish_and_clear();
                control.async_publish(say(SessionControl::END)).await.map_err(dds)?;
                ended = true;
                eprintln!("bench live: camera done ({encoding}); waiting for the map");
            }
            Some(Ok((array, _))) = diagnostics.next() => {
                for status in array.status {
                    let value = |key: &str| status.values.iter().find(|v| v.key == key).map(|v| v.value.clone()).unwrap_or_default();
                    let seen = figures.stages.entry(status.name.clone()).or_default();
                    let done: u64 = value("done").parse().unwrap_or(0);
                    if done > seen.done {
                        seen.first_done.get_or_insert(Instant::now());
                        seen.last_done = Some(Instant::now());
                    }
                    seen.received = value("received").parse().unwrap_or(0);
                    seen.dropped = value("dropped").parse().unwrap_or(0);
                    seen.lost = value("lost").parse().unwrap_or(0);
                    seen.done = done;
                    seen.seconds_per_item = value("seconds_per_item").parse().unwrap_or(0.0);
                }
            }
            Some(Ok(_)) = keyframes.next() => arrivals.push(Instant::now()),
            Some(Ok((message, _))) = status.next() => {
                let registered = message.sessions.iter().find(|s| s.session == session).map_or(0, |s| s.registered);
                if message.state == MapStatus::READY && registered > figures.registered {
                    let now = Instant::now();
                    let credited = figures.delays_s.len();
                    for arrival in arrivals.iter().skip(credited).take(registered as usize - credited) {
                        figures.delays_s.push((now - *arrival).as_secs_f64());
                    }
                    figures.registered = registered;
                }
                if message.state == MapStatus::FAILED {
                    bail!("the mapper failed: {}", message.message);
                }
                if ended && message.state == MapStatus::READY {
                    mapped_at = Some(Instant::now());
                }
            }
            _ = memory_tick.tick() => {
                for node in nodes.iter_mut() {
                    node.sample_memory();
                    if let Some(status) = node.child.try_wait()? {
                        bail!("node {} exited ({status}) during the run", node.name);
                    }
                }
            }
        }
        // A few seconds after the map of the whole visit, for the last diagnostics.
        if mapped_at.is_some_and(|t| t.elapsed() > Duration::from_secs(3)) {
            break;
        }
        if ended && publishing.elapsed() > Duration::from_secs_f64(args.seconds + 3600.0) {
            bail!("no map an hour after the camera stopped");
        }
    }
    figures.keyframes = arrivals.len();
    Ok(figures)
}

fn print_figures(args: &Args, width: u32, height: u32, all: &[Figures]) {
    println!(
        "live load: a camera at {:.1} Hz, {width}x{height}, {:.0} s, {} distinct views (each a keyframe at ingest's default overlap)",
        args.rate_hz, args.seconds, args.views
    );
    for figures in all {
        let camera_hz = figures.published as f64 / figures.publish_s.max(1e-9);
        println!(
            "\n{}: camera published {} frames in {:.1} s ({camera_hz:.1} Hz)",
            figures.encoding, figures.published, figures.publish_s
        );
        println!(
            "{:<28} {:>9} {:>8} {:>6} {:>8} {:>14} {:>10} {:>13}",
            "node: stage", "received", "dropped", "lost", "done", "sustained Hz", "s/item", "peak RSS MiB"
        );
        for (name, seen) in &figures.stages {
            let span = match (seen.first_done, seen.last_done) {
                (Some(a), Some(b)) if b > a => (b - a).as_secs_f64(),
                _ => 0.0,
            };
            let sustained = if span > 0.0 { (seen.done.saturating_sub(1)) as f64 / span } else { 0.0 };
            let memory = figures
                .memory
                .iter()
                .find(|(node, _)| name.split(':').next().is_some_and(|n| n.trim_start_matches('/') == *node))
                .map_or_else(|| "-".to_owned(), |(_, kib)| format!("{:.0}", *kib as f64 / 1024.0));
            println!(
                "{name:<28} {:>9} {:>8} {:>6} {:>8} {sustained:>14.2} {:>10.3} {memory:>13}",
                seen.received, seen.dropped, seen.lost, seen.done, seen.seconds_per_item
            );
        }
        let ingest = figures.stages.iter().find(|(n, _)| n.ends_with("ingest: frames")).map(|(_, s)| s);
        let (received, lost) = ingest.map_or((0, 0), |s| (s.received, s.lost));
        println!(
            "frames lost before the ingest node: {} of {} (published - received), {lost} counted by ingest on /diagnostics",
            figures.published.saturating_sub(received),
            figures.published
        );
        println!("keyframes kept: {} (views: {})", figures.keyframes, args.views);
        let mut delays = figures.delays_s.clone();
        delays.sort_by(f64::total_cmp);
        match delays.as_slice() {
            [] => println!("keyframe -> registered pose: no keyframe registered"),
            d => println!(
                "keyframe -> registered pose: median {:.1} s, max {:.1} s ({} of {} keyframes registered; the mapper maps when the visit ends)",
                d[d.len() / 2],
                d[d.len() - 1],
                figures.registered,
                figures.keyframes
            ),
        }
    }
}

fn dds(error: impl std::fmt::Debug) -> anyhow::Error {
    anyhow::anyhow!("DDS: {error:?}")
}
