//! The evaluation protocol on a synthetic scene with exact truth.

#![allow(clippy::unwrap_used, clippy::expect_used)] // test helpers outside #[test] fns

use nalgebra::{Point2, Point3, UnitQuaternion, Vector3};
use revisit_core::{Camera, CameraModel, Image, Observation, Point3D, Reconstruction, Rigid3, TrackElement};
use revisit_eval::*;

const F: f64 = 500.0;
const CX: f64 = 320.0;
const CY: f64 = 240.0;

/// Deterministic uniform numbers in [0, 1) (xorshift64*).
struct Rng(u64);
impl Rng {
    fn next(&mut self) -> f64 {
        self.0 ^= self.0 >> 12;
        self.0 ^= self.0 << 25;
        self.0 ^= self.0 >> 27;
        (self.0.wrapping_mul(0x2545_F491_4F6C_DD1D) >> 11) as f64 / (1u64 << 53) as f64
    }
    fn range(&mut self, lo: f64, hi: f64) -> f64 {
        lo + (hi - lo) * self.next()
    }
}

/// An independent pinhole projection (the scene's camera has no distortion).
fn pinhole(cam_from_world: &Rigid3, x: &Point3<f64>) -> Point2<f64> {
    let p = cam_from_world.rotation * x.coords + cam_from_world.translation;
    Point2::new(F * p.x / p.z + CX, F * p.y / p.z + CY)
}

/// Sessions A and B, four cameras each 6 m above 300 points, every point
/// observed exactly in every image. Images 1-4 are A/a0..a3, 5-8 B/b0..b3.
fn truth_scene() -> Reconstruction {
    let mut rng = Rng(42);
    let mut model = Reconstruction::default();
    model.cameras.insert(1, Camera::new(1, CameraModel::Pinhole, 640, 480, vec![F, F, CX, CY]).unwrap());
    for k in 0..8u32 {
        let (session, prefix) = if k < 4 { ("A", "a") } else { ("B", "b") };
        let centre = Vector3::new(rng.range(-1.0, 1.0), rng.range(-0.8, 0.8), -6.0 + rng.range(-0.3, 0.3));
        let rotation =
            UnitQuaternion::from_euler_angles(rng.range(-0.05, 0.05), rng.range(-0.05, 0.05), rng.range(-3.1, 3.1));
        let cam_from_world = Rigid3::new(rotation, -(rotation * centre));
        let name = format!("{session}/{prefix}{}.png", k % 4);
        model.images.insert(k + 1, Image { image_id: k + 1, camera_id: 1, name, cam_from_world, points2d: vec![] });
    }
    for p in 0..300u64 {
        let xyz = Point3::new(rng.range(-2.0, 2.0), rng.range(-1.5, 1.5), rng.range(-0.5, 0.5));
        let mut track = Vec::new();
        for image in model.images.values_mut() {
            let xy = pinhole(&image.cam_from_world, &xyz);
            image.points2d.push(Observation { xy, point3d_id: Some(p + 1) });
            track.push(TrackElement { image_id: image.image_id, point2d_idx: p as u32 });
        }
        model.points3d.insert(p + 1, Point3D { xyz, rgb: [0; 3], error: 0.0, track });
    }
    model
}

/// Click pairs between sessions, both directions: 8 clicks per pair, each on
/// a keypoint of img0 (plus a sub-pixel offset), truth = exact projection in img1.
fn clicks(truth: &Reconstruction) -> Vec<ClickPair> {
    let mut rng = Rng(7);
    let mut pairs = Vec::new();
    for (id0, id1) in [(1u32, 5u32), (2, 6), (3, 8), (6, 1), (7, 4), (8, 2)] {
        let (image0, image1) = (&truth.images[&id0], &truth.images[&id1]);
        let mut uv_clicked = Vec::new();
        let mut uv_groundtruth = Vec::new();
        for _ in 0..8 {
            let p = (rng.next() * 300.0) as usize;
            let observation = image0.points2d[p];
            let xyz = truth.points3d[&observation.point3d_id.unwrap()].xyz;
            uv_clicked.push([observation.xy.x + 0.3, observation.xy.y - 0.2]);
            let gt = pinhole(&image1.cam_from_world, &xyz);
            uv_groundtruth.push([gt.x, gt.y]);
        }
        pairs.push(ClickPair {
            img0: image0.name.clone(),
            img1: image1.name.clone(),
            uv_clicked,
            uv_groundtruth,
            source: "test".into(),
            row: pairs.len() + 1,
        });
    }
    pairs
}

/// `world_new = displacement * world` applied to the images (and, if asked,
/// the points) of session B only.
fn displace_session_b(model: &mut Reconstruction, displacement: &Rigid3, move_points: bool) {
    for image in model.images.values_mut().filter(|i| i.name.starts_with("B/")) {
        image.cam_from_world = image.cam_from_world * displacement.inverse();
    }
    if move_points {
        for point in model.points3d.values_mut() {
            point.xyz = *displacement * point.xyz;
        }
    }
}

/// Keeps only the images of one session (and the points they see).
fn only_session(model: &Reconstruction, session: &str) -> Reconstruction {
    let mut out = model.clone();
    out.images.retain(|_, image| image.name.starts_with(&format!("{session}/")));
    out
}

fn displacement() -> Rigid3 {
    Rigid3::new(UnitQuaternion::from_euler_angles(0.05, -0.04, 0.06), Vector3::new(0.3, -0.2, 0.1))
}

fn median(mut values: Vec<f64>) -> f64 {
    values.sort_by(f64::total_cmp);
    let n = values.len();
    if n % 2 == 1 {
        values[n / 2]
    } else {
        0.5 * (values[n / 2 - 1] + values[n / 2])
    }
}

#[test]
fn truth_model_scores_zero() {
    let truth = truth_scene();
    let pairs = clicks(&truth);
    let scores = score(std::slice::from_ref(&truth), &pairs, &ScoreOptions::default());
    assert_eq!(scores.overall.scored, 48);
    assert_eq!(scores.overall.skipped, 0);
    assert!(scores.overall.median_px.unwrap() < 1e-9 && scores.overall.mean_px.unwrap() < 1e-9);
    assert!(scores.one_model);
    assert_eq!(scores.radius_px, 3.0);
    assert_eq!(scores.pairs.keys().collect::<Vec<_>>(), ["A-B"]);
    assert_eq!(scores.pairs["A-B"].scored, 48);
    assert_eq!(scores.clicks.len(), 48);
}

#[test]
fn displaced_session_scores_the_expected_error() {
    let truth = truth_scene();
    let pairs = clicks(&truth);
    let d = displacement();
    let mut model = truth.clone();
    displace_session_b(&mut model, &d, false);
    // Expected, from the truth: a point seen in A lands where the moved B
    // camera sees it; a point seen in B is the true point, seen by the true A.
    let mut expected = Vec::new();
    for pair in &pairs {
        let (moving_img1, image1) = (pair.img1.starts_with("B/"), truth.image_by_name(&pair.img1).unwrap());
        for (clicked, gt) in pair.uv_clicked.iter().zip(&pair.uv_groundtruth) {
            let image0 = truth.image_by_name(&pair.img0).unwrap();
            let obs = image0.points2d.iter().min_by(|a, b| {
                let da = (a.xy - Point2::new(clicked[0], clicked[1])).norm();
                let db = (b.xy - Point2::new(clicked[0], clicked[1])).norm();
                da.total_cmp(&db)
            });
            let xyz = truth.points3d[&obs.unwrap().point3d_id.unwrap()].xyz;
            let cam = if moving_img1 { image1.cam_from_world * d.inverse() } else { image1.cam_from_world };
            expected.push((pinhole(&cam, &xyz) - Point2::new(gt[0], gt[1])).norm());
        }
    }
    let scores = score(std::slice::from_ref(&model), &pairs, &ScoreOptions::default());
    assert_eq!(scores.overall.scored, 48);
    let expected_median = median(expected.clone());
    // Clicks from A into a moved B image are off; clicks from B see the true point in A.
    let from_a =
        expected.iter().zip(pairs.iter().flat_map(|p| p.uv_clicked.iter().map(move |_| p.img0.starts_with("A/"))));
    for (e, is_from_a) in from_a {
        assert!(if is_from_a { *e > 1.0 } else { *e < 1e-9 }, "{e} from A: {is_from_a}");
    }
    assert!((scores.overall.median_px.unwrap() - expected_median).abs() < 1e-6);
    let expected_mean = expected.iter().sum::<f64>() / expected.len() as f64;
    assert!((scores.overall.mean_px.unwrap() - expected_mean).abs() < 1e-6);
    for (click, e) in scores.clicks.iter().zip(&expected) {
        assert!((click.error_px.unwrap() - e).abs() < 1e-6, "{click:?}");
    }
}

#[test]
fn separate_models_aligned_exactly_score_zero_and_misaligned_score_the_offset() {
    let truth = truth_scene();
    let pairs = clicks(&truth);
    let models = [only_session(&truth, "A"), only_session(&truth, "B")];
    let scores = score(&models, &pairs, &ScoreOptions::default());
    assert_eq!(scores.overall.scored, 48);
    assert!(scores.overall.median_px.unwrap() < 1e-9);
    assert!(!scores.one_model, "no single model holds both sessions");
    assert_eq!(scores.models, 2);

    // Model B off by a rigid transform (its images and points together).
    let d = displacement();
    let mut b = models[1].clone();
    displace_session_b(&mut b, &d, true);
    let scores = score(&[models[0].clone(), b], &pairs, &ScoreOptions::default());
    let mut expected = Vec::new();
    for pair in &pairs {
        let image1 = truth.image_by_name(&pair.img1).unwrap();
        let image0 = truth.image_by_name(&pair.img0).unwrap();
        for (clicked, gt) in pair.uv_clicked.iter().zip(&pair.uv_groundtruth) {
            let c = Point2::new(clicked[0], clicked[1]);
            let obs = image0.points2d.iter().min_by(|a, b| (a.xy - c).norm().total_cmp(&(b.xy - c).norm())).unwrap();
            let xyz = truth.points3d[&obs.point3d_id.unwrap()].xyz;
            let projected = if pair.img1.starts_with("B/") {
                pinhole(&(image1.cam_from_world * d.inverse()), &xyz) // true point, displaced camera
            } else {
                pinhole(&image1.cam_from_world, &(d * xyz)) // displaced point, true camera
            };
            expected.push((projected - Point2::new(gt[0], gt[1])).norm());
        }
    }
    assert!((scores.overall.median_px.unwrap() - median(expected.clone())).abs() < 1e-6);
    assert!(median(expected) > 5.0);
}

#[test]
fn missing_images_and_far_clicks_are_counted_by_reason() {
    let truth = truth_scene();
    let mut pairs = clicks(&truth);
    pairs[0].img0 = "C/c0.png".into(); // 8 clicks: img0 not in model
    pairs[1].img1 = "B/gone.png".into(); // 8 clicks: img1 not in model
    pairs[2].uv_clicked[0] = [-50.0, -50.0]; // 1 click: no keypoint near
    pairs[3].img0 = "b1.png".into(); // session omitted: unique suffix, still scored
    let scores = score(std::slice::from_ref(&truth), &pairs, &ScoreOptions { radius_px: 2.0, ..Default::default() });
    let by = &scores.overall.skipped_by_reason;
    assert_eq!(by.get(&SkipReason::Img0NotInModel), Some(&8));
    assert_eq!(by.get(&SkipReason::Img1NotInModel), Some(&8));
    assert_eq!(by.get(&SkipReason::NoPoint3dWithinRadius), Some(&1));
    assert_eq!(scores.overall.skipped, 17);
    assert_eq!(scores.overall.scored, 31);
    assert_eq!(scores.radius_px, 2.0);
    assert!(scores.overall.median_px.unwrap() < 1e-9);
    // The missing C session keeps "one model" from holding every session.
    assert!(!scores.one_model);
    assert!(scores.pairs.contains_key("B-C"));
    let json = serde_json::to_value(&scores).unwrap();
    for key in ["median_px", "mean_px", "scored", "skipped", "one_model", "radius_px", "pairs"] {
        assert!(json.get(key).is_some(), "JSON lacks {key}");
    }
    assert_eq!(json["skipped_by_reason"]["img0_not_in_model"], 8);
    assert_eq!(json["pairs"]["A-B"]["scored"], 31);
}

#[test]
fn parser_reads_published_style_files() {
    let text = "img0,img1,uv_clicked,uv_groundtruth\r\n\
        2019/IMG_0001.JPG,2021/IMG_0100.JPG,\"[[10.5, 20.25], [30, 40], [50, 60], [70, 80], [90, 100], [110, 120], [130, 140], [150, 160]]\",\"[[11, 21], [31, 41], [51, 61], [71, 81], [91, 101], [111, 121], [131, 141], [151, 161]]\"\r\n\
        2019/IMG_0002.JPG,2021/IMG_0101.JPG,\"[[1, 2]]\",\"[[3, 4], [5, 6]]\"\r\n\
        2019/IMG_0003.JPG,2021/IMG_0102.JPG,\"[[1, 2]\",\"[[3, 4]]\"\r\n\
        2019/IMG_0004.JPG,2021/IMG_0103.JPG,\"[[1, 2]]\"\r\n\
        2019/IMG_0005.JPG,2021/IMG_0104.JPG,\"[[1.5,2.5]]\",\"[[3.5,4.5]]\"\r\n";
    let parsed = parse_points_csv(text, "reef.csv").unwrap();
    assert_eq!(parsed.pairs.len(), 2);
    let first = &parsed.pairs[0];
    assert_eq!((first.img0.as_str(), first.img1.as_str(), first.row), ("2019/IMG_0001.JPG", "2021/IMG_0100.JPG", 1));
    assert_eq!(first.uv_clicked.len(), 8);
    assert_eq!(first.uv_clicked[0], [10.5, 20.25]);
    assert_eq!(first.uv_groundtruth[7], [151.0, 161.0]);
    assert_eq!(parsed.pairs[1].row, 5);
    let rows: Vec<usize> = parsed.malformed.iter().map(|m| m.row).collect();
    assert_eq!(rows, [2, 3, 4]);
    assert!(parsed.malformed[0].reason.contains("1 clicked points but 2 ground-truth"), "{:?}", parsed.malformed[0]);
    assert_eq!(parsed.malformed[0].source, "reef.csv");

    // Written back, read again: the same pairs.
    let again = parse_points_csv(&write_points_csv(&parsed.pairs), "reef.csv").unwrap();
    assert_eq!(
        again.pairs.iter().map(|p| (&p.img0, &p.uv_clicked, &p.uv_groundtruth)).collect::<Vec<_>>(),
        parsed.pairs.iter().map(|p| (&p.img0, &p.uv_clicked, &p.uv_groundtruth)).collect::<Vec<_>>()
    );

    let err = parse_points_csv("a,b\n1,2\n", "bad.csv").unwrap_err().to_string();
    assert!(err.starts_with("bad.csv: no column \"img0\""), "{err}");
}

#[test]
fn umeyama_recovers_a_known_similarity() {
    let mut rng = Rng(3);
    let src: Vec<Point3<f64>> =
        (0..20).map(|_| Point3::new(rng.range(-5.0, 5.0), rng.range(-5.0, 5.0), rng.range(-1.0, 1.0))).collect();
    let rotation = UnitQuaternion::from_euler_angles(0.3, -1.2, 2.5);
    let (scale, translation) = (2.5, Vector3::new(10.0, -3.0, 0.5));
    let dst: Vec<Point3<f64>> = src.iter().map(|p| Point3::from(rotation * p.coords * scale + translation)).collect();
    let sim = umeyama(&src, &dst).unwrap();
    assert!((sim.scale - scale).abs() < 1e-10);
    assert!(sim.rotation.angle_to(&rotation) < 1e-10);
    assert!((sim.translation - translation).norm() < 1e-9);
    let collinear: Vec<Point3<f64>> = (0..5).map(|k| Point3::new(k as f64, 0.0, 0.0)).collect();
    assert_eq!(umeyama(&collinear, &collinear), Err(AlignError::Degenerate));
    assert_eq!(umeyama(&src[..2], &dst[..2]), Err(AlignError::TooFew(2)));
}

fn poses_csv(truth: &Reconstruction) -> String {
    let mut writer = csv::Writer::from_writer(Vec::new());
    writer.write_record(["session", "image", "qw", "qx", "qy", "qz", "tx", "ty", "tz"]).unwrap();
    for image in truth.images.values() {
        let (session, file) = image.name.split_once('/').unwrap();
        let [qw, qx, qy, qz] = image.cam_from_world.wxyz();
        let t = image.cam_from_world.translation;
        let numbers = [qw, qx, qy, qz, t.x, t.y, t.z].map(|v| v.to_string());
        writer.write_record([session, file].into_iter().chain(numbers.iter().map(String::as_str))).unwrap();
    }
    String::from_utf8(writer.into_inner().unwrap()).unwrap()
}

#[test]
fn truth_figures_after_similarity_alignment() {
    let truth = truth_scene();
    let poses = parse_truth_poses_csv(&poses_csv(&truth), "truth/poses.csv").unwrap();
    assert_eq!(poses.len(), 8);
    assert_eq!(poses[4].name, "B/b0.png");

    // The truth seen through an arbitrary similarity, minus one image of B.
    let mut model = truth.clone();
    model
        .transform(0.37, &Rigid3::new(UnitQuaternion::from_euler_angles(1.0, 0.2, -0.7), Vector3::new(3.0, 1.0, -2.0)));
    model.images.remove(&8);
    let t = score_truth(std::slice::from_ref(&model), &poses, &TruthOptions::default());
    assert_eq!(t.largest_model, Some(0));
    assert!(t.overall.centre_median_m.unwrap() < 1e-9 && t.overall.rotation_median_deg.unwrap() < 1e-6);
    assert_eq!(t.sessions["A"].registration_rate, 1.0);
    assert_eq!(t.sessions["B"].registration_rate, 0.75);
    assert!((t.similarities[0].unwrap().scale - 1.0 / 0.37).abs() < 1e-9);
    assert!(t.scene_size_m > 1.0);
    assert!(t.sessions.values().all(|s| s.scale_rel_error.unwrap().abs() < 1e-9));

    // Session B 5% too large inside a joint model (its camera centres spread about the origin).
    let mut grown = truth.clone();
    for image in grown.images.values_mut().filter(|i| i.name.starts_with("B/")) {
        let centre = image.cam_from_world.origin_of_target().coords * 1.05;
        image.cam_from_world = Rigid3::new(image.cam_from_world.rotation, -(image.cam_from_world.rotation * centre));
    }
    let t = score_truth(std::slice::from_ref(&grown), &poses, &TruthOptions::default());
    let scale = |s: &str| 1.0 + t.sessions[s].scale_rel_error.unwrap();
    assert!((scale("B") / scale("A") - 1.0 / 1.05).abs() < 1e-9, "{:?}", t.sessions);

    // Session B displaced inside a joint model: B's camera centres move.
    let d = Rigid3::new(UnitQuaternion::identity(), Vector3::new(0.5, 0.0, 0.0));
    let mut moved = truth.clone();
    displace_session_b(&mut moved, &d, false);
    let t = score_truth(std::slice::from_ref(&moved), &poses, &TruthOptions::default());
    assert!(t.overall.centre_mean_m.unwrap() > 0.1, "{:?}", t.overall);
    // Aligning two separate models each on its own hides the offset; the union does not.
    let models = [only_session(&moved, "A"), only_session(&moved, "B")];
    let each = score_truth(&models, &poses, &TruthOptions { alignment: Alignment::EachModel });
    assert!(each.overall.centre_median_m.unwrap() < 1e-9);
    let union = score_truth(&models, &poses, &TruthOptions::default());
    assert!(union.overall.centre_median_m.unwrap() > 0.1);
    assert_eq!(union.sessions["B"].registration_rate, 0.0, "B is not in the largest model (A wins the tie)");

    let err = parse_truth_poses_csv("session,image,qw,qx,qy,qz,tx,ty,tz\nA,a.png,1,0,0,0,0,zero,0\n", "poses.csv")
        .unwrap_err()
        .to_string();
    assert_eq!(err, "poses.csv: row 1: ty \"zero\" is not a number");
}

#[test]
fn histogram_marks_the_median() {
    let errors: Vec<f64> = (0..100).map(|k| 1.0 + (k % 10) as f64 * 0.5).collect();
    let options = HistogramOptions::default();
    let img = histogram(&errors, "A-B", &options);
    assert_eq!((img.width(), img.height()), (800, 480));
    let red = img.pixels().filter(|p| p.0 == [214, 39, 40]).count();
    let bars = img.pixels().filter(|p| p.0 == [70, 130, 180]).count();
    assert!(red > 300, "median line and label: {red}");
    assert!(bars > 10_000, "bars: {bars}");
    // Nothing to plot still gives a picture with axes and no median.
    let empty = histogram(&[], "A-B", &options);
    assert_eq!(empty.pixels().filter(|p| p.0 == [214, 39, 40]).count(), 0);
}
