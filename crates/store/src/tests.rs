use revisit_core::{Camera, Features, Keypoint, PairKind, TwoViewConfig, TwoViewGeometry};

use super::*;

fn features(n: usize, seed: u8) -> Features {
    Features {
        keypoints: (0..n)
            .map(|i| Keypoint { x: i as f32 + 0.5, y: f32::from(seed), scale: 2.0, orientation: 0.25 })
            .collect(),
        descriptors: (0..n * 128).map(|i| (i as u8).wrapping_add(seed)).collect(),
        descriptor_dim: 128,
    }
}

fn store_with_images() -> (tempfile::TempDir, Store, BTreeMap<String, ImageId>) {
    let dir = tempfile::tempdir().unwrap();
    let mut store = Store::open(&dir.path().join("database.db")).unwrap();
    store.ensure_session("2019", "/data/2019").unwrap();
    let camera = store.ensure_camera("2019/640x480", &Camera::default_for_size(0, 640, 480), false).unwrap();
    let names = vec!["2019/a.png".to_string(), "2019/b.png".to_string()];
    let ids = store.ensure_images(&names, camera.camera_id).unwrap();
    (dir, store, ids)
}

#[test]
fn features_round_trip() {
    let (_dir, mut store, ids) = store_with_images();
    let id = ids["2019/a.png"];
    let written = features(5, 3);
    store.write_features(id, &written).unwrap();
    let read = store.read_features(id).unwrap();
    assert_eq!(read.descriptors, written.descriptors);
    for (a, b) in read.keypoints.iter().zip(&written.keypoints) {
        assert!((a.x - b.x).abs() < 1e-6 && (a.scale - b.scale).abs() < 1e-5);
        assert!((a.orientation - b.orientation).abs() < 1e-5);
    }
    assert_eq!(store.images_with_features().unwrap(), BTreeSet::from([id]));
}

#[test]
fn reopening_keeps_everything_and_adds_nothing_twice() {
    let (dir, mut store, ids) = store_with_images();
    store.write_features(ids["2019/a.png"], &features(3, 1)).unwrap();
    drop(store);
    let mut store = Store::open(&dir.path().join("database.db")).unwrap();
    assert_eq!(store.ensure_session("2019", "/data/2019").unwrap().visit, 0);
    let camera = store.ensure_camera("2019/640x480", &Camera::default_for_size(0, 640, 480), false).unwrap();
    let again = store.ensure_images(&["2019/a.png".to_string()], camera.camera_id).unwrap();
    assert_eq!(again, ids);
    assert_eq!(store.sessions().unwrap().len(), 1);
    assert_eq!(store.images_with_features().unwrap().len(), 1);
}

#[test]
fn a_session_cannot_change_its_source() {
    let (_dir, mut store, _) = store_with_images();
    let err = store.ensure_session("2019", "/elsewhere").unwrap_err();
    assert!(err.to_string().contains("session \"2019\" was added from /data/2019, not /elsewhere"), "{err}");
}

#[test]
fn visits_keep_the_order_they_were_added_in() {
    let (dir, mut store, _) = store_with_images();
    store.ensure_session("2018", "/data/2018").unwrap();
    store.ensure_session("2021", "/data/2021").unwrap();
    drop(store);
    let mut store = Store::open(&dir.path().join("database.db")).unwrap();
    // Given again in another order, each keeps its place.
    assert_eq!(store.ensure_session("2021", "/data/2021").unwrap().visit, 2);
    let order: Vec<(String, usize)> = store.sessions().unwrap().into_iter().map(|s| (s.name, s.visit)).collect();
    assert_eq!(order, [("2019".to_owned(), 0), ("2018".to_owned(), 1), ("2021".to_owned(), 2)]);
}

#[test]
fn a_camera_keeps_its_model_and_size() {
    let (_dir, mut store, _) = store_with_images();
    let again = store.ensure_camera("2019/640x480", &Camera::default_for_size(0, 640, 480), false).unwrap();
    assert_eq!(again.camera_id, 1);
    let err = store.ensure_camera("2019/640x480", &Camera::default_for_size(0, 800, 600), false).unwrap_err();
    assert!(
        err.to_string().contains("camera 2019/640x480 is SIMPLE_RADIAL 640x480, not SIMPLE_RADIAL 800x600"),
        "{err}"
    );
}

#[test]
fn settings_are_pinned() {
    let (_dir, store, _) = store_with_images();
    store.pin_setting("sift", "a").unwrap();
    store.pin_setting("sift", "a").unwrap();
    assert!(matches!(store.pin_setting("sift", "b"), Err(StoreError::SettingMismatch { .. })));
}

#[test]
fn pairs_are_stored_in_colmap_order() {
    let (_dir, mut store, ids) = store_with_images();
    let (a, b) = (ids["2019/a.png"], ids["2019/b.png"]);
    let geometry = TwoViewGeometry {
        config: TwoViewConfig::Uncalibrated,
        inlier_matches: vec![[4, 1]],
        f: Some(nalgebra::Matrix3::identity()),
        e: None,
        h: None,
        cam2_from_cam1: None,
    };
    // Given as (b, a): stored as (a, b) with the columns swapped.
    let record = PairRecord {
        image_id1: b,
        image_id2: a,
        kind: PairKind::Intra,
        method: "sift".into(),
        roll_deg: 0,
        predicted_roll_deg: Some(90),
        num_matches: 2,
        num_inliers: 1,
    };
    store.write_pair(&record, &[[4, 1], [5, 2]], &geometry).unwrap();
    let pair = revisit_core::pair_id(a, b);
    assert_eq!(store.matched_pairs().unwrap(), BTreeSet::from([pair]));
    let (config, inliers) = store.two_view_geometry(pair).unwrap().unwrap();
    assert_eq!(config, TwoViewConfig::Uncalibrated);
    assert_eq!(inliers, vec![[1, 4]]);
    assert_eq!(store.pair_records().unwrap()[0].image_id1, a.min(b));
    assert_eq!(store.pair_records().unwrap()[0].predicted_roll_deg, Some(90));

    // Set aside, COLMAP no longer sees the pair; its inliers are kept and come back whole, also
    // after pycolmap has added its columns to COLMAP's table (as it does when it maps).
    store.conn.execute_batch("ALTER TABLE two_view_geometries ADD COLUMN camera1 BLOB").unwrap();
    store.set_aside(pair, "off consensus").unwrap();
    assert_eq!(store.two_view_geometry(pair).unwrap(), None);
    assert_eq!(store.verified_matches(pair).unwrap(), vec![[1, 4]]);
    assert_eq!(store.set_aside_pairs().unwrap(), BTreeMap::from([(pair, "off consensus".to_owned())]));
    store.restore_set_aside(pair).unwrap();
    assert_eq!(store.two_view_geometry(pair).unwrap(), Some((TwoViewConfig::Uncalibrated, vec![[1, 4]])));
    assert!(store.set_aside_pairs().unwrap().is_empty());
    // A pair matched again is judged afresh: nothing of it stays aside.
    store.set_aside(pair, "off consensus").unwrap();
    store.write_pair(&PairRecord { predicted_roll_deg: None, ..record }, &[[4, 1], [5, 2]], &geometry).unwrap();
    assert!(store.set_aside_pairs().unwrap().is_empty());
    assert_eq!(store.pair_records().unwrap()[0].predicted_roll_deg, None);
    assert!(store.two_view_geometry(pair).unwrap().is_some());
}

#[test]
fn pose_priors_round_trip_and_replace() {
    let (_dir, mut store, ids) = store_with_images();
    let (a, b) = (ids["2019/a.png"], ids["2019/b.png"]);
    let camera_id = store.camera(1).unwrap().camera_id;
    let covariance = nalgebra::Matrix3::from_diagonal(&nalgebra::Vector3::new(0.01, 0.01, 0.0004));
    let prior = |image_id, x: f64, covariance_m2| PosePrior {
        image_id,
        camera_id,
        position_m: nalgebra::Point3::new(x, 2.0, -3.0),
        covariance_m2,
    };
    store.write_pose_priors(&[prior(a, 1.0, Some(covariance)), prior(b, 5.0, None)]).unwrap();
    assert_eq!(store.pose_priors().unwrap(), vec![prior(a, 1.0, Some(covariance)), prior(b, 5.0, None)]);
    // An image's new prior replaces its old one.
    store.write_pose_priors(&[prior(b, 7.0, Some(covariance))]).unwrap();
    assert_eq!(store.pose_priors().unwrap(), vec![prior(a, 1.0, Some(covariance)), prior(b, 7.0, Some(covariance))]);
}
