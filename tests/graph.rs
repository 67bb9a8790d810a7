//! The node graph against `revisit reconstruct`, each test with its graph launched in its own domain
//! on loopback, one process per node:
//! - a synthetic 3-visit survey (mild change) played from its bags, with the bags' clock, into the
//!   graph with two matchers, every node killed (SIGKILL) once mid-replay and respawned, gives the
//!   map that `reconstruct` gives adding the same visits one at a time, stamped with the bags'
//!   time, placed on the last visit's odometry by `map -> odom` on `/tf`;
//! - an independent DDS peer (PyPI cyclonedds) publishes a visit as raw Image and CameraInfo and
//!   receives the map (once asked for on the mapper's `~/map` service before the visit ends,
//!   again when it ends), which `bag record` records as mcap-ros2-support reads it; the mapper's
//!   `~/save` service writes `reconstruct`'s outputs.

#![allow(clippy::unwrap_used, clippy::expect_used)]

mod common;

use std::collections::BTreeSet;
use std::io::{BufRead, BufReader};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::sync::OnceLock;
use std::time::{Duration, Instant};

use common::{cross_error_px, fully_registered, read_json, reconstruct, run_ok};
use revisit_msgs::nav_msgs::Odometry;
use revisit_msgs::revisit_msgs::SessionControl;
use revisit_msgs::sensor_msgs::{CompressedImage, Image};
use serde_json::{json, Value};

const VISITS: [&str; 3] = ["s1", "s2", "s3"];
/// How long a graph may take to map the survey (the tests run two graphs at once on 2 cores).
const MAP_WITHIN: Duration = Duration::from_secs(1200);

/// The synthetic survey (3 visits x 5 images, mild change, with bags), made once for every test.
fn reef() -> &'static Path {
    static REEF: OnceLock<PathBuf> = OnceLock::new();
    REEF.get_or_init(|| {
        let dir = tempfile::Builder::new().prefix("revisit-graph-").tempdir().unwrap().keep();
        let reef = dir.join("reef");
        let synth = ["synth", "--out", reef.to_str().unwrap(), "--sessions", "3", "--images-per-session", "5"];
        // Mild change: what is compared is the graph against `reconstruct`; linking through strong
        // change is `tests/cross.rs`'s.
        run_ok(&[&synth[..], &["--change", "mild", "--seed", "0", "--bag"]].concat());
        reef
    })
}

/// `reconstruct` adding the visits one at a time, as they come in; its report and options.
struct Offline {
    work: PathBuf,
    report: Value,
    /// The reconstruction's options as a file the nodes read (`options_file`).
    options: PathBuf,
}

fn offline() -> &'static Offline {
    static OFFLINE: OnceLock<Offline> = OnceLock::new();
    OFFLINE.get_or_init(|| {
        let work = reef().parent().unwrap().join("offline");
        // A matcher node searches each pair's roll (it does not see the verified pairs that
        // would predict it): so does this reconstruction.
        for k in 1..=VISITS.len() {
            reconstruct(reef(), &VISITS[..k], &work, &["--vpr-top-k", "3", "--roll-search", "probe"]);
        }
        let report = read_json(&work.join("report.json"));
        assert_eq!(report["models"], 1, "{report:#}");
        assert_eq!(fully_registered(&report), VISITS, "{report:#}");
        let options = reef().parent().unwrap().join("options.json");
        std::fs::write(&options, report["options"].to_string()).unwrap();
        Offline { work, report, options }
    })
}

fn in_domain(mut command: Command, domain: u32) -> Command {
    command.env("ROS_DOMAIN_ID", domain.to_string()).env("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST");
    command.env("RUST_LOG", format!("info,{}", revisit_node::QUIET_DDS));
    command
}

/// A launched graph, its log in a file, stopped with Ctrl-C (SIGINT) when the test ends, passed
/// or not.
struct Graph {
    launch: Child,
    log: PathBuf,
    domain: u32,
}

impl Graph {
    fn launch(dir: &Path, domain: u32, launch_file: &str) -> Graph {
        let path = dir.join(format!("graph-{domain}.yaml"));
        std::fs::write(&path, launch_file).unwrap();
        let log = dir.join(format!("launch-{domain}.log"));
        let mut command = in_domain(common::revisit(), domain);
        let stderr = std::fs::File::create(&log).unwrap();
        let launch = command.args(["launch", path.to_str().unwrap()]).stderr(stderr).spawn().unwrap();
        Graph { launch, log, domain }
    }

    fn log(&self) -> String {
        std::fs::read_to_string(&self.log).unwrap_or_default()
    }

    /// Waits until `done` holds, failing if the graph stops or `MAP_WITHIN` passes.
    fn wait_for(&mut self, what: &str, done: impl Fn(&Graph) -> bool) {
        let started = Instant::now();
        while !done(self) {
            let log = self.log();
            assert!(started.elapsed() < MAP_WITHIN, "waited {MAP_WITHIN:?} for {what}:\n{log}");
            assert!(self.launch.try_wait().unwrap().is_none(), "the graph stopped waiting for {what}:\n{log}");
            std::thread::sleep(Duration::from_millis(200));
        }
    }

    /// Plays a visit's bag into the graph (with its `/clock`), waiting for the graph's subscribers.
    fn play(&self, bag: &Path) {
        let mut play = in_domain(common::revisit(), self.domain);
        let args = ["bag", "play", bag.to_str().unwrap(), "--wait-for-subscribers", "--clock"];
        assert!(play.args(args).status().unwrap().success(), "bag play {}", bag.display());
    }

    /// The process id of node `name` now, from the launcher's "started NAME (pid N)".
    fn pid(&self, name: &str) -> Option<u32> {
        let said = format!("started {name} (pid ");
        let log = self.log();
        let line = log.lines().rev().find(|l| l.contains(&said))?;
        line.split(&said).nth(1)?.trim_end_matches(')').parse().ok()
    }

    /// Kills node `name` with SIGKILL and waits until the launcher has respawned it and its DDS
    /// endpoints have had time to match.
    fn kill(&mut self, name: &str) {
        let pid = self.pid(name).unwrap_or_else(|| panic!("no pid for {name}:\n{}", self.log()));
        assert!(Command::new("kill").args(["-KILL", &pid.to_string()]).status().unwrap().success());
        println!("killed {name} (pid {pid})");
        self.wait_for(&format!("{name} respawned"), |g| g.pid(name).is_some_and(|p| p != pid));
        std::thread::sleep(Duration::from_secs(3));
    }

    fn interrupt(&mut self) -> std::process::ExitStatus {
        let _ = Command::new("kill").args(["-INT", &self.launch.id().to_string()]).status();
        self.launch.wait().unwrap()
    }
}

impl Drop for Graph {
    fn drop(&mut self) {
        if self.launch.try_wait().is_ok_and(|status| status.is_none()) {
            self.interrupt();
        }
    }
}

/// The replay must not drop frames: the camera topics are read reliably (`bag play` and the
/// Cyclone peer publish reliably; a camera driver's best-effort topics would not match this).
const INGEST: &str = "      keyframe.min_overlap: 0.0
      qos_overrides./camera/image_raw/compressed.subscription.reliability: reliable
      qos_overrides./camera/image_raw/compressed.subscription.depth: 100
      qos_overrides./camera/image_raw.subscription.reliability: reliable
      qos_overrides./camera/image_raw.subscription.depth: 100
      qos_overrides./camera/camera_info.subscription.reliability: reliable
      qos_overrides./camera/camera_info.subscription.depth: 100
    remappings:
      image: /camera/image_raw
      image/compressed: /camera/image_raw/compressed
      camera_info: /camera/camera_info
";

/// A launch file: `parameters` for every node, then each (kind, name, extra YAML lines) with its
/// state under `state/<name>`.
fn launch_file(state: &Path, parameters: &str, nodes: &[(&str, &str, &str)], respawn: bool) -> String {
    let mut file = format!("parameters: {{{parameters}}}\nnodes:\n");
    for (kind, name, extra) in nodes {
        let state = state.join(name);
        let respawn = if respawn { "    respawn: true\n    respawn_delay_s: 0.5\n" } else { "" };
        // The mapper's state is a `reconstruct` work folder.
        let folder = if *kind == "mapper" { "work_dir" } else { "state_dir" };
        file.push_str(&format!(
            "  - node: {kind}\n    name: {name}\n{respawn}    parameters:\n      {folder}: {}\n{extra}",
            state.display()
        ));
    }
    file
}

/// The whole graph with `matchers` matchers, every node with `reconstruct`'s options and
/// respawned when it dies.
fn survey_graph(state: &Path, matchers: &[&str]) -> String {
    let parameters = format!("use_sim_time: true, onnx_threads: 1, options_file: {}", offline().options.display());
    let mut nodes = vec![("ingest", "ingest", INGEST), ("features", "features", ""), ("places", "places", "")];
    nodes.extend(matchers.iter().map(|name| ("matcher", *name, "")));
    nodes.push(("mapper", "mapper", ""));
    launch_file(state, &parameters, &nodes, true)
}

/// The graph's map is `reconstruct`'s: every visit registered as offline, the same cross-visit
/// error, every cross-visit pair from the matcher nodes.
fn assert_same_map(work: &Path) -> Value {
    let expected = &offline().report;
    let got = read_json(&work.join("report.json"));
    assert_eq!(fully_registered(&got), fully_registered(expected), "{got:#}");
    assert_eq!(got["models"], expected["models"]);
    for visit in VISITS {
        assert_eq!(got["sessions"][visit]["registered"], expected["sessions"][visit]["registered"], "{visit}");
    }
    let want = cross_error_px(reef(), &VISITS, &offline().work).expect("offline clicks scored");
    let have = cross_error_px(reef(), &VISITS, work).expect("graph clicks scored");
    println!("cross-visit error: reconstruct {want} px, graph {have} px");
    assert!((have - want).abs() <= (0.1 * want).max(0.2), "graph {have} px, reconstruct {want} px");
    assert_eq!(got["cross"]["learned_matching"]["done"], 0, "the mapper matched pairs itself: {got:#}");
    got
}

/// A node's journal lines starting with `kind` (e.g. `done`), split on tabs or spaces.
fn journal(state: &Path, node: &str, kind: &str) -> Vec<Vec<String>> {
    let text = std::fs::read_to_string(state.join(node).join("journal")).unwrap_or_default();
    text.lines()
        .map(|l| l.split(['\t', ' ']).map(str::to_owned).collect::<Vec<_>>())
        .filter(|words| words[0] == kind)
        .collect()
}

/// Starts the Cyclone DDS peer listening for `topics`; returns once it is ready.
fn listener(dir: &Path, domain: u32, topics: Value, settle_s: u64) -> (Child, PathBuf) {
    let heard = dir.join(format!("heard-{domain}.json"));
    let spec = dir.join(format!("listen-{domain}.json"));
    let spec_json = json!({"domain": domain, "timeout": MAP_WITHIN.as_secs(), "settle": settle_s, "topics": topics});
    std::fs::write(&spec, spec_json.to_string()).unwrap();
    let mut listener = revisit_testkit::interop_command("listen", &heard, &spec);
    let mut listener = listener.stdout(Stdio::piped()).spawn().unwrap();
    let mut ready = String::new();
    BufReader::new(listener.stdout.as_mut().unwrap()).read_line(&mut ready).unwrap();
    assert_eq!(ready.trim(), "ready");
    (listener, heard)
}

fn last(heard: &Value, topic: &str) -> Value {
    heard[topic].as_array().unwrap().last().unwrap_or_else(|| panic!("nothing heard on {topic}")).clone()
}

fn stamp_ns(message: &Value) -> u64 {
    let stamp = &message["header"]["stamp"];
    stamp["sec"].as_u64().unwrap() * 1_000_000_000 + stamp["nanosec"].as_u64().unwrap()
}

#[test]
fn a_survey_played_into_the_graph_maps_as_reconstruct_does_with_every_node_killed_once() {
    const DOMAIN: u32 = 55;
    let dir = tempfile::tempdir().unwrap();
    let state = dir.path().join("state");
    let matchers = ["matcher_a", "matcher_b"];
    let mut graph = Graph::launch(dir.path(), DOMAIN, &survey_graph(&state, &matchers));
    let bag = |visit: &str| reef().join("bags").join(visit);
    let described = |state: &Path| journal(state, "features", "done").len();

    // The features node mid-way through the first visit.
    graph.play(&bag("s1"));
    graph.wait_for("2 keyframes described", |_| described(&state) >= 2);
    graph.kill("features");
    // The ingest node between visits, once its first visit is described (its backlog is gone
    // with it; a live camera's frames sent while it is down are lost, as with any driver).
    graph.wait_for("s1 described", |g| described(&state) >= 5 && g.log().contains("visit s1 ended"));
    graph.kill("ingest");
    graph.play(&bag("s2"));
    graph.play(&bag("s3"));
    // The places node once it answered s2 (it must answer s3 from its index after the restart).
    graph.wait_for("s2's candidates", |_| journal(&state, "places", "answered").iter().any(|w| w[1] == "s2"));
    graph.kill("places");
    // A matcher in the middle of its pairs.
    let matched = journal(&state, "matcher_a", "done").len();
    graph.wait_for("a pair matched", |_| journal(&state, "matcher_a", "done").len() > matched);
    graph.kill("matcher_a");
    // The mapper while it maps the last visit.
    graph.wait_for("s3 mapping", |g| g.log().contains("visit s3 is complete: mapping"));
    graph.kill("mapper");
    let mapped = |state: &Path| {
        let text = std::fs::read_to_string(state.join("mapper").join("mapper.journal")).unwrap_or_default();
        text.lines().any(|l| l.contains(r#""kind":"mapped","session":"s3""#))
    };
    graph.wait_for("s3 mapped after the restart", |_| mapped(&state));

    // An independent peer, started late as Foxglove would be, gets the latched map.
    let topics = json!({
        "/map/status": {"type": "revisit_msgs/msg/MapStatus", "count": 1, "transient_local": true},
        "/map/cloud": {"type": "sensor_msgs/msg/PointCloud2", "count": 1, "transient_local": true},
        "/map/path/s1": {"type": "nav_msgs/msg/Path", "count": 1, "transient_local": true},
        "/map/path/s3": {"type": "nav_msgs/msg/Path", "count": 1, "transient_local": true},
        // Sent once a second (not latched, as TF is).
        "/tf": {"type": "tf2_msgs/msg/TFMessage", "count": 1},
        // What the ingest node said since its restart: s2's and s3's START and END.
        "/visits": {"type": "revisit_msgs/msg/SessionControl", "count": 4, "transient_local": true},
    });
    let (mut listener, heard) = listener(dir.path(), DOMAIN, topics, 3);
    let listened = listener.wait().unwrap().success();
    assert!(graph.interrupt().success(), "the graph did not stop cleanly on Ctrl-C");

    let got = assert_same_map(&state.join("mapper"));
    // The two matchers shared the pairs (`tests/matchers.rs` checks that none is done twice
    // when no matcher dies) and did every pair `reconstruct` tried.
    let done: Vec<BTreeSet<Vec<String>>> =
        matchers.iter().map(|m| journal(&state, m, "done").into_iter().collect()).collect();
    println!("pairs matched: {} by {}, {} by {}", done[0].len(), matchers[0], done[1].len(), matchers[1]);
    assert!(done.iter().all(|d| !d.is_empty()), "a matcher did no pair");
    let tried = offline().report["pairs"]["cross"]["tried"].as_u64().unwrap();
    assert_eq!(done[0].union(&done[1]).count() as u64, tried, "{got:#}");

    // What the independent peer received: the map stamped with its newest keyframe, the nodes'
    // own messages with the bags' clock (use_sim_time).
    assert!(listened, "the Cyclone DDS listener failed");
    let heard = read_json(&heard);
    let status = last(&heard, "/map/status");
    assert_eq!(status["state"], 3, "{status:#}"); // READY
    assert_eq!(status["sessions"].as_array().unwrap().len(), 3, "{status:#}");
    let cloud = last(&heard, "/map/cloud");
    let names: Vec<&str> = cloud["fields"].as_array().unwrap().iter().map(|f| f["name"].as_str().unwrap()).collect();
    assert_eq!(names, ["x", "y", "z", "rgb", "session"]);
    assert!(cloud["width"].as_u64().unwrap() > 100, "{}", cloud["width"]);
    assert_eq!(cloud["width"], status["points"]);
    let path = last(&heard, "/map/path/s1");
    assert_eq!(path["header"]["frame_id"], "map");
    assert_eq!(path["poses"].as_array().unwrap().len() as u64, got["sessions"]["s1"]["registered"].as_u64().unwrap());
    // The map placed on the newest visit's odometry: REP 105's `map -> odom` takes each of s3's
    // keyframes' odometry positions to its camera on the (metric) map, to within the odometry's
    // drift.
    let tf = &last(&heard, "/tf")["transforms"][0];
    assert_eq!((tf["header"]["frame_id"].as_str(), tf["child_frame_id"].as_str()), (Some("map"), Some("odom")));
    let (t, q) = (&tf["transform"]["translation"], &tf["transform"]["rotation"]);
    let [t, q] = [vector(t, "xyz"), vector(q, "xyzw")];
    let s3 = last(&heard, "/map/path/s3");
    let in_map: Vec<Vec<f64>> =
        s3["poses"].as_array().unwrap().iter().map(|p| vector(&p["pose"]["position"], "xyz")).collect();
    let in_odom = odometry_positions(&bag("s3"));
    assert_eq!(in_map.len(), in_odom.len());
    let mut misfit_m: Vec<f64> = in_map
        .iter()
        .zip(&in_odom)
        .map(|(m, o)| {
            distance(&m.iter().zip(rotate(&q, o)).zip(&t).map(|((m, r), t)| m - (r + t)).collect::<Vec<_>>(), &[0.0; 3])
        })
        .collect();
    misfit_m.sort_by(f64::total_cmp);
    let span_m = in_odom.iter().flat_map(|a| in_odom.iter().map(|b| distance(a, b))).fold(0.0, f64::max);
    println!("map -> odom: median misfit {:.3} m over a {span_m:.2} m track", misfit_m[misfit_m.len() / 2]);
    assert!(misfit_m[misfit_m.len() / 2] < 0.05 * span_m, "misfits {misfit_m:?} m, track {span_m} m, {tf:#}");
    let bag_time = |visit| revisit_bag::Bag::open(&bag(visit)).unwrap().info().unwrap().time_range_ns().unwrap();
    let (first, _) = bag_time("s1");
    let (_, end) = bag_time("s3");
    let visits = heard["/visits"].as_array().unwrap();
    assert_eq!(visits.len(), 4, "{visits:?}");
    let map = [("status", &status), ("cloud", &cloud), ("path", &path)];
    for (topic, message) in map.into_iter().chain(visits.iter().map(|v| ("visits", v))) {
        let stamp = stamp_ns(message);
        assert!(
            (first..=end + 1_000_000_000).contains(&stamp),
            "{topic} stamped {stamp} ns, not in the bags' time {first}..{end}"
        );
    }
}

/// The camera positions by odometry in a visit's bag, in time order.
fn odometry_positions(bag: &Path) -> Vec<[f64; 3]> {
    let mut positions = Vec::new();
    for message in revisit_bag::Bag::open(bag).unwrap().messages() {
        let message = message.unwrap();
        if message.topic.name == "/odom" {
            let p = revisit_msgs::decode::<Odometry>(&message.data).unwrap().pose.pose.position;
            positions.push([p.x, p.y, p.z]);
        }
    }
    positions
}

/// A message's fields named by `axes` (`"xyz"`, `"xyzw"`), as numbers.
fn vector(value: &Value, axes: &str) -> Vec<f64> {
    axes.chars().map(|axis| value[axis.to_string()].as_f64().unwrap()).collect()
}

/// `v` turned by the unit quaternion `q` (x, y, z, w).
fn rotate(q: &[f64], v: &[f64; 3]) -> [f64; 3] {
    let (u, w) = ([q[0], q[1], q[2]], q[3]);
    let cross =
        |a: [f64; 3], b: [f64; 3]| [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]];
    let uv = cross(u, *v);
    let uuv = cross(u, uv);
    [0, 1, 2].map(|i| v[i] + 2.0 * (w * uv[i] + uuv[i]))
}

fn distance(a: &[f64], b: &[f64]) -> f64 {
    a.iter().zip(b).map(|(a, b)| (a - b).powi(2)).sum::<f64>().sqrt()
}

/// A visit's frames as a camera driver publishes them: raw RGB Image and CameraInfo (from the
/// visit's bag), between a session START and END.
fn camera_topics(bag: &Path, visit: &str) -> Value {
    let (mut images, mut infos) = (vec![Value::Null], vec![Value::Null]);
    for message in revisit_bag::Bag::open(bag).unwrap().messages() {
        let message = message.unwrap();
        let decoded = (revisit_msgs::find(&message.topic.type_name).unwrap().decode_json)(&message.data).unwrap();
        match message.topic.name.as_str() {
            "/camera/image_raw/compressed" => {
                let compressed: CompressedImage = serde_json::from_value(decoded).unwrap();
                let rgb = image::load_from_memory(&compressed.data).unwrap().to_rgb8();
                let raw = Image {
                    header: compressed.header,
                    height: rgb.height(),
                    width: rgb.width(),
                    encoding: "rgb8".into(),
                    is_bigendian: 0,
                    step: 3 * rgb.width(),
                    data: rgb.into_raw(),
                };
                images.push(serde_json::to_value(raw).unwrap());
            }
            "/camera/camera_info" => infos.push(decoded),
            _ => {}
        }
    }
    let control = |command| SessionControl { command, session: visit.into(), ..SessionControl::default() };
    let mut session = vec![Value::Null; images.len() + 1];
    session[0] = serde_json::to_value(control(SessionControl::START)).unwrap();
    session[images.len()] = serde_json::to_value(control(SessionControl::END)).unwrap();
    json!({
        "/camera/image_raw": {"type": "sensor_msgs/msg/Image", "values": images},
        "/camera/camera_info": {"type": "sensor_msgs/msg/CameraInfo", "values": infos},
        "/revisit/session": {"type": "revisit_msgs/msg/SessionControl", "values": session, "transient_local": true},
    })
}

#[test]
fn an_independent_peer_publishes_a_visit_and_receives_the_map() {
    const DOMAIN: u32 = 56;
    let dir = tempfile::tempdir().unwrap();
    let state = dir.path().join("state");
    let nodes = [("ingest", "ingest", INGEST), ("features", "features", ""), ("mapper", "mapper", "")];
    let mut graph = Graph::launch(dir.path(), DOMAIN, &launch_file(&state, "cross: sift", &nodes, false));
    let map_topics = ["/map/status", "/map/cloud", "/map/path/peer"];
    let types = ["revisit_msgs/msg/MapStatus", "sensor_msgs/msg/PointCloud2", "nav_msgs/msg/Path"];
    // MAPPING, then READY with the map: once on the map service's call, once at the visit's END.
    let counts = [4, 2, 2];
    let topics: serde_json::Map<String, Value> = (0..3)
        .map(|i| (map_topics[i].to_owned(), json!({"type": types[i], "count": counts[i], "transient_local": true})))
        .collect();
    let (listener, heard) = listener(dir.path(), DOMAIN, Value::Object(topics), 2);
    let recorded = dir.path().join("recorded");
    let mut record = in_domain(common::revisit(), DOMAIN);
    let record_args =
        ["bag", "record", "--out", recorded.to_str().unwrap(), "--max-messages", "8", "--duration", "1200"];
    let recorder = record.args(record_args).args(map_topics).stderr(Stdio::piped()).spawn().unwrap();

    // The peer publishes the first visit's frames as a camera driver would, two a second, and
    // leaves the visit open.
    let talk = |name: &str, topics: Value| {
        let spec = dir.path().join(name);
        std::fs::write(&spec, json!({"domain": DOMAIN, "timeout": 120, "rate_hz": 2, "topics": topics}).to_string())
            .unwrap();
        revisit_testkit::interop("talk", Path::new("-"), &spec);
    };
    let mut topics = camera_topics(&reef().join("bags/s1"), "peer");
    let end = topics["/revisit/session"]["values"].as_array_mut().unwrap().pop().unwrap();
    talk("frames.json", topics);
    let frames = state.join("mapper/frames/peer");
    let kept = || std::fs::read_dir(&frames).map_or(0, |d| d.count());
    graph.wait_for("the peer's keyframes at the mapper", |_| kept() == 5);

    // Mapped on request before the visit ends, then again when it ends.
    let service = |args: &[&str]| in_domain(common::revisit(), DOMAIN).arg("service").args(args).output().unwrap();
    let mapped = service(&["map"]);
    let said = String::from_utf8_lossy(&mapped.stdout);
    assert!(mapped.status.success(), "service map: {}", String::from_utf8_lossy(&mapped.stderr));
    assert!(
        said.contains("visit peer mapped as far as it has come") && said.contains("5 of its images registered"),
        "{said}"
    );
    talk(
        "end.json",
        json!({"/revisit/session": {"type": "revisit_msgs/msg/SessionControl", "values": [end], "transient_local": true}}),
    );
    graph.wait_for("the peer's visit mapped", |g| g.log().contains("visit peer mapped and published"));

    // Saved on request as `reconstruct` writes its outputs; a folder that cannot be is named.
    let saved = dir.path().join("saved");
    let save = service(&["save", saved.to_str().unwrap()]);
    assert!(save.status.success(), "service save: {}", String::from_utf8_lossy(&save.stderr));
    let saved_report = read_json(&saved.join("report.json"));
    assert_eq!(fully_registered(&saved_report), ["peer"], "{saved_report:#}");
    let model = saved_report["chosen_model"].as_str().unwrap();
    assert!(Path::new(model).starts_with(&saved) && Path::new(model).join("images.bin").exists(), "{model}");
    let poses = std::fs::read_to_string(saved.join("poses.csv")).unwrap();
    assert_eq!(poses.lines().count(), 6, "{poses}");
    assert!(saved.join("points.ply").exists());
    let blocked = saved.join("poses.csv").join("inside");
    let refused = service(&["save", blocked.to_str().unwrap()]);
    let error = String::from_utf8_lossy(&refused.stderr);
    assert!(!refused.status.success() && error.trim().lines().count() == 1 && error.contains("poses.csv"), "{error}");
    let heard_ok = listener.wait_with_output().unwrap().status.success();
    let recorder = recorder.wait_with_output().unwrap();
    assert!(recorder.status.success(), "bag record: {}", String::from_utf8_lossy(&recorder.stderr));
    assert!(graph.interrupt().success(), "the graph did not stop cleanly on Ctrl-C");

    assert!(heard_ok, "the Cyclone DDS listener failed");
    let heard = read_json(&heard);
    let status = last(&heard, "/map/status");
    assert_eq!(status["state"], 3, "{status:#}"); // READY
    let report = read_json(&state.join("mapper/report.json"));
    assert_eq!(fully_registered(&report), ["peer"], "{report:#}");
    let path = last(&heard, "/map/path/peer");
    assert_eq!(path["poses"].as_array().unwrap().len(), 5);
    assert_eq!(last(&heard, "/map/cloud")["width"], status["points"]);
    // What `bag record` wrote reads in mcap-ros2-support and rosbags as the peer heard it.
    let expected: serde_json::Map<String, Value> = map_topics
        .iter()
        .zip(types)
        .map(|(topic, ty)| (topic.to_string(), json!({"type": ty, "values": heard[topic]})))
        .collect();
    let expected_path = dir.path().join("expected.json");
    std::fs::write(&expected_path, Value::Object(expected).to_string()).unwrap();
    revisit_testkit::interop("check", &recorded, &expected_path);
}
