//! Revisit's model files against pycolmap 4.2.1, an independent COLMAP
//! implementation: pycolmap reads what Revisit writes, and Revisit reads what
//! pycolmap writes (which includes its extra `rigs` and `frames` files).
//!
//! Needs the project's virtual environment (`.venv` at the workspace root,
//! with pycolmap). CI installs it; when it is missing this test fails.

#![allow(clippy::unwrap_used, clippy::expect_used)] // test helpers outside #[test] fns

mod common;

use std::path::{Path, PathBuf};
use std::process::Command;

use revisit_colmap::{read_model, write_binary, write_text};
use revisit_core::Reconstruction;
use serde_json::Value;

fn workspace_root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../..")
}

fn venv_python() -> PathBuf {
    let python = workspace_root().join(".venv/bin/python");
    assert!(
        python.is_file(),
        "{} is missing: create the project's virtual environment with pycolmap 4.2.1 (see README.md)",
        python.display()
    );
    python
}

/// Runs colmap_roundtrip.py (beside this file) on `model_dir`; returns pycolmap's view of
/// the model and the folders where pycolmap wrote it back.
fn pycolmap_round_trip(model_dir: &Path, work: &Path) -> (Value, PathBuf, PathBuf) {
    let (out_bin, out_txt) = (work.join("pycolmap_bin"), work.join("pycolmap_txt"));
    let output = Command::new(venv_python())
        .arg(Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/colmap_roundtrip.py"))
        .args([model_dir, &out_bin, &out_txt])
        .output()
        .unwrap();
    assert!(output.status.success(), "pycolmap failed: {}", String::from_utf8_lossy(&output.stderr));
    let dump: Value = serde_json::from_slice(&output.stdout).unwrap();
    assert_eq!(dump["version"], "4.2.1", "expected pycolmap 4.2.1");
    (dump, out_bin, out_txt)
}

fn close(a: f64, b: f64, tol: f64) -> bool {
    (a - b).abs() <= tol * (1.0 + a.abs().max(b.abs()))
}

fn f64s(value: &Value) -> Vec<f64> {
    value.as_array().unwrap().iter().map(|v| v.as_f64().unwrap()).collect()
}

/// pycolmap saw the same model as Revisit wrote (JSON floats to 1e-12).
fn check_dump(dump: &Value, model: &Reconstruction) {
    assert_eq!(dump["cameras"].as_object().unwrap().len(), model.cameras.len());
    assert_eq!(dump["images"].as_object().unwrap().len(), model.images.len());
    assert_eq!(dump["points3D"].as_object().unwrap().len(), model.points3d.len());
    for (id, camera) in &model.cameras {
        let c = &dump["cameras"][id.to_string()];
        assert_eq!(c["model"], camera.model.name());
        assert_eq!(
            (c["width"].as_u64().unwrap(), c["height"].as_u64().unwrap()),
            (camera.width.into(), camera.height.into())
        );
        let params = f64s(&c["params"]);
        assert_eq!(params.len(), camera.params.len());
        for (a, b) in params.iter().zip(&camera.params) {
            assert!(close(*a, *b, 1e-15), "camera {id}: {a} vs {b}");
        }
    }
    for (id, image) in &model.images {
        let i = &dump["images"][id.to_string()];
        assert_eq!(i["name"], image.name.as_str());
        assert_eq!(i["camera_id"].as_u64().unwrap(), u64::from(image.camera_id));
        for (a, b) in f64s(&i["qvec"]).iter().zip(image.cam_from_world.wxyz()) {
            assert!((a - b).abs() < 1e-12, "image {id} qvec");
        }
        for (a, b) in f64s(&i["tvec"]).iter().zip(image.cam_from_world.translation.iter()) {
            assert!((a - b).abs() < 1e-12, "image {id} tvec");
        }
        let points2d = i["points2D"].as_array().unwrap();
        assert_eq!(points2d.len(), image.points2d.len());
        for (p, o) in points2d.iter().zip(&image.points2d) {
            assert!(close(p[0].as_f64().unwrap(), o.xy.x, 1e-15) && close(p[1].as_f64().unwrap(), o.xy.y, 1e-15));
            assert_eq!(p[2].as_i64().unwrap(), o.point3d_id.map_or(-1, |id| id as i64));
        }
    }
    for (id, point) in &model.points3d {
        let p = &dump["points3D"][id.to_string()];
        for (a, b) in f64s(&p["xyz"]).iter().zip(point.xyz.iter()) {
            assert!(close(*a, *b, 1e-15), "point {id}");
        }
        let rgb: Vec<u64> = p["rgb"].as_array().unwrap().iter().map(|v| v.as_u64().unwrap()).collect();
        assert_eq!(rgb, point.rgb.map(u64::from));
        let track: Vec<(u64, u64)> =
            p["track"].as_array().unwrap().iter().map(|e| (e[0].as_u64().unwrap(), e[1].as_u64().unwrap())).collect();
        let expected: Vec<(u64, u64)> =
            point.track.iter().map(|e| (u64::from(e.image_id), u64::from(e.point2d_idx))).collect();
        assert_eq!(track, expected, "point {id} track");
    }
}

/// What Revisit reads back from pycolmap's files equals the original: poses
/// to 1e-12, everything else exactly.
fn check_read_back(dir: &Path, model: &Reconstruction) {
    let back = read_model(dir).unwrap_or_else(|e| panic!("reading pycolmap's {}: {e}", dir.display()));
    assert_eq!(back.cameras, model.cameras, "{}", dir.display());
    assert_eq!(back.points3d, model.points3d, "{}", dir.display());
    assert_eq!(back.images.len(), model.images.len());
    for (id, image) in &model.images {
        let other = &back.images[id];
        assert_eq!((&other.name, other.camera_id, &other.points2d), (&image.name, image.camera_id, &image.points2d));
        let delta = other.cam_from_world * image.cam_from_world.inverse();
        assert!(
            delta.rotation.angle() < 1e-12 && delta.translation.norm() < 1e-12,
            "image {id} pose, {}",
            dir.display()
        );
    }
}

#[test]
fn pycolmap_reads_revisit_models_and_revisit_reads_pycolmap_models() {
    let model = common::sample_model();
    let work = tempfile::tempdir().unwrap();
    for (form, dir) in [("bin", work.path().join("revisit_bin")), ("txt", work.path().join("revisit_txt"))] {
        if form == "bin" {
            write_binary(&model, &dir).unwrap();
        } else {
            write_text(&model, &dir).unwrap();
        }
        let scratch = work.path().join(format!("from_{form}"));
        let (dump, out_bin, out_txt) = pycolmap_round_trip(&dir, &scratch);
        check_dump(&dump, &model);
        assert!(out_bin.join("cameras.bin").is_file() && out_txt.join("points3D.txt").is_file());
        check_read_back(&out_bin, &model);
        check_read_back(&out_txt, &model);
    }
}
