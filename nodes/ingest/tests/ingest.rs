//! The ingest node fed by a played bag keeps the same keyframes, under the same names, as the
//! offline bag ingest (`reconstruct --bag`) of that bag; visits start and end by session control.

#![allow(clippy::unwrap_used, clippy::expect_used)]

use std::time::Duration;

use futures::StreamExt;
use image::{DynamicImage, ImageFormat, RgbImage};
use revisit_bag::{Bag, BagWriter, QosProfile};
use revisit_msgs::builtin_interfaces::Time;
use revisit_msgs::revisit_msgs::{Keyframe, SessionControl};
use revisit_msgs::sensor_msgs::CompressedImage;
use revisit_msgs::std_msgs::Header;
use revisit_node::{play, Domain, Node, PlayOptions, RosArgs, WORK_QUEUE};
use revisit_pipeline::bags::{ingest, IngestOptions};
use revisit_pipeline::ingest::SessionSpec;
use revisit_pipeline::{Cancel, Silent};

const T0_NS: u64 = 1_767_225_600_000_000_000;

/// A visit "a": START, 24 PNG frames of a window sliding 9 px a frame over a noise texture
/// (10 Hz), END.
fn sliding_bag(dir: &std::path::Path) -> Bag {
    let mut state = 0x2545_f491_4f6c_dd1du64;
    let texture = RgbImage::from_fn(420, 120, |_, _| {
        state ^= state << 13;
        state ^= state >> 7;
        state ^= state << 17;
        let v = (state >> 56) as u8;
        image::Rgb([v, v / 2, 255 - v])
    });
    let texture = image::imageops::blur(&texture, 1.5);
    let mut writer = BagWriter::create(&dir.join("bag")).unwrap();
    let control = writer.add_topic::<SessionControl>("/revisit/session", QosProfile::LATCHED).unwrap();
    let frames = writer.add_topic::<CompressedImage>("/camera/image_raw/compressed", QosProfile::SENSOR_DATA).unwrap();
    let say = |command, ns: u64| SessionControl {
        header: Header { stamp: Time::from_nanos(ns as i64), frame_id: String::new() },
        command,
        session: "a".into(),
        source: "test".into(),
        ..SessionControl::default()
    };
    writer.write(control, T0_NS, &say(SessionControl::START, T0_NS)).unwrap();
    for i in 0..24u32 {
        let ns = T0_NS + 300_000_000 + u64::from(i) * 100_000_000;
        let window = image::imageops::crop_imm(&texture, i * 9, 0, 160, 120).to_image();
        let mut png = Vec::new();
        DynamicImage::ImageRgb8(window).write_to(&mut std::io::Cursor::new(&mut png), ImageFormat::Png).unwrap();
        let header = Header { stamp: Time::from_nanos(ns as i64), frame_id: "camera".into() };
        writer.write(frames, ns, &CompressedImage { header, format: "png".into(), data: png }).unwrap();
    }
    let end_ns = T0_NS + 300_000_000 + 24 * 100_000_000 + 300_000_000;
    writer.write(control, end_ns, &say(SessionControl::END, end_ns)).unwrap();
    Bag::open(&writer.finish().unwrap().dir).unwrap()
}

/// The keyframes `reconstruct --bag` keeps from `bag`, by file name.
fn offline_keyframes(dir: &std::path::Path, bag: &Bag) -> Vec<String> {
    let spec = SessionSpec { name: "a".into(), dir: bag.path().to_owned() };
    let offline = ingest(&spec, &IngestOptions::default(), &dir.join("offline"), &Silent, &Cancel::new()).unwrap();
    let mut expected: Vec<String> = std::fs::read_dir(&offline.visits[0].dir)
        .unwrap()
        .map(|e| e.unwrap().file_name().into_string().unwrap())
        .collect();
    expected.sort();
    assert!(expected.len() > 3 && expected.len() < 24, "the selection should keep some frames: {expected:?}");
    expected
}

/// Runs the ingest node (`words`: its ROS arguments) in `domain` while `feed` runs, and returns the
/// keyframe names (sorted) and visit markers it published, up to the END.
async fn ingest_node_hears(
    domain: Domain,
    words: &[String],
    feed: impl AsyncFnOnce(),
) -> (Vec<String>, Vec<(u8, String)>) {
    let mut ingest_node = Node::start_in(domain, revisit_ingest_node::NAME, &RosArgs::parse(words).unwrap()).unwrap();
    let mut listener = Node::start_in(domain, "listener", &RosArgs::default()).unwrap();
    let keyframes = listener.subscription::<Keyframe>("/keyframes", WORK_QUEUE).unwrap();
    let visits = listener.subscription::<SessionControl>("/visits", WORK_QUEUE).unwrap();
    let running = tokio::spawn(async move {
        let summary = revisit_ingest_node::run(&mut ingest_node).await;
        (ingest_node, summary)
    });
    feed().await;

    let mut names = Vec::new();
    let mut keyframes = std::pin::pin!(keyframes.async_stream());
    let mut visits = std::pin::pin!(visits.async_stream());
    let mut said = Vec::new();
    let collected = tokio::time::timeout(Duration::from_secs(30), async {
        while said.len() < 2 {
            tokio::select! {
                Some(Ok((keyframe, _))) = keyframes.next() => {
                    assert_eq!(keyframe.session, "a");
                    names.push(keyframe.image_name);
                }
                Some(Ok((control, _))) = visits.next() => said.push((control.command, control.session)),
            }
        }
        // Keyframes published before END may still be arriving.
        while let Ok(Some(Ok((keyframe, _)))) = tokio::time::timeout(Duration::from_millis(500), keyframes.next()).await
        {
            names.push(keyframe.image_name);
        }
    })
    .await;
    assert!(collected.is_ok(), "no END within 30 s; keyframes so far {names:?}, visits {said:?}");
    running.abort();
    listener.shutdown().await;
    names.sort();
    (names, said)
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn played_bag_gives_the_offline_keyframes() {
    let dir = tempfile::tempdir().unwrap();
    let bag = sliding_bag(dir.path());
    let expected = offline_keyframes(dir.path(), &bag);
    let domain = Domain { id: 43, localhost_only: true };
    let words = ["-r", "image/compressed:=/camera/image_raw/compressed"].map(String::from);
    let (names, said) = ingest_node_hears(domain, &words, async || {
        let mut player = Node::start_in(domain, "player", &RosArgs::default()).unwrap();
        let options = PlayOptions { wait_for_subscribers: true, ..Default::default() };
        play(&mut player, &bag, &options, &|_, _| {}).await.unwrap();
        player.shutdown().await;
    })
    .await;
    assert_eq!(said, [(SessionControl::START, "a".to_owned()), (SessionControl::END, "a".to_owned())]);
    assert_eq!(names, expected);
}

/// The same bag given to the node as its `bag` parameter: the same keyframes.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_bag_given_as_a_parameter_gives_the_offline_keyframes() {
    let dir = tempfile::tempdir().unwrap();
    let bag = sliding_bag(dir.path());
    let expected = offline_keyframes(dir.path(), &bag);
    let domain = Domain { id: 45, localhost_only: true };
    let words = ["-p".into(), format!("bag:={}", bag.path().display()), "-p".into(), "bag_rate:=0".into()];
    let (names, said) = ingest_node_hears(domain, &words, async || {}).await;
    assert_eq!(said, [(SessionControl::START, "a".to_owned()), (SessionControl::END, "a".to_owned())]);
    assert_eq!(names, expected);

    // A bag that is not one is named, before anything starts.
    let words = ["-p".into(), format!("bag:={}", dir.path().join("missing").display())];
    let node = Node::start_in(domain, revisit_ingest_node::NAME, &RosArgs::parse(&words).unwrap());
    let error = revisit_ingest_node::run(&mut node.unwrap()).await.unwrap_err().to_string();
    assert!(error.starts_with("parameter bag:") && error.contains("missing"), "{error}");
}

/// A frame that comes before its visit's START (topics are not ordered with each other) but is
/// stamped after it joins the visit; one stamped before it does not.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_frame_that_beats_its_start_joins_the_visit() {
    let domain = Domain { id: 44, localhost_only: true };
    let words = ["-r", "image/compressed:=/camera", "-p", "keyframe.min_overlap:=0"].map(String::from);
    let mut ingest_node = Node::start_in(domain, revisit_ingest_node::NAME, &RosArgs::parse(&words).unwrap()).unwrap();
    let mut camera = Node::start_in(domain, "camera", &RosArgs::default()).unwrap();
    let images = camera.publisher::<CompressedImage>("/camera", revisit_node::RELIABLE).unwrap();
    let control = camera.publisher::<SessionControl>("/revisit/session", revisit_node::LATCHED).unwrap();
    let keyframes = camera.subscription::<Keyframe>("/keyframes", WORK_QUEUE).unwrap();
    let running = tokio::spawn(async move {
        let summary = revisit_ingest_node::run(&mut ingest_node).await;
        (ingest_node, summary)
    });
    while camera.readers_of("/camera") == 0 || camera.readers_of("/revisit/session") == 0 {
        tokio::time::sleep(Duration::from_millis(50)).await;
    }
    tokio::time::sleep(Duration::from_millis(500)).await;
    let frame = |ns: u64| {
        let mut png = Vec::new();
        let image = DynamicImage::ImageRgb8(RgbImage::from_fn(64, 48, |x, y| image::Rgb([x as u8, y as u8, 0])));
        image.write_to(&mut std::io::Cursor::new(&mut png), ImageFormat::Png).unwrap();
        let header = Header { stamp: Time::from_nanos(ns as i64), frame_id: "camera".into() };
        CompressedImage { header, format: "png".into(), data: png }
    };
    let say = |command, ns: u64| SessionControl {
        header: Header { stamp: Time::from_nanos(ns as i64), frame_id: String::new() },
        command,
        session: "a".into(),
        ..SessionControl::default()
    };
    let pause = || tokio::time::sleep(Duration::from_millis(300));
    images.async_publish(frame(T0_NS - 1_000_000)).await.unwrap(); // before the visit
    images.async_publish(frame(T0_NS + 1_000_000)).await.unwrap(); // in it, ahead of its START
    pause().await;
    control.async_publish(say(SessionControl::START, T0_NS)).await.unwrap();
    pause().await;
    images.async_publish(frame(T0_NS + 2_000_000)).await.unwrap();
    pause().await;
    control.async_publish(say(SessionControl::END, T0_NS + 3_000_000)).await.unwrap();

    let mut keyframes = std::pin::pin!(keyframes.async_stream());
    let mut stamps = Vec::new();
    while let Ok(Some(Ok((keyframe, _)))) = tokio::time::timeout(Duration::from_secs(3), keyframes.next()).await {
        stamps.push(keyframe.header.stamp.as_nanos() as u64);
    }
    assert_eq!(stamps, [T0_NS + 1_000_000, T0_NS + 2_000_000]);
    running.abort();
    camera.shutdown().await;
}
