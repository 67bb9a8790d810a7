//! `revisit launch`: the graph a launch file describes starts, takes a played bag, respawns a
//! node killed with SIGKILL, and stops cleanly on Ctrl-C; the ROS 2 Python launch file parses
//! and says the same. Separate processes on loopback, in their own domain.

#![allow(clippy::unwrap_used, clippy::expect_used)]

mod common;

use std::io::{BufRead, BufReader};
use std::process::{Command, Stdio};
use std::sync::mpsc;
use std::time::Duration;

use revisit_bag::Bag;
use revisit_msgs::revisit_msgs::{Keyframe, SessionControl};

const DOMAIN: &str = "54";

fn revisit_in_domain() -> Command {
    let mut command = common::revisit();
    command.env("ROS_DOMAIN_ID", DOMAIN).env("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST");
    command.env("RUST_LOG", "info,rustdds=error,ros2_client=error");
    command
}

/// Waits until `lines` has a line containing `needle`, returning it.
fn wait_for(lines: &mpsc::Receiver<String>, needle: &str, log: &mut Vec<String>) -> String {
    loop {
        match lines.recv_timeout(Duration::from_secs(60)) {
            Ok(line) => {
                log.push(line.clone());
                if line.contains(needle) {
                    return line;
                }
            }
            Err(_) => panic!("no line with {needle:?} in 60 s:\n{}", log.join("\n")),
        }
    }
}

#[test]
fn the_launched_graph_ingests_a_played_bag_respawns_and_stops_on_ctrl_c() {
    let dir = tempfile::tempdir().unwrap();
    let reef = dir.path().join("reef");
    let reef_arg = reef.to_str().unwrap();
    common::run_ok(&["synth", "--out", reef_arg, "--sessions", "1", "--images-per-session", "6", "--change", "none"]);
    common::run_ok(&[
        "synth",
        "--out",
        reef_arg,
        "--sessions",
        "1",
        "--images-per-session",
        "6",
        "--change",
        "none",
        "--bag",
        "--bag-rate",
        "5",
    ]);

    // The whole graph of the shipped launch file, its nodes' state in the test's folder.
    let mut launch = revisit_in_domain()
        .args(["launch"])
        .arg(revisit_testkit::repo().join("launch-scripts/survey.yaml"))
        .current_dir(dir.path())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let stderr = BufReader::new(launch.stderr.take().unwrap());
    let (send, lines) = mpsc::channel();
    std::thread::spawn(move || {
        for line in stderr.lines().map_while(Result::ok) {
            let _ = send.send(line);
        }
    });
    let mut log = Vec::new();
    let started = wait_for(&lines, "started ingest (pid", &mut log);
    let pid: String = started.rsplit("pid ").next().unwrap().chars().take_while(char::is_ascii_digit).collect();
    wait_for(&lines, "ingesting", &mut log);

    let recorded = dir.path().join("recorded");
    let recorder = revisit_in_domain()
        // Long enough for the visit's END on a loaded machine (its keyframes wait for odometry):
        // about 21 s here, over 40 s once after the graph tests on a slower day.
        .args(["bag", "record", "/keyframes", "/visits", "--duration", "60", "--out"])
        .arg(&recorded)
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .spawn()
        .unwrap();
    let play = revisit_in_domain()
        .args(["bag", "play", reef.join("bags/s1").to_str().unwrap(), "--wait-for-subscribers"])
        .output()
        .unwrap();
    assert!(play.status.success(), "{}", String::from_utf8_lossy(&play.stderr));
    let recorder = recorder.wait_with_output().unwrap();
    assert!(recorder.status.success());

    // A node killed outright comes back.
    assert!(Command::new("kill").args(["-KILL", &pid]).status().unwrap().success());
    wait_for(&lines, "respawned ingest", &mut log);
    wait_for(&lines, "ingesting", &mut log);

    assert!(Command::new("kill").args(["-INT", &launch.id().to_string()]).status().unwrap().success());
    wait_for(&lines, "ingest stopped", &mut log);
    let status = launch.wait().unwrap();
    assert!(status.success(), "launch exited {status}:\n{}", log.join("\n"));

    let bag = Bag::open(&recorded).unwrap();
    let (mut names, mut said) = (Vec::new(), Vec::new());
    for message in bag.messages() {
        let message = message.unwrap();
        match message.topic.name.as_str() {
            "/keyframes" => names.push(revisit_msgs::decode::<Keyframe>(&message.data).unwrap().image_name),
            "/visits" => {
                let control: SessionControl = revisit_msgs::decode(&message.data).unwrap();
                said.push((control.command, control.session));
            }
            other => panic!("unexpected topic {other}"),
        }
    }
    assert_eq!(said, [(SessionControl::START, "s1".to_owned()), (SessionControl::END, "s1".to_owned())]);
    assert!(names.len() >= 2 && names.iter().all(|n| n.starts_with("s1_")), "{names:?}");
}

#[test]
fn launch_files_are_checked_before_anything_starts() {
    let dir = tempfile::tempdir().unwrap();
    let file = dir.path().join("bad.yaml");
    std::fs::write(&file, "nodes:\n  - node: ingest\n  - node: teleport\n").unwrap();
    let err = common::run_err(&["launch", file.to_str().unwrap()]);
    assert!(err.contains("bad.yaml: nodes[1]: no node \"teleport\""), "{err}");
    std::fs::write(&file, "nodes:\n  - node: ingest\n    remappings: {\"bad name\": x}\n").unwrap();
    let err = common::run_err(&["launch", file.to_str().unwrap()]);
    assert!(err.contains("nodes[0]"), "{err}");
}

#[test]
fn the_ros_launch_file_parses_and_matches_the_yaml() {
    let py = revisit_testkit::repo().join("launch-scripts/survey.launch.py");
    let check = Command::new(common::python())
        .args(["-c", "import ast, sys; ast.parse(open(sys.argv[1]).read(), sys.argv[1])"])
        .arg(&py)
        .output()
        .unwrap();
    assert!(check.status.success(), "{}", String::from_utf8_lossy(&check.stderr));
    let python = std::fs::read_to_string(&py).unwrap();
    let yaml: serde_json::Value = {
        let text = std::fs::read_to_string(revisit_testkit::repo().join("launch-scripts/survey.yaml")).unwrap();
        serde_yaml_ng::from_str(&text).unwrap()
    };
    for node in yaml["nodes"].as_array().unwrap() {
        let kind = node["node"].as_str().unwrap();
        assert!(python.contains(&format!("executable=\"revisit-{kind}\"")), "{kind} missing from the .py");
        for (from, to) in node["remappings"].as_object().into_iter().flatten() {
            let pair = format!("(\"{from}\", \"{}\")", to.as_str().unwrap());
            assert!(python.contains(&pair), "remapping {pair} missing from the .py");
        }
        for (name, value) in node["parameters"].as_object().unwrap() {
            assert!(python.contains(&format!("\"{name}\": {value}")), "parameter {name} missing from the .py");
        }
    }
}
