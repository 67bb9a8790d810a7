//! `revisit bag` end to end, as a user runs it: the shared t265 bag (real, mcap) reads and its
//! fisheye topics export; image folders pack into a bag and export back unchanged; damaged bags
//! and wrong arguments give one-line errors.

#![allow(clippy::unwrap_used, clippy::expect_used)]

mod common;

use common::{run_err, run_ok, shared_data};
use revisit_bag::Bag;
use revisit_msgs::{revisit_msgs::SessionControl, sensor_msgs::Image};
use std::path::Path;

fn stdout(args: &[&str]) -> String {
    String::from_utf8(run_ok(args).stdout).unwrap()
}

fn one_line(stderr: &str) -> &str {
    let lines: Vec<&str> = stderr.lines().filter(|l| !l.trim().is_empty()).collect();
    assert_eq!(lines.len(), 1, "one line expected:\n{stderr}");
    lines[0]
}

#[test]
fn the_t265_bag_lists_its_topics_and_its_fisheye_topics_export_to_folders() {
    let bag = shared_data("t265_locoffice");
    let info = stdout(&["bag", "info", bag.to_str().unwrap()]);
    for (topic, typ, count) in [
        ("/camera/fisheye1/image_raw", "sensor_msgs/msg/Image", 3),
        ("/camera/fisheye2/image_raw", "sensor_msgs/msg/Image", 3),
        ("/camera/gyro/sample", "sensor_msgs/msg/Imu", 19),
        ("/camera/accel/sample", "sensor_msgs/msg/Imu", 6),
        ("/camera/odom/sample", "nav_msgs/msg/Odometry", 19),
    ] {
        let line =
            info.lines().find(|l| l.trim_start().starts_with(topic)).unwrap_or_else(|| panic!("{topic}:\n{info}"));
        assert!(line.contains(typ) && line.split_whitespace().any(|w| w == count.to_string()), "{line}");
    }
    assert!(info.contains("Messages:     50") && info.contains("Duration:     0.090"), "{info}");

    let out = tempfile::tempdir().unwrap();
    for camera in ["fisheye1", "fisheye2"] {
        let topic = format!("/camera/{camera}/image_raw");
        let dir = out.path().join(camera);
        stdout(&["bag", "export", bag.to_str().unwrap(), "--topic", &topic, "--out", dir.to_str().unwrap()]);
        // Each exported image holds the message's pixels exactly.
        let messages: Vec<Image> = Bag::open(&bag)
            .unwrap()
            .messages()
            .map(Result::unwrap)
            .filter(|m| m.topic.name == topic)
            .map(|m| revisit_msgs::decode(&m.data).unwrap())
            .collect();
        assert_eq!(messages.len(), 3);
        for (i, message) in messages.iter().enumerate() {
            let image = image::open(dir.join(format!("{i:06}.png"))).unwrap().into_luma8();
            assert_eq!((image.width(), image.height()), (848, 800));
            assert_eq!(image.as_raw(), &message.data, "{camera} frame {i}");
        }
        let stamps = std::fs::read_to_string(dir.join("timestamps.csv")).unwrap();
        assert_eq!(stamps.lines().count(), 4, "{stamps}");
    }
}

fn make_session(dir: &Path, seed: u32, jpeg: bool) {
    std::fs::create_dir_all(dir).unwrap();
    for i in 0..3 {
        let image = image::RgbImage::from_fn(64, 48, |x, y| {
            image::Rgb([(x * 4 + i * 7 + seed) as u8, (y * 5) as u8, (x ^ y) as u8])
        });
        let name = dir.join(format!("img_{i}.{}", if jpeg { "jpg" } else { "png" }));
        image.save(&name).unwrap();
    }
}

#[test]
fn image_folders_pack_into_a_bag_and_export_back_unchanged() {
    let work = tempfile::tempdir().unwrap();
    let (a, b) = (work.path().join("a"), work.path().join("b"));
    make_session(&a, 0, false);
    make_session(&b, 50, true);
    for compressed in [false, true] {
        let bag = work.path().join(if compressed { "packed_compressed" } else { "packed" });
        let mut args = vec!["bag", "pack", "--session"];
        let (sa, sb) = (format!("2024={}", a.display()), format!("2025={}", b.display()));
        args.extend([sa.as_str(), "--session", sb.as_str(), "--out", bag.to_str().unwrap(), "--rate", "5"]);
        if compressed {
            args.push("--compressed");
        }
        stdout(&args);
        assert!(bag.join("metadata.yaml").is_file());

        // Visit markers in order, around each visit's frames.
        let markers: Vec<(u8, String)> = Bag::open(&bag)
            .unwrap()
            .messages()
            .map(Result::unwrap)
            .filter(|m| m.topic.name == "/revisit/session")
            .map(|m| revisit_msgs::decode::<SessionControl>(&m.data).unwrap())
            .map(|c| (c.command, c.session))
            .collect();
        let expected_markers = [(0, "2024"), (1, "2024"), (0, "2025"), (1, "2025")];
        assert_eq!(markers, expected_markers.map(|(c, s)| (c, s.to_owned())));

        let topic = if compressed { "/camera_64x48/image_raw/compressed" } else { "/camera_64x48/image_raw" };
        let out = work.path().join(format!("export_{compressed}"));
        stdout(&["bag", "export", bag.to_str().unwrap(), "--topic", topic, "--out", out.to_str().unwrap()]);
        for (i, source) in ["a/img_0.png", "a/img_1.png", "a/img_2.png", "b/img_0.jpg", "b/img_1.jpg", "b/img_2.jpg"]
            .iter()
            .enumerate()
        {
            let source = work.path().join(source);
            let jpeg = source.extension().unwrap() == "jpg";
            let exported = out.join(format!("{i:06}.{}", if compressed && jpeg { "jpg" } else { "png" }));
            if compressed {
                assert_eq!(
                    std::fs::read(&exported).unwrap(),
                    std::fs::read(&source).unwrap(),
                    "{}",
                    exported.display()
                );
            } else {
                let (got, want) =
                    (image::open(&exported).unwrap().into_rgb8(), image::open(&source).unwrap().into_rgb8());
                assert_eq!(got, want, "{}", exported.display());
            }
        }
    }
}

#[test]
fn damaged_bags_and_wrong_arguments_are_one_line_errors() {
    let work = tempfile::tempdir().unwrap();
    let real = std::fs::read(shared_data("t265_locoffice/locoffice_ros2_mcap.mcap")).unwrap();
    let truncated = work.path().join("truncated.mcap");
    std::fs::write(&truncated, &real[..real.len() / 2]).unwrap();
    let error = run_err(&["bag", "info", truncated.to_str().unwrap()]);
    assert!(one_line(&error).contains("truncated.mcap"), "{error}");

    let not_a_bag = work.path().join("notes.txt");
    std::fs::write(&not_a_bag, "hello").unwrap();
    let error = run_err(&["bag", "info", not_a_bag.to_str().unwrap()]);
    assert!(one_line(&error).contains("notes.txt"), "{error}");

    let bag = shared_data("t265_locoffice");
    let out = work.path().join("out");
    let error = run_err(&[
        "bag",
        "export",
        bag.to_str().unwrap(),
        "--topic",
        "/camera/gyro/sample",
        "--out",
        out.to_str().unwrap(),
    ]);
    assert!(one_line(&error).contains("/camera/gyro/sample"), "{error}");

    let images = work.path().join("images");
    make_session(&images, 0, false);
    let spec = format!("a={}", images.display());
    let existing = work.path().to_str().unwrap();
    let error = run_err(&["bag", "pack", "--session", &spec, "--out", existing]);
    assert!(one_line(&error).contains(existing), "{error}");
    let fresh = work.path().join("fresh");
    let error = run_err(&["bag", "pack", "--session", &spec, "--out", fresh.to_str().unwrap(), "--rate", "0"]);
    assert!(one_line(&error).contains("--rate"), "{error}");
}

fn synth(out: &Path, extra: &[&str]) {
    let mut args = vec!["synth", "--out", out.to_str().unwrap(), "--size", "320x240", "--bag"];
    args.extend_from_slice(extra);
    run_ok(&args);
}

fn registered(work: &Path) -> Vec<(String, u64, u64)> {
    let report = common::read_json(&work.join("report.json"));
    let sessions = report["sessions"].as_object().unwrap();
    sessions
        .iter()
        .map(|(name, s)| (name.clone(), s["images"].as_u64().unwrap(), s["registered"].as_u64().unwrap()))
        .collect()
}

fn median_error_px(work: &Path, truth: &Path) -> f64 {
    let json = work.join("eval.json");
    let mut args = vec!["eval".to_owned(), "--model".into(), work.join("model").display().to_string()];
    args.push("--truth".into());
    args.push(truth.display().to_string());
    args.push("--json".into());
    args.push(json.display().to_string());
    args.push("--points".into());
    for entry in std::fs::read_dir(truth).unwrap() {
        let path = entry.unwrap().path();
        if path.file_name().unwrap().to_str().unwrap().starts_with("evaluation_points_") {
            args.push(path.display().to_string());
        }
    }
    run_ok(&args.iter().map(String::as_str).collect::<Vec<_>>());
    common::read_json(&json)["median_px"].as_f64().unwrap()
}

#[test]
fn a_synthetic_survey_reconstructs_from_bags_as_from_folders() {
    let work = tempfile::tempdir().unwrap();
    let survey = work.path().join("survey");
    synth(&survey, &["--sessions", "3", "--images-per-session", "12", "--change", "mild", "--bag-navigation"]);
    let folders = work.path().join("folders");
    let bags = work.path().join("bags");
    let mut from_folders = vec!["reconstruct", "--cross", "sift", "--out", folders.to_str().unwrap()];
    let mut from_bags = vec!["reconstruct", "--cross", "sift", "--all-frames", "--out", bags.to_str().unwrap()];
    // The navigation: a CSV per visit beside the folders, a topic in the bags.
    from_bags.extend(["--nav-topic", "/nav"]);
    let specs: Vec<[String; 3]> = ["s1", "s2", "s3"]
        .iter()
        .map(|s| {
            [
                format!("{s}={}", survey.join("sessions").join(s).display()),
                format!("{s}={}", survey.join("nav").join(format!("{s}.csv")).display()),
                format!("{s}={}", survey.join("bags").join(s).display()),
            ]
        })
        .collect();
    for [folder, nav, bag] in &specs {
        from_folders.extend(["--session", folder.as_str(), "--nav", nav.as_str()]);
        from_bags.extend(["--bag", bag.as_str()]);
    }
    run_ok(&from_folders);
    run_ok(&from_bags);
    // Each keyframe's navigation from the bag is the visit's CSV row for its image.
    for s in ["s1", "s2", "s3"] {
        let rows = |path: &Path| -> Vec<(String, [f64; 6])> {
            let mut reader = csv::Reader::from_path(path).unwrap();
            let row = |r: csv::StringRecord| (r[0].to_owned(), std::array::from_fn(|i| r[i + 1].parse().unwrap()));
            reader.records().map(|r| row(r.unwrap())).collect()
        };
        let (from_bag, from_csv) =
            (rows(&bags.join(format!("frames/{s}.nav.csv"))), rows(&survey.join(format!("nav/{s}.csv"))));
        assert_eq!(from_bag.len(), from_csv.len(), "{s}");
        for ((bag_image, bag_fix), (csv_image, csv_fix)) in from_bag.iter().zip(&from_csv) {
            assert_eq!(bag_image, csv_image);
            assert!(
                bag_fix.iter().zip(csv_fix).all(|(a, b)| (a - b).abs() < 1e-9),
                "{bag_image}: {bag_fix:?} against {csv_fix:?}"
            );
        }
    }
    for work in [&folders, &bags] {
        let report = common::read_json(&work.join("report.json"));
        assert_eq!(report["mapping"]["frame"], "navigation", "{report:#}");
        assert!(["s1", "s2", "s3"].iter().all(|s| report["sessions"][s]["navigation"] == 12), "{report:#}");
    }
    assert_eq!(registered(&bags), registered(&folders));
    assert!(registered(&bags).iter().all(|(_, images, registered)| images == registered && *images == 12));
    let truth = survey.join("truth");
    let (folder_px, bag_px) = (median_error_px(&folders, &truth), median_error_px(&bags, &truth));
    assert!((folder_px - bag_px).abs() <= 0.1, "cross-visit error {bag_px} px from bags, {folder_px} px from folders");
}

#[test]
fn keyframes_of_a_30_hz_bag_keep_a_fraction_and_every_keyframe_registers() {
    let work = tempfile::tempdir().unwrap();
    let survey = work.path().join("survey");
    // 23 steps of 10 frames: 231 frames at 30 Hz.
    synth(
        &survey,
        &[
            "--sessions",
            "1",
            "--images-per-session",
            "24",
            "--frames-per-step",
            "10",
            "--bag-rate",
            "30",
            "--eval-pairs",
            "0",
        ],
    );
    let out = work.path().join("work");
    let bag = format!("s1={}", survey.join("bags/s1").display());
    run_ok(&["reconstruct", "--cross", "none", "--bag", &bag, "--out", out.to_str().unwrap()]);
    let ingested = common::read_json(&out.join("frames/s1.ingested.json"));
    let visit = &ingested["visits"][0];
    let (frames, kept) = (visit["frames"].as_u64().unwrap(), visit["keyframes"].as_u64().unwrap());
    assert_eq!(frames, 231);
    // The default (overlap below 0.7) keeps about one frame in six here: 37 of 231.
    assert!((23..=70).contains(&kept), "{kept} of {frames} frames kept");
    assert_eq!(registered(&out), vec![("s1".to_owned(), kept, kept)]);

    // Running again reads nothing from the bag: the keyframes are stored.
    let stamp = std::fs::metadata(out.join("frames/s1.ingested.json")).unwrap().modified().unwrap();
    run_ok(&["reconstruct", "--cross", "none", "--bag", &bag, "--out", out.to_str().unwrap()]);
    assert_eq!(std::fs::metadata(out.join("frames/s1.ingested.json")).unwrap().modified().unwrap(), stamp);

    // A navigation topic that is not one, or not there: one line naming it, nothing lost.
    for (topic, says) in [
        ("/camera/camera_info", "--nav-topic /camera/camera_info is sensor_msgs/msg/CameraInfo; expected"),
        ("/usbl", "--nav-topic /usbl: no such topic in"),
    ] {
        let error = run_err(&[
            "reconstruct",
            "--cross",
            "none",
            "--bag",
            &bag,
            "--nav-topic",
            topic,
            "--out",
            out.to_str().unwrap(),
        ]);
        assert!(one_line(&error).contains(says), "{error}");
    }
    assert_eq!(registered(&out), vec![("s1".to_owned(), kept, kept)]);
    assert_eq!(std::fs::metadata(out.join("frames/s1.ingested.json")).unwrap().modified().unwrap(), stamp);
}
