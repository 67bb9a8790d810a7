//! ALIKED and XFeat on ONNX Runtime, checked against the PyTorch reference
//! outputs in ../shared/models/reference (PROVENANCE.md says how they were made).

#![allow(clippy::unwrap_used, clippy::expect_used)] // test helpers panic on broken fixtures

use std::path::Path;

use ndarray::ArrayD;
use ndarray_npy::NpzReader;
use revisit_core::{LearnedFeatures, Roll};
use revisit_features::learned::{Aliked, Planar, XFeat, XFeatOptions};
use revisit_onnx::{OnnxError, Runtime};
use revisit_testkit::shared;

fn runtime() -> Runtime {
    revisit_testkit::runtime(0)
}

fn npz(name: &str) -> NpzReader<std::fs::File> {
    NpzReader::new(std::fs::File::open(shared("models/reference").join(name)).unwrap()).unwrap()
}

fn array(reader: &mut NpzReader<std::fs::File>, key: &str) -> ArrayD<f32> {
    reader.by_name(key).unwrap()
}

fn max_abs_diff(a: &[f32], b: &[f32]) -> f32 {
    assert_eq!(a.len(), b.len());
    a.iter().zip(b).map(|(x, y)| (x - y).abs()).fold(0.0, f32::max)
}

fn pair_image(name: &str) -> image::RgbImage {
    image::open(shared("data/xfeat_pair").join(name)).unwrap().to_rgb8()
}

/// For each reference keypoint (centre convention), the index of ours at the
/// same position (ours are in the corner convention), if any.
fn same_positions(ours: &LearnedFeatures, reference: &ArrayD<f32>, tolerance_px: f32) -> Vec<Option<usize>> {
    let reference: Vec<f32> = reference.iter().copied().collect();
    let mut by_cell: std::collections::HashMap<(i64, i64), Vec<usize>> = std::collections::HashMap::new();
    for (i, p) in ours.keypoints.iter().enumerate() {
        by_cell.entry(((p[0] - 0.5).round() as i64, (p[1] - 0.5).round() as i64)).or_default().push(i);
    }
    reference
        .chunks_exact(2)
        .map(|r| {
            let key = (r[0].round() as i64, r[1].round() as i64);
            by_cell.get(&key)?.iter().copied().find(|&i| {
                let p = ours.keypoints[i];
                (p[0] - 0.5 - r[0]).abs() <= tolerance_px && (p[1] - 0.5 - r[1]).abs() <= tolerance_px
            })
        })
        .collect()
}

fn descriptor_rows_agree(ours: &LearnedFeatures, reference: &ArrayD<f32>, found: &[Option<usize>]) -> f32 {
    let dim = ours.descriptor_dim;
    let reference: Vec<f32> = reference.iter().copied().collect();
    let mut worst = 0.0f32;
    for (r, i) in found.iter().enumerate() {
        if let Some(i) = i {
            worst =
                worst.max(max_abs_diff(&ours.descriptors[i * dim..(i + 1) * dim], &reference[r * dim..(r + 1) * dim]));
        }
    }
    worst
}

#[test]
fn xfeat_backbone_reproduces_the_reference() {
    let mut reference = npz("xfeat_ref.npz");
    let x = array(&mut reference, "x");
    let (height, width) = (x.shape()[2], x.shape()[3]);
    let input = Planar { data: x.iter().copied().collect(), channels: 1, width, height };
    let mut xfeat = XFeat::open(&runtime(), &shared("models/xfeat_backbone.onnx"), XFeatOptions::default()).unwrap();
    let output = xfeat.backbone(&input).unwrap();
    for (name, ours) in [("feats", output.feats()), ("keypoints", output.keypoints()), ("heatmap", output.heatmap())] {
        let theirs = array(&mut reference, name);
        let diff = max_abs_diff(ours.as_slice().unwrap(), theirs.as_slice().unwrap());
        assert!(diff < 1e-4, "{name}: max abs difference {diff}");
    }
}

#[test]
fn xfeat_detection_and_description_reproduce_the_reference() {
    let mut reference = npz("xf_feats.npz");
    let mut xfeat = XFeat::open(&runtime(), &shared("models/xfeat_backbone.onnx"), XFeatOptions::default()).unwrap();
    for (file, k, d) in [("ref.png", "k0", "d0"), ("tgt.png", "k1", "d1")] {
        let ours = xfeat.extract(&pair_image(file), Roll::R0).unwrap();
        let keypoints = array(&mut reference, k);
        let found = same_positions(&ours, &keypoints, 1e-3);
        let matched = found.iter().flatten().count();
        assert_eq!(ours.len(), 4096, "{file}");
        assert!(matched >= 4090, "{file}: {matched} of 4096 reference keypoints found");
        let worst = descriptor_rows_agree(&ours, &array(&mut reference, d), &found);
        assert!(worst < 1e-3, "{file}: descriptors differ by up to {worst}");
    }
}

#[test]
fn aliked_reproduces_the_reference_and_its_resize() {
    let mut reference = npz("aliked_480x640_ref.npz");
    let image = array(&mut reference, "image");
    let mut aliked = Aliked::open(&runtime(), &shared("models/aliked_n16_480x640.onnx")).unwrap();
    assert_eq!(aliked.frame(), (640, 480));

    let fitted = image::imageops::resize(&pair_image("ref.png"), 640, 480, image::imageops::FilterType::Triangle);
    let ours_resized = Planar::rgb(&fitted, Roll::R0);
    let resize_diff = max_abs_diff(&ours_resized.data, image.as_slice().unwrap());
    assert!(resize_diff < 2.0 / 255.0, "resize differs by {resize_diff}");

    let input = Planar { data: image.iter().copied().collect(), channels: 3, width: 640, height: 480 };
    let ours = aliked.run(&input).unwrap();
    assert_eq!(ours.len(), 1024);
    let found = same_positions(&ours, &array(&mut reference, "keypoints"), 1e-2);
    let matched = found.iter().flatten().count();
    assert!(matched >= 1014, "{matched} of 1024 reference keypoints found");
    let worst = descriptor_rows_agree(&ours, &array(&mut reference, "descriptors"), &found);
    assert!(worst < 1e-3, "descriptors differ by up to {worst}");

    // Through the whole extractor, keypoints land in the 800x600 image's frame.
    let full = aliked.extract(&pair_image("ref.png"), Roll::R0).unwrap();
    assert_eq!((full.width, full.height), (800, 600));
    assert!(full.keypoints.iter().all(|p| p[0] > 0.0 && p[0] < 800.0 && p[1] > 0.0 && p[1] < 600.0));
}

#[test]
fn a_rolled_portrait_image_is_letterboxed_and_mapped_back() {
    let mut aliked = Aliked::open(&runtime(), &shared("models/aliked_n16_480x640.onnx")).unwrap();
    let features = aliked.extract(&pair_image("ref.png"), Roll::R90).unwrap();
    assert_eq!((features.width, features.height), (600, 800));
    assert!(features.len() > 200, "only {} keypoints on the rolled image", features.len());
    assert!(features.keypoints.iter().all(|p| p[0] < 600.0 && p[1] < 800.0));
}

#[test]
fn a_missing_or_wrong_model_is_a_clear_error() {
    let runtime = runtime();
    let missing = Path::new("/nonexistent/aliked.onnx");
    let Err(error) = Aliked::open(&runtime, missing) else { panic!("a missing model opened") };
    assert!(matches!(error, OnnxError::MissingModel { .. }) && error.to_string().contains("/nonexistent/aliked.onnx"));

    // XFeat's backbone takes one grey channel, not ALIKED's three.
    let Err(error) = Aliked::open(&runtime, &shared("models/xfeat_backbone.onnx")) else {
        panic!("XFeat's backbone was accepted as ALIKED")
    };
    assert!(matches!(error, OnnxError::Contract { .. }), "{error}");
    assert!(error.to_string().contains("xfeat_backbone.onnx") && error.to_string().contains("image"), "{error}");

    let garbage = std::env::temp_dir().join(format!("revisit-garbage-{}.onnx", std::process::id()));
    std::fs::write(&garbage, b"not a model").unwrap();
    let Err(error) = XFeat::open(&runtime, &garbage, XFeatOptions::default()) else { panic!("garbage opened") };
    std::fs::remove_file(&garbage).unwrap();
    assert!(matches!(error, OnnxError::BadModel { .. }), "{error}");
}
