//! A bag into visits: `pipeline::bags::ingest` on a bag that `pack` wrote from two folders.

#![allow(clippy::unwrap_used, clippy::expect_used)]

use revisit_pipeline::{
    bags::{self, IngestOptions, PackOptions},
    ingest::{self, SessionSpec},
    keyframes::KeyframeOptions,
    Cancel, Silent,
};
use std::path::Path;

fn folder(dir: &Path, shade: u8) -> SessionSpec {
    std::fs::create_dir_all(dir).unwrap();
    for i in 0..3u8 {
        let image = image::GrayImage::from_fn(64, 48, |x, y| {
            image::Luma([(x as u8 ^ y as u8).wrapping_mul(shade).wrapping_add(i)])
        });
        image.save(dir.join(format!("f{i}.png"))).unwrap();
    }
    SessionSpec { name: dir.file_name().unwrap().to_str().unwrap().to_owned(), dir: dir.to_owned() }
}

#[test]
fn one_bag_splits_into_visits_at_gaps_and_keeps_every_frame_exactly() {
    let work = tempfile::tempdir().unwrap();
    let specs = [folder(&work.path().join("a"), 3), folder(&work.path().join("b"), 5)];
    let scanned: Vec<_> = specs.iter().map(|s| ingest::scan_session(s).unwrap()).collect();
    let bag = work.path().join("survey");
    bags::pack(&scanned, &bag, PackOptions { rate_hz: 10.0, compressed: false }, &Silent, &Cancel::new()).unwrap();

    let options =
        IngestOptions { split_gap_s: Some(3600.0), keyframes: KeyframeOptions::ALL, ..IngestOptions::default() };
    let spec = SessionSpec { name: "reef".into(), dir: bag.clone() };
    let frames = work.path().join("frames");
    let ingested = bags::ingest(&spec, &options, &frames, &Silent, &Cancel::new()).unwrap();
    let visits: Vec<(&str, usize, usize)> =
        ingested.visits.iter().map(|v| (v.name.as_str(), v.frames, v.keyframes)).collect();
    assert_eq!(visits, vec![("reef-1", 3, 3), ("reef-2", 3, 3)]);
    assert_eq!(ingested.topic, "/camera_64x48/image_raw");
    for (visit, source) in ingested.visits.iter().zip(["a", "b"]) {
        for i in 0..3 {
            let got = image::open(visit.dir.join(format!("{}_{i:04}.png", visit.name))).unwrap().into_luma8();
            let want = image::open(work.path().join(source).join(format!("f{i}.png"))).unwrap().into_luma8();
            assert_eq!(got, want, "{} frame {i}", visit.name);
        }
    }
    // A second topic of images makes the choice the user's.
    let two = work.path().join("two");
    let mut stereo = scanned[0].clone();
    let mut other = stereo.cameras[0].clone();
    other.name = "right".into();
    stereo.cameras.push(other);
    bags::pack(&[stereo], &two, PackOptions { rate_hz: 10.0, compressed: true }, &Silent, &Cancel::new()).unwrap();
    let spec = SessionSpec { name: "stereo".into(), dir: two };
    let error =
        bags::ingest(&spec, &IngestOptions::default(), &frames, &Silent, &Cancel::new()).err().unwrap().to_string();
    assert!(error.contains("several image topics") && error.contains("--topic"), "{error}");
}
