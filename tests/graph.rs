//! The node graph against `revisit reconstruct`: a synthetic 3-visit survey (mild change), its bags played into
//! the launched graph (ingest, features, places, matcher, mapper: one process each, on loopback, in
//! their own domain), gives the map that `reconstruct` gives adding the same visits one at a
//! time, and an independent DDS peer (PyPI cyclonedds) receives the map topics.

#![allow(clippy::unwrap_used, clippy::expect_used)]

mod common;

use std::io::{BufRead, BufReader};
use std::path::Path;
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use common::{cross_error_px, fully_registered, read_json, reconstruct, run_ok};

const DOMAIN: &str = "55";
const VISITS: [&str; 3] = ["s1", "s2", "s3"];

fn in_domain(mut command: Command) -> Command {
    command.env("ROS_DOMAIN_ID", DOMAIN).env("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST");
    command.env("RUST_LOG", "info");
    command
}

/// A launched graph, stopped with Ctrl-C (SIGINT) when the test ends, passed or not.
struct Running(std::process::Child);

impl Running {
    fn interrupt(&mut self) -> std::process::ExitStatus {
        let _ = Command::new("kill").args(["-INT", &self.0.id().to_string()]).status();
        self.0.wait().unwrap()
    }
}

impl Drop for Running {
    fn drop(&mut self) {
        if self.0.try_wait().is_ok_and(|status| status.is_none()) {
            self.interrupt();
        }
    }
}

/// The launch file of the whole graph, every node's state under `state`, every node with the
/// reconstruction's `options`.
fn launch_file(state: &Path, options: &Path) -> String {
    let options = options.display();
    let node = |kind: &str, extra: &str| {
        format!(
            "  - node: {kind}\n    parameters:\n      options_file: {options}\n      state_dir: {}/{kind}\n{extra}",
            state.display()
        )
    };
    [
        "nodes:\n".to_owned(),
        node(
            "ingest",
            // A replay must not drop frames: the camera topics are read reliably (`bag play`
            // publishes reliably; a camera driver's best-effort topics would not match this).
            "      keyframe.min_overlap: 0.0\n      qos_overrides./camera/image_raw/compressed.subscription.reliability: reliable\n      qos_overrides./camera/image_raw/compressed.subscription.depth: 100\n      qos_overrides./camera/camera_info.subscription.reliability: reliable\n      qos_overrides./camera/camera_info.subscription.depth: 100\n    remappings:\n      image/compressed: /camera/image_raw/compressed\n      camera_info: /camera/camera_info\n",
        ),
        node("features", ""),
        node("places", ""),
        node("matcher", ""),
        node("mapper", &format!("      work_dir: {}/mapper\n", state.display())),
    ]
    .concat()
}

#[test]
fn a_survey_played_into_the_graph_maps_as_reconstruct_does() {
    let dir = tempfile::tempdir().unwrap();
    let reef = dir.path().join("reef");
    let reef_arg = reef.to_str().unwrap();
    let synth = ["synth", "--out", reef_arg, "--sessions", "3", "--images-per-session", "5"];
    // Mild change: what is compared is the graph against `reconstruct`; linking through strong
    // change is `tests/cross.rs`'s.
    run_ok(&[&synth[..], &["--change", "mild", "--seed", "0", "--bag"]].concat());

    // Offline: the visits added one at a time, as they come in.
    let offline = dir.path().join("offline");
    let extra = ["--vpr-top-k", "3"];
    for k in 1..=VISITS.len() {
        reconstruct(&reef, &VISITS[..k], &offline, &extra);
    }
    let expected = read_json(&offline.join("report.json"));
    assert_eq!(expected["models"], 1, "{expected:#}");
    assert_eq!(fully_registered(&expected), VISITS, "{expected:#}");
    // The graph runs with the very options `reconstruct` used.
    let options = dir.path().join("options.json");
    std::fs::write(&options, expected["options"].to_string()).unwrap();

    let state = dir.path().join("state");
    let launch_path = dir.path().join("graph.yaml");
    std::fs::write(&launch_path, launch_file(&state, &options)).unwrap();
    let mut launch = in_domain(common::revisit());
    let log = std::fs::File::create(dir.path().join("launch.log")).unwrap();
    let mut launch = Running(launch.args(["launch", launch_path.to_str().unwrap()]).stderr(log).spawn().unwrap());
    for visit in VISITS {
        let bag = reef.join("bags").join(visit);
        let mut play = in_domain(common::revisit());
        let status = play.args(["bag", "play", bag.to_str().unwrap(), "--wait-for-subscribers"]).status().unwrap();
        assert!(status.success(), "bag play {visit}");
    }
    let started = Instant::now();
    loop {
        let log = std::fs::read_to_string(dir.path().join("launch.log")).unwrap_or_default();
        if log.contains("visit s3 mapped and published") {
            break;
        }
        assert!(started.elapsed() < Duration::from_secs(900), "the graph did not map s3 in 15 min:\n{log}");
        assert!(launch.0.try_wait().unwrap().is_none(), "the graph stopped:\n{log}");
        std::thread::sleep(Duration::from_secs(1));
    }
    // An independent peer, started late as Foxglove would be, gets the latched map.
    let listened = dir.path().join("listened.json");
    let spec = dir.path().join("listen.json");
    let topics = serde_json::json!({
        "domain": DOMAIN.parse::<u32>().unwrap(),
        "timeout": 60,
        "settle": 3,
        "topics": {
            "/map/status": {"type": "revisit_msgs/msg/MapStatus", "count": 1, "transient_local": true},
            "/map/cloud": {"type": "sensor_msgs/msg/PointCloud2", "count": 1, "transient_local": true},
            "/map/path/s1": {"type": "nav_msgs/msg/Path", "count": 1, "transient_local": true},
        }
    });
    std::fs::write(&spec, topics.to_string()).unwrap();
    let mut listener = revisit_testkit::interop_command("listen", &listened, &spec);
    let mut listener = listener.env("ROS_DOMAIN_ID", DOMAIN).stdout(Stdio::piped()).spawn().unwrap();
    let mut ready = String::new();
    BufReader::new(listener.stdout.as_mut().unwrap()).read_line(&mut ready).unwrap();
    assert_eq!(ready.trim(), "ready");

    let listened_ok = listener.wait().unwrap().success();
    assert!(launch.interrupt().success(), "the graph did not stop cleanly on Ctrl-C");

    // The same map: every visit registered as offline, the same cross-visit error.
    let graph = state.join("mapper");
    let got = read_json(&graph.join("report.json"));
    assert_eq!(fully_registered(&got), fully_registered(&expected), "{got:#}");
    assert_eq!(got["models"], expected["models"]);
    for visit in VISITS {
        assert_eq!(got["sessions"][visit]["registered"], expected["sessions"][visit]["registered"], "{visit}");
    }
    let (want, have) = (cross_error_px(&reef, &VISITS, &offline), cross_error_px(&reef, &VISITS, &graph));
    println!("cross-visit error: reconstruct {want:?} px, graph {have:?} px");
    let (want, have) = (want.expect("offline clicks scored"), have.expect("graph clicks scored"));
    assert!((have - want).abs() <= (0.1 * want).max(0.2), "graph {have} px, reconstruct {want} px");
    // Every cross-visit pair came from the matcher node: the mapper matched none itself.
    assert_eq!(got["cross"]["learned_matching"]["done"], 0, "{got:#}");

    // What the independent peer received.
    assert!(listened_ok, "the Cyclone DDS listener failed");
    let heard = read_json(&listened);
    let status = heard["/map/status"].as_array().unwrap().last().unwrap().clone();
    assert_eq!(status["state"], 3, "{status:#}"); // READY
    assert_eq!(status["sessions"].as_array().unwrap().len(), 3, "{status:#}");
    let cloud = heard["/map/cloud"].as_array().unwrap().last().unwrap().clone();
    let names: Vec<&str> = cloud["fields"].as_array().unwrap().iter().map(|f| f["name"].as_str().unwrap()).collect();
    assert_eq!(names, ["x", "y", "z", "rgb", "session"]);
    assert!(cloud["width"].as_u64().unwrap() > 100, "{}", cloud["width"]);
    assert_eq!(cloud["width"], status["points"]);
    let path = heard["/map/path/s1"].as_array().unwrap().last().unwrap().clone();
    assert_eq!(path["header"]["frame_id"], "map");
    assert_eq!(path["poses"].as_array().unwrap().len() as u64, got["sessions"]["s1"]["registered"].as_u64().unwrap());
}
