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
