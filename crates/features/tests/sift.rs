//! SIFT at its boundary: images in, keypoints and descriptors out, checked
//! against what a user would verify by hand.

#![allow(clippy::unwrap_used, clippy::expect_used)] // test helpers panic on broken fixtures

use std::f32::consts::{FRAC_PI_2, TAU};
use std::path::Path;

use image::GrayImage;
use revisit_core::Features;
use revisit_features::{extract_sift, FeatureError, Normalization, SiftOptions};

const SUBVO: &str = "../../../shared/data/subvo/images";

fn subvo_frame(name: &str) -> Option<GrayImage> {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join(SUBVO).join(name);
    assert!(path.exists(), "{} is missing: the tests need ../shared beside the checkout", path.display());
    Some(image::open(&path).expect("decodable subvo frame").to_luma8())
}

/// A bright Gaussian blob of `sigma_px` centred on pixel (cx, cy) on a dark,
/// faintly textured background.
fn blob_image(width: u32, height: u32, cx: f32, cy: f32, sigma_px: f32) -> GrayImage {
    GrayImage::from_fn(width, height, |x, y| {
        let (dx, dy) = (x as f32 - cx, y as f32 - cy);
        let blob = 200.0 * (-(dx * dx + dy * dy) / (2.0 * sigma_px * sigma_px)).exp();
        image::Luma([(20.0 + blob).round() as u8])
    })
}

/// The image turned 90 degrees clockwise: pixel (x, y) goes to (h - 1 - y, x).
fn rotate_clockwise(image: &GrayImage) -> GrayImage {
    let (w, h) = image.dimensions();
    GrayImage::from_fn(h, w, |x, y| *image.get_pixel(y, h - 1 - x))
}

fn angle_difference(a: f32, b: f32) -> f32 {
    let d = (a - b).rem_euclid(TAU);
    d.min(TAU - d)
}

fn descriptor_distance(a: &[u8], b: &[u8]) -> f32 {
    a.iter().zip(b).map(|(&p, &q)| (f32::from(p) - f32::from(q)).powi(2)).sum::<f32>().sqrt()
}

#[test]
fn blob_gives_a_keypoint_at_its_centre_with_its_sigma() {
    let sigma_px = 4.0;
    let image = blob_image(96, 80, 41.0, 37.0, sigma_px);
    let features = extract_sift(&SiftOptions::default(), &image).unwrap();
    let strongest = features.keypoints.first().expect("the blob is detected");
    // Pixel (41, 37) has its centre at (41.5, 37.5) in COLMAP's convention.
    assert!((strongest.x - 41.5).abs() < 0.2 && (strongest.y - 37.5).abs() < 0.2, "{strongest:?}");
    assert!(
        (strongest.scale / sigma_px - 1.0).abs() < 0.25,
        "scale {} for a blob of sigma {sigma_px}",
        strongest.scale
    );
}

#[test]
fn first_octave_zero_finds_the_blob_too() {
    let image = blob_image(96, 80, 50.0, 30.0, 5.0);
    let options = SiftOptions { first_octave: 0, ..Default::default() };
    let features = extract_sift(&options, &image).unwrap();
    let strongest = features.keypoints.first().expect("the blob is detected");
    assert!((strongest.x - 50.5).abs() < 0.3 && (strongest.y - 30.5).abs() < 0.3, "{strongest:?}");
    assert!((strongest.scale / 5.0 - 1.0).abs() < 0.25, "{strongest:?}");
}

#[test]
fn rotating_the_image_rotates_keypoints_and_keeps_descriptors() {
    let Some(frame) = subvo_frame("frame_00_00_31.000.jpg") else {
        return;
    };
    // 2^k + 1 pixels a side: every octave's decimation commutes with the turn.
    let crop = image::imageops::crop_imm(&frame, 500, 250, 257, 257).to_image();
    let turned = rotate_clockwise(&crop);
    let options = SiftOptions { max_num_features: 4000, ..Default::default() };
    let original = extract_sift(&options, &crop).unwrap();
    let rotated = extract_sift(&options, &turned).unwrap();
    assert!(original.len() > 200, "only {} keypoints on a textured crop", original.len());
    let h = crop.height() as f32;
    let strongest = 200;
    let mut found = 0;
    for (i, kp) in original.keypoints.iter().take(strongest).enumerate() {
        // Corner convention: (x, y) -> (h - y, x); orientation + 90 degrees.
        let (x, y) = (h - kp.y, kp.x);
        let twin = rotated.keypoints.iter().enumerate().find(|(_, r)| {
            (r.x - x).abs() < 0.05
                && (r.y - y).abs() < 0.05
                && (r.scale / kp.scale - 1.0).abs() < 0.01
                && angle_difference(r.orientation, kp.orientation + FRAC_PI_2) < 0.05
        });
        if let Some((j, _)) = twin {
            let distance = descriptor_distance(original.descriptor(i).unwrap(), rotated.descriptor(j).unwrap());
            assert!(distance < 0.05 * 512.0, "keypoint {i}: descriptor distance {distance}");
            found += 1;
        }
    }
    assert!(found >= strongest * 9 / 10, "{found} of the {strongest} strongest keypoints survive a 90 degree turn");
}

#[test]
fn extraction_is_deterministic() {
    let Some(frame) = subvo_frame("frame_00_00_21.000.jpg") else {
        return;
    };
    let crop = image::imageops::crop_imm(&frame, 300, 200, 400, 300).to_image();
    let options = SiftOptions { max_num_features: 500, ..Default::default() };
    let a = extract_sift(&options, &crop).unwrap();
    let b = extract_sift(&options, &crop).unwrap();
    assert_eq!(a.len(), 500);
    assert_eq!(a, b);
    // Strongest first is part of the contract.
    let scales_ok = a.keypoints.iter().all(|k| k.scale > 0.5 && k.orientation >= 0.0 && k.orientation < TAU);
    assert!(scales_ok);
}

#[test]
fn ignore_regions_drop_keypoints_before_the_cap() {
    let Some(frame) = subvo_frame("frame_00_00_21.000.jpg") else {
        return;
    };
    let crop = image::imageops::crop_imm(&frame, 0, 0, 480, 320).to_image();
    let region = [0, 0, 240, 160];
    let all = extract_sift(&SiftOptions { max_num_features: 100_000, ..Default::default() }, &crop).unwrap();
    let inside = |f: &Features| f.keypoints.iter().filter(|k| k.x < region[2] as f32 && k.y < region[3] as f32).count();
    assert!(inside(&all) > 20, "the test needs keypoints in the region, got {}", inside(&all));
    let outside: Vec<_> =
        all.keypoints.iter().filter(|k| k.x >= region[2] as f32 || k.y >= region[3] as f32).copied().collect();
    let cap = outside.len() * 3 / 4;
    let options = SiftOptions { max_num_features: cap, ignore_regions_px: vec![region], ..Default::default() };
    let kept = extract_sift(&options, &crop).unwrap();
    assert_eq!(inside(&kept), 0);
    // The cap is filled by the strongest keypoints outside the region.
    assert_eq!(kept.keypoints, outside[..cap]);
}

#[test]
fn descriptor_bytes_are_scaled_like_colmap() {
    let Some(frame) = subvo_frame("frame_00_00_25.000.jpg") else {
        return;
    };
    let crop = image::imageops::crop_imm(&frame, 600, 300, 300, 200).to_image();
    let mut by_normalization = Vec::new();
    for normalization in [Normalization::L1Root, Normalization::L2] {
        let options = SiftOptions { max_num_features: 200, normalization, ..Default::default() };
        let features = extract_sift(&options, &crop).unwrap();
        assert_eq!(features.len(), 200);
        assert_eq!(features.descriptor_dim, 128);
        assert_eq!(features.descriptors.len(), 128 * features.len());
        for descriptor in features.descriptors.chunks_exact(128) {
            // Unit L2 norm times 512, rounded per entry.
            let norm = descriptor.iter().map(|&b| f32::from(b).powi(2)).sum::<f32>().sqrt();
            assert!((norm - 512.0).abs() < 12.0, "{normalization:?}: byte norm {norm}");
        }
        by_normalization.push(features);
    }
    // RootSIFT is the square root of the L1-normalised clamped SIFT vector.
    let (root, l2) = (&by_normalization[0], &by_normalization[1]);
    assert_eq!(root.keypoints, l2.keypoints);
    for (r, s) in root.descriptors.chunks_exact(128).zip(l2.descriptors.chunks_exact(128)) {
        let sum: f32 = s.iter().map(|&b| f32::from(b)).sum();
        for (&rb, &sb) in r.iter().zip(s) {
            let expected = 512.0 * (f32::from(sb) / sum).sqrt();
            assert!((f32::from(rb) - expected).abs() < 8.0, "{rb} vs {expected}");
        }
    }
}

/// Brute-force mutual nearest neighbours passing Lowe's ratio test.
fn ratio_matches(a: &Features, b: &Features, ratio: f32) -> usize {
    let nearest = |from: &Features, to: &Features, i: usize| {
        let d = from.descriptor(i).unwrap();
        let mut best = (f32::MAX, f32::MAX, usize::MAX);
        for j in 0..to.len() {
            let dist = descriptor_distance(d, to.descriptor(j).unwrap());
            if dist < best.0 {
                best = (dist, best.0, j);
            } else if dist < best.1 {
                best.1 = dist;
            }
        }
        best
    };
    (0..a.len())
        .filter(|&i| {
            let (best, second, j) = nearest(a, b, i);
            best < ratio * second && nearest(b, a, j).2 == i
        })
        .count()
}

#[test]
fn consecutive_real_frames_match() {
    let (Some(first), Some(second)) = (subvo_frame("frame_00_00_21.000.jpg"), subvo_frame("frame_00_00_23.000.jpg"))
    else {
        return;
    };
    let options = SiftOptions { max_num_features: 1000, ..Default::default() };
    let a = extract_sift(&options, &first).unwrap();
    let b = extract_sift(&options, &second).unwrap();
    assert_eq!((a.len(), b.len()), (1000, 1000));
    let matches = ratio_matches(&a, &b, 0.8);
    assert!(matches > 250, "only {matches} ratio-test matches between overlapping frames");
}

#[test]
fn options_are_checked_and_strict() {
    let bad = SiftOptions { octave_resolution: 0, ..Default::default() };
    assert!(matches!(bad.check(), Err(FeatureError::InvalidOption { option: "octave_resolution", .. })));
    let image = GrayImage::new(8, 8);
    assert!(matches!(
        extract_sift(&SiftOptions::default(), &image),
        Err(FeatureError::ImageTooSmall { width: 8, height: 8, .. })
    ));
    let parsed: SiftOptions = serde_json::from_str(r#"{"max_num_features": 10, "upright": true}"#).unwrap();
    assert_eq!(parsed, SiftOptions { max_num_features: 10, upright: true, ..Default::default() });
    assert!(serde_json::from_str::<SiftOptions>(r#"{"max_features": 10}"#).is_err());
    let upright = extract_sift(&parsed, &blob_image(64, 64, 30.0, 30.0, 3.0)).unwrap();
    assert!(upright.keypoints.iter().all(|k| k.orientation == 0.0));
}
