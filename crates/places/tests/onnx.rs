//! Global descriptors from a user's ONNX model, with small models that the
//! test generates (place_test_models.py beside this file, with the project's
//! Python).

#![allow(clippy::unwrap_used, clippy::expect_used)] // test helpers panic on broken fixtures

use std::path::Path;

use image::{Rgb, RgbImage};
use revisit_core::Roll;
use revisit_onnx::{OnnxError, Runtime};
use revisit_places::{nearest, CandidateOptions, GlobalDescriptor, OnnxPlaces};
use revisit_testkit::generated_models;

fn runtime() -> Runtime {
    revisit_testkit::runtime(1)
}

/// Generates the test models into a fresh folder.
fn models() -> tempfile::TempDir {
    generated_models(&Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/place_test_models.py"))
}

/// A 640x480 image: four coloured quadrants, with a white square in the
/// top-left one so that every roll looks different.
fn quadrants() -> RgbImage {
    RgbImage::from_fn(640, 480, |x, y| {
        let base = match (x < 320, y < 240) {
            (true, true) => [200, 40, 40],
            (false, true) => [30, 180, 60],
            (true, false) => [50, 60, 190],
            (false, false) => [220, 210, 40],
        };
        if (40..120).contains(&x) && (40..120).contains(&y) {
            Rgb([255, 255, 255])
        } else {
            Rgb(base)
        }
    })
}

fn distance(a: &[f32], b: &[f32]) -> f32 {
    a.iter().zip(b).map(|(x, y)| (x - y) * (x - y)).sum::<f32>().sqrt()
}

#[test]
fn a_fixed_size_model_describes_places_at_every_roll() {
    let dir = models();
    let mut places = OnnxPlaces::open(&runtime(), &dir.path().join("grid_64.onnx")).unwrap();
    assert_eq!(places.name(), "onnx-grid_64");
    let image = quadrants();
    let at0 = places.describe(&image, Roll::R0).unwrap();
    assert_eq!(at0.len(), 48);
    let norm: f32 = at0.iter().map(|v| v * v).sum::<f32>().sqrt();
    assert!((norm - 1.0).abs() < 1e-5, "not L2-normalised: {norm}");
    assert_eq!(places.describe(&image, Roll::R0).unwrap(), at0, "not deterministic");

    // The same place seen by a camera turned a quarter: the query at the
    // right roll is the database image again, and `nearest` finds that roll.
    let turned = image::imageops::rotate90(&image);
    let other_place = RgbImage::from_pixel(640, 480, Rgb([90, 90, 90]));
    let database = [places.describe(&other_place, Roll::R0).unwrap(), at0.clone()];
    let query: Vec<(Roll, Vec<f32>)> = Roll::ALL.iter().map(|&r| (r, places.describe(&turned, r).unwrap())).collect();
    let query_views: Vec<(Roll, &[f32])> = query.iter().map(|(r, d)| (*r, d.as_slice())).collect();
    let database_views: Vec<&[f32]> = database.iter().map(Vec::as_slice).collect();
    let found = nearest(&query_views, &database_views, &CandidateOptions { top_k: 1, max_distance: Some(0.05) });
    assert_eq!(found.len(), 1, "{found:?}");
    assert_eq!(found[0].index, 1);
    assert!(found[0].distance < 1e-3, "{found:?}");
    assert_ne!(found[0].roll, Roll::R0);
    let wrong_roll = distance(&query[0].1, &database[1]);
    assert!(wrong_roll > 0.1, "rolls are indistinguishable: {wrong_roll}");
}

#[test]
fn a_dynamic_model_takes_the_image_as_it_is() {
    let dir = models();
    let mut places = OnnxPlaces::open(&runtime(), &dir.path().join("mean_dynamic.onnx")).unwrap();
    let descriptor = places.describe(&RgbImage::from_pixel(100, 60, Rgb([0, 128, 255])), Roll::R90).unwrap();
    let expected: [f32; 3] = [0.0, 128.0 / 255.0, 1.0];
    let norm = expected.iter().map(|v| v * v).sum::<f32>().sqrt();
    assert_eq!(descriptor.len(), 3);
    for (d, e) in descriptor.iter().zip(expected) {
        assert!((d - e / norm).abs() < 1e-5, "{descriptor:?}");
    }
}

#[test]
fn a_model_that_breaks_the_contract_is_named_with_its_input() {
    let dir = models();
    let path = dir.path().join("grey_input.onnx");
    let error = OnnxPlaces::open(&runtime(), &path).err().expect("a grey-input model must be refused");
    assert!(matches!(error, OnnxError::Contract { ref input, .. } if input == "grey"), "{error}");
    let message = error.to_string();
    assert!(message.contains("grey_input.onnx") && message.contains("[1, 3, H, W]"), "{message}");

    let missing = OnnxPlaces::open(&runtime(), &dir.path().join("nothing.onnx")).err().unwrap();
    assert!(matches!(missing, OnnxError::MissingModel { .. }), "{missing}");
}

#[test]
fn a_descriptor_of_the_wrong_shape_is_named_with_its_output() {
    let dir = models();
    let mut places = OnnxPlaces::open(&runtime(), &dir.path().join("two_rows.onnx")).unwrap();
    let image = RgbImage::from_pixel(64, 48, Rgb([10, 20, 30]));
    let error = places.describe(&image, Roll::R0).expect_err("a [2, 3] descriptor was accepted");
    assert!(matches!(error, OnnxError::Output { ref output, .. } if output == "descriptor"), "{error}");
    let message = error.to_string();
    assert!(message.contains("two_rows.onnx") && message.contains("[2, 3]"), "{message}");
}
