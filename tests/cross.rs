//! Linking visits across strong change: the synthetic reef's sediment moves
//! between visits and each visit flies a heading about 90 or 180 degrees from
//! the first. SIFT alone cannot link them; place recognition plus learned
//! matching with roll search can, and a fourth visit extends the model without
//! redoing any finished work.

mod common;

use common::{read_json, run_err, run_ok};

#[test]
fn cross_visit_bad_input_gets_one_line_errors() {
    let dir = tempfile::tempdir().unwrap();
    let root = dir.path();
    let a = root.join("a");
    let b = root.join("b");
    common::copy_first(&common::shared_data("subvo/images"), 2, &a);
    common::copy_first(&common::shared_data("subvo/images"), 1, &b);
    let work = root.join("work").display().to_string();
    let two = |extra: &[&str]| -> String {
        let mut args = vec!["reconstruct", "--out", &work];
        let first = format!("first={}", a.display());
        let again = format!("again={}", a.display());
        args.extend(["--session", &first, "--session", &again]);
        args.extend(extra);
        let stderr = run_err(&args);
        let lines: Vec<&str> = stderr.lines().filter(|l| !l.trim().is_empty()).collect();
        assert_eq!(lines.len(), 1, "not one line: {stderr}");
        lines[0].to_owned()
    };

    let missing = two(&["--onnxruntime", "/nonexistent/libonnxruntime.so"]);
    assert!(missing.contains("/nonexistent/libonnxruntime.so"), "{missing}");

    // A model whose inputs break the contract: LightGlue where ALIKED belongs.
    let models = root.join("models");
    std::fs::create_dir_all(&models).unwrap();
    let shared = common::models();
    std::fs::copy(shared.join("lightglue_aliked.onnx"), models.join("aliked_n16_480x640.onnx")).unwrap();
    std::fs::copy(shared.join("lightglue_aliked.onnx"), models.join("lightglue_aliked.onnx")).unwrap();
    let wrong = two(&["--models", models.to_str().unwrap()]);
    assert!(wrong.contains("aliked_n16_480x640.onnx"), "{wrong}");

    let one = format!("b={}", b.display());
    let stderr = run_err(&["reconstruct", "--out", &work, "--session", &one]);
    assert!(stderr.contains("one image") && stderr.contains("session b"), "{stderr}");
}

#[test]
fn match_prints_verified_matches_in_each_images_own_frame() {
    let dir = tempfile::tempdir().unwrap();
    let images = common::shared_data("subvo/images");
    let mut names: Vec<_> = std::fs::read_dir(&images).unwrap().map(|e| e.unwrap().path()).collect();
    names.sort();
    let a = &names[0];
    // The same image turned a quarter clockwise: pixel (x, y) moves to
    // (height - y, x), and roll search must find that.
    let rotated = dir.path().join("rotated.png");
    image::open(a).unwrap().rotate90().save(&rotated).unwrap();
    let (_, height) = image::image_dimensions(a).unwrap();
    let json = dir.path().join("match.json");
    let png = dir.path().join("match.png");
    run_ok(&[
        "match",
        a.to_str().unwrap(),
        rotated.to_str().unwrap(),
        "--roll-search",
        "--json",
        json.to_str().unwrap(),
        "--draw",
        png.to_str().unwrap(),
    ]);
    let result = read_json(&json);
    let roll = result["roll_deg"].as_i64().unwrap();
    assert!(roll == 90 || roll == 270, "{}", result["roll_deg"]);
    let matches = result["matches"].as_array().unwrap();
    assert_eq!(result["inliers"].as_u64().unwrap() as usize, matches.len());
    assert!(matches.len() >= 100, "{} matches", matches.len());
    let far = matches
        .iter()
        .map(|m| [0, 1, 2, 3].map(|i| m[i].as_f64().unwrap()))
        .filter(|[xa, ya, xb, yb]| (xb - (height as f64 - ya)).hypot(yb - xa) > 2.0)
        .count();
    assert!(far * 20 < matches.len(), "{far} of {} matches off by more than 2 px", matches.len());
    let (drawn_width, _) = image::image_dimensions(&png).unwrap();
    assert!(drawn_width > height);
}
