//! The pipeline's records as the nodes' messages and back: one conversion per
//! record, shared by the node that publishes it and the node that stores it.

use std::collections::BTreeMap;

use revisit_core::TwoViewGeometry;
use revisit_core::{umeyama, Features, Keypoint, LearnedFeatures, Reconstruction, Rigid3, Roll, Similarity};
use revisit_matching::CrossMatch;
use revisit_msgs::geometry_msgs::{
    Point, Pose, PoseArray, PoseStamped, Quaternion, Transform, TransformStamped, Vector3 as VectorMessage,
};
use revisit_msgs::nav_msgs::Path;
use revisit_msgs::revisit_msgs::{CrossVisitMatches, Features as FeaturesMessage, MapStatus, SessionStatus};
use revisit_msgs::sensor_msgs::{CameraInfo, PointCloud2, PointField};
use revisit_msgs::std_msgs::Header;

use crate::options::CameraSpec;
use crate::Report;

/// The method name SIFT features are published under.
pub const SIFT: &str = "sift";

/// SIFT features of `image_name` (a keyframe's name within its session) as a message.
pub fn sift_message(
    header: Header,
    session: &str,
    image_name: &str,
    size: [u32; 2],
    features: &Features,
) -> FeaturesMessage {
    FeaturesMessage {
        header,
        session: session.to_owned(),
        image_name: image_name.to_owned(),
        method: SIFT.to_owned(),
        roll_degrees: 0,
        count: features.len() as u32,
        width: size[0],
        height: size[1],
        keypoints: features.keypoints.iter().flat_map(|k| [k.x, k.y, k.scale, k.orientation]).collect(),
        scores: Vec::new(),
        descriptor_size: features.descriptor_dim as u32,
        descriptor_type: FeaturesMessage::DESCRIPTOR_UINT8,
        descriptors: features.descriptors.clone(),
    }
}

/// Learned features at `roll` as a message.
pub fn learned_message(
    header: Header,
    session: &str,
    image_name: &str,
    method: &str,
    roll: Roll,
    features: &LearnedFeatures,
) -> FeaturesMessage {
    FeaturesMessage {
        header,
        session: session.to_owned(),
        image_name: image_name.to_owned(),
        method: method.to_owned(),
        roll_degrees: roll.degrees() as i32,
        count: features.len() as u32,
        width: features.width,
        height: features.height,
        keypoints: features.keypoints.iter().flatten().copied().collect(),
        scores: features.scores.clone(),
        descriptor_size: features.descriptor_dim as u32,
        descriptor_type: FeaturesMessage::DESCRIPTOR_FLOAT32,
        descriptors: features.descriptors.iter().flat_map(|d| d.to_le_bytes()).collect(),
    }
}

/// What a features message holds, checked: every length agrees with `count`.
#[derive(Debug, Clone, PartialEq)]
pub enum FeaturesRecord {
    Sift(Features),
    Learned { method: String, roll: Roll, features: LearnedFeatures },
}

/// Reads a features message; the error says which field disagrees.
pub fn features_record(message: &FeaturesMessage) -> Result<FeaturesRecord, String> {
    let count = message.count as usize;
    let dim = message.descriptor_size as usize;
    let expect = |what: &str, len: usize, want: usize| match len == want {
        true => Ok(()),
        false => Err(format!("{what} holds {len} values, {count} features need {want}")),
    };
    if message.method == SIFT {
        expect("keypoints", message.keypoints.len(), 4 * count)?;
        expect("descriptors", message.descriptors.len(), dim * count)?;
        if message.descriptor_type != FeaturesMessage::DESCRIPTOR_UINT8 || message.roll_degrees != 0 {
            return Err("SIFT features must be uint8 descriptors at roll 0".into());
        }
        let keypoints = message
            .keypoints
            .chunks_exact(4)
            .map(|k| Keypoint { x: k[0], y: k[1], scale: k[2], orientation: k[3] })
            .collect();
        return Ok(FeaturesRecord::Sift(Features {
            keypoints,
            descriptors: message.descriptors.clone(),
            descriptor_dim: dim,
        }));
    }
    let roll = u32::try_from(message.roll_degrees)
        .ok()
        .and_then(Roll::from_degrees)
        .ok_or_else(|| format!("roll_degrees {} is not 0, 90, 180 or 270", message.roll_degrees))?;
    if message.descriptor_type != FeaturesMessage::DESCRIPTOR_FLOAT32 {
        return Err("learned features must be float32 descriptors".into());
    }
    expect("keypoints", message.keypoints.len(), 2 * count)?;
    expect("scores", message.scores.len(), count)?;
    expect("descriptors", message.descriptors.len(), 4 * dim * count)?;
    let features = LearnedFeatures {
        keypoints: message.keypoints.chunks_exact(2).map(|k| [k[0], k[1]]).collect(),
        descriptors: message
            .descriptors
            .chunks_exact(4)
            .map(|b| f32::from_le_bytes([b[0], b[1], b[2], b[3]]))
            .collect(),
        descriptor_dim: dim,
        scores: message.scores.clone(),
        width: message.width,
        height: message.height,
    };
    Ok(FeaturesRecord::Learned { method: message.method.clone(), roll, features })
}

/// What the learned matcher found for a pair (`image1` at roll 0, `image2` rolled), as a message;
/// names are `(session, file)`.
pub fn cross_match_message(
    header: Header,
    image1: (&str, &str),
    image2: (&str, &str),
    method: &str,
    found: &CrossMatch,
) -> CrossVisitMatches {
    CrossVisitMatches {
        header,
        session1: image1.0.to_owned(),
        image_name1: image1.1.to_owned(),
        session2: image2.0.to_owned(),
        image_name2: image2.1.to_owned(),
        method: method.to_owned(),
        roll_degrees: found.roll.degrees() as i32,
        matches: found.matches.iter().flatten().copied().collect(),
        rolls_tried: found.inliers_by_roll.iter().map(|(roll, _)| roll.degrees() as i32).collect(),
        inliers_by_roll: found.inliers_by_roll.iter().map(|(_, n)| *n as u32).collect(),
        fell_back: found.fell_back,
        probabilities: found.probabilities.clone(),
    }
}

/// What a matcher found, from its message (the geometry is left to the mapper's verification).
pub fn cross_match(message: &CrossVisitMatches) -> Result<CrossMatch, String> {
    let roll_of = |degrees: i32| {
        u32::try_from(degrees)
            .ok()
            .and_then(Roll::from_degrees)
            .ok_or_else(|| format!("roll {degrees} is not 0, 90, 180 or 270"))
    };
    if !message.matches.len().is_multiple_of(2) || message.rolls_tried.len() != message.inliers_by_roll.len() {
        return Err("matches must come in pairs and each roll tried must have its inlier count".into());
    }
    if !message.probabilities.is_empty() && 2 * message.probabilities.len() != message.matches.len() {
        return Err("probabilities must be empty or one per match".into());
    }
    let inliers_by_roll = message
        .rolls_tried
        .iter()
        .zip(&message.inliers_by_roll)
        .map(|(roll, n)| Ok((roll_of(*roll)?, *n as usize)))
        .collect::<Result<_, String>>()?;
    Ok(CrossMatch {
        roll: roll_of(message.roll_degrees)?,
        matches: message.matches.chunks_exact(2).map(|m| [m[0], m[1]]).collect(),
        probabilities: message.probabilities.clone(),
        geometry: TwoViewGeometry::degenerate(),
        inliers_by_roll,
        fell_back: message.fell_back,
        predicted: None,
    })
}

/// A calibration from a `CameraInfo`: PINHOLE from `K` (ROS puts pixel centres at 0, COLMAP at
/// 0.5), or OPENCV with `plumb_bob`/`rational_polynomial` distortion that is not zero. `None` for an
/// uncalibrated camera (`K` all zero).
pub fn camera_spec(info: &CameraInfo) -> Option<CameraSpec> {
    let k = info.k;
    let (fx, fy, cx, cy) = (k[0], k[4], k[2] + 0.5, k[5] + 0.5);
    if !(fx > 0.0 && fy > 0.0 && [cx, cy].iter().all(|v| v.is_finite())) {
        return None;
    }
    let distorted = info.d.iter().any(|d| *d != 0.0);
    let (model, params) = match (distorted, info.d.as_slice()) {
        (true, [k1, k2, p1, p2, ..]) => ("OPENCV", vec![fx, fy, cx, cy, *k1, *k2, *p1, *p2]),
        _ => ("PINHOLE", vec![fx, fy, cx, cy]),
    };
    let text = format!("{model}:{}", params.iter().map(f64::to_string).collect::<Vec<_>>().join(","));
    text.parse().ok()
}

/// A camera's pose in the map, as ROS poses it: the camera's centre and orientation
/// (`world_from_cam`).
pub fn camera_pose(cam_from_world: &Rigid3) -> Pose {
    let world_from_cam = cam_from_world.inverse();
    let [w, x, y, z] = world_from_cam.wxyz();
    let t = world_from_cam.translation;
    Pose { position: Point { x: t.x, y: t.y, z: t.z }, orientation: Quaternion { x, y, z, w } }
}

/// Where the map sits on a visit's odometry: the similarity `odom_from_map` that takes the camera
/// centres of the registered images named in `centres_in_odom` (`session/file` -> the camera's
/// position by odometry) onto those positions, least squares (Umeyama). `None` with fewer than
/// 3 such images or all on one line.
pub fn odom_from_map(model: &Reconstruction, centres_in_odom: &BTreeMap<String, [f64; 3]>) -> Option<Similarity> {
    let (mut in_map, mut in_odom) = (Vec::new(), Vec::new());
    for image in model.images.values() {
        if let Some(&[x, y, z]) = centres_in_odom.get(&image.name) {
            in_map.push(nalgebra::Point3::from(image.cam_from_world.inverse().translation));
            in_odom.push(nalgebra::Point3::new(x, y, z));
        }
    }
    umeyama(&in_map, &in_odom).ok()
}

/// REP 105's `map -> odom` transform (the odometry frame's pose in the map frame) for a map
/// scaled to metres by `odom_from_map`'s scale: `header` names the map frame.
pub fn map_to_odom(header: &Header, odom_frame_id: &str, odom_from_map: &Similarity) -> TransformStamped {
    let map_from_odom = odom_from_map.rigid().inverse();
    let [w, x, y, z] = map_from_odom.wxyz();
    let t = map_from_odom.translation;
    TransformStamped {
        header: header.clone(),
        child_frame_id: odom_frame_id.to_owned(),
        transform: Transform {
            translation: VectorMessage { x: t.x, y: t.y, z: t.z },
            rotation: Quaternion { x, y, z, w },
        },
    }
}

/// The map's outputs as messages, stamped with `header` (its frame is the map's).
#[derive(Debug, Clone, PartialEq)]
pub struct MapMessages {
    /// Every 3D point: `x`, `y`, `z` (float32, metres or the model's unit), `rgb` (uint32 0x00RRGGBB
    /// in a float32, PCL's convention, which RViz and Foxglove colour by) and `session` (uint32: the
    /// first visit, in visit order, whose images observe the point).
    pub cloud: PointCloud2,
    /// Each visit's registered cameras in image-name (time) order, by session name.
    pub paths: BTreeMap<String, Path>,
    /// Every registered camera.
    pub cameras: PoseArray,
    pub status: MapStatus,
}

/// The map messages of `model` (the chosen model of `report`), visits ordered by `visits`
/// (session names, the reference first).
pub fn map_messages(header: &Header, model: &Reconstruction, report: &Report, visits: &[String]) -> MapMessages {
    let visit_of_session = |session: &str| visits.iter().position(|v| v == session).unwrap_or(visits.len());
    let session_of = |name: &str| name.split_once('/').map_or("", |(session, _)| session).to_owned();
    let image_visit: BTreeMap<_, usize> =
        model.images.iter().map(|(id, image)| (*id, visit_of_session(&session_of(&image.name)))).collect();
    const STEP: u32 = 20;
    let field = |name: &str, offset, datatype| PointField { name: name.into(), offset, datatype, count: 1 };
    let mut data = Vec::with_capacity(model.points3d.len() * STEP as usize);
    for point in model.points3d.values() {
        for v in [point.xyz.x, point.xyz.y, point.xyz.z] {
            data.extend((v as f32).to_le_bytes());
        }
        let [r, g, b] = point.rgb.map(u32::from);
        data.extend(((r << 16) | (g << 8) | b).to_le_bytes());
        let first = point.track.iter().filter_map(|t| image_visit.get(&t.image_id)).min().copied().unwrap_or(0);
        data.extend((first as u32).to_le_bytes());
    }
    let cloud = PointCloud2 {
        header: header.clone(),
        height: 1,
        width: model.points3d.len() as u32,
        fields: vec![
            field("x", 0, PointField::FLOAT32),
            field("y", 4, PointField::FLOAT32),
            field("z", 8, PointField::FLOAT32),
            field("rgb", 12, PointField::FLOAT32),
            field("session", 16, PointField::UINT32),
        ],
        is_bigendian: false,
        point_step: STEP,
        row_step: STEP * model.points3d.len() as u32,
        data,
        is_dense: true,
    };
    let mut images: Vec<_> = model.images.values().collect();
    images.sort_by(|a, b| a.name.cmp(&b.name));
    let mut paths: BTreeMap<String, Path> = BTreeMap::new();
    for image in &images {
        let path =
            paths.entry(session_of(&image.name)).or_insert_with(|| Path { header: header.clone(), poses: Vec::new() });
        path.poses.push(PoseStamped { header: header.clone(), pose: camera_pose(&image.cam_from_world) });
    }
    let cameras =
        PoseArray { header: header.clone(), poses: images.iter().map(|i| camera_pose(&i.cam_from_world)).collect() };
    let sessions = report
        .sessions
        .iter()
        .map(|(name, s)| SessionStatus {
            session: name.clone(),
            visit: s.visit as u32,
            images: s.images as u32,
            registered: s.registered as u32,
        })
        .collect();
    let status = MapStatus {
        header: header.clone(),
        state: MapStatus::READY,
        message: match report.unlinked_sessions.is_empty() {
            true => format!("{} images in one model", model.images.len()),
            false => format!("not linked: {}", report.unlinked_sessions.join(", ")),
        },
        sessions,
        points: model.points3d.len() as u32,
        mean_reprojection_error_px: report.mapping.mean_reprojection_error_px.unwrap_or(f64::NAN),
    };
    MapMessages { cloud, paths, cameras, status }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn features_survive_their_message() {
        let sift = Features {
            keypoints: vec![Keypoint { x: 1.5, y: 2.5, scale: 3.0, orientation: 0.25 }; 3],
            descriptors: (0..3 * 128).map(|i| i as u8).collect(),
            descriptor_dim: 128,
        };
        let message = sift_message(Header::default(), "s1", "a.png", [640, 480], &sift);
        assert_eq!(features_record(&message), Ok(FeaturesRecord::Sift(sift)));

        let learned = LearnedFeatures {
            keypoints: vec![[4.0, 5.0], [6.0, 7.0]],
            descriptors: (0..2 * 128).map(|i| i as f32 / 7.0).collect(),
            descriptor_dim: 128,
            scores: vec![0.5, 0.25],
            width: 640,
            height: 480,
        };
        let message = learned_message(Header::default(), "s1", "a.png", "aliked", Roll::R90, &learned);
        let record = FeaturesRecord::Learned { method: "aliked".into(), roll: Roll::R90, features: learned };
        assert_eq!(features_record(&message), Ok(record));
    }

    #[test]
    fn a_message_whose_lengths_disagree_is_refused() {
        let learned = LearnedFeatures {
            keypoints: vec![[1.0, 2.0]],
            descriptor_dim: 2,
            descriptors: vec![0.0; 2],
            scores: vec![1.0],
            width: 4,
            height: 4,
        };
        let mut message = learned_message(Header::default(), "s", "a", "aliked", Roll::R0, &learned);
        message.count = 2;
        assert!(features_record(&message).unwrap_err().contains("keypoints"));
        message.count = 1;
        message.roll_degrees = 45;
        assert!(features_record(&message).unwrap_err().contains("45"));
    }

    #[test]
    fn camera_info_gives_colmap_intrinsics() {
        let mut info = CameraInfo { k: [500.0, 0.0, 319.5, 0.0, 510.0, 239.5, 0.0, 0.0, 1.0], ..Default::default() };
        let spec = camera_spec(&info).unwrap();
        assert_eq!(spec.model.name(), "PINHOLE");
        assert_eq!(spec.params, vec![500.0, 510.0, 320.0, 240.0]);
        info.d = vec![0.1, 0.0, 0.0, 0.0, 0.0];
        assert_eq!(camera_spec(&info).unwrap().model.name(), "OPENCV");
        assert!(camera_spec(&CameraInfo::default()).is_none());
    }
}
