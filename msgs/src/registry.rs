//! Every message type by name, for code that meets types at run time (bags, tests).

use crate::{
    builtin_interfaces as bi, diagnostic_msgs as diag, geometry_msgs as geo, nav_msgs as nav, revisit_msgs as rv,
    rosgraph_msgs as graph, sample, sensor_msgs as sensor, std_msgs as std_, tf2_msgs as tf2, CdrError, Definition,
    Message,
};

/// A message type known at run time.
pub struct MessageType {
    pub definition: &'static Definition,
    /// Whether CDR bytes decode as this type.
    pub check: fn(&[u8]) -> Result<(), CdrError>,
    /// CDR bytes to the message's values as JSON (field names as in the `.msg` file).
    pub decode_json: fn(&[u8]) -> Result<serde_json::Value, CdrError>,
    /// A deterministic message with distinct values in every field ([`sample::message`]), as
    /// CDR and as JSON.
    pub sample: fn(u64) -> (Vec<u8>, serde_json::Value),
}

fn entry<M: Message>() -> MessageType {
    MessageType {
        definition: M::DEFINITION,
        check: |bytes| crate::decode::<M>(bytes).map(drop),
        decode_json: |bytes| {
            let message: M = crate::decode(bytes)?;
            Ok(serde_json::to_value(&message).unwrap_or_default())
        },
        sample: |seed| {
            let message: M = sample::message(seed);
            let bytes = crate::encode(&message).unwrap_or_default();
            (bytes, serde_json::to_value(&message).unwrap_or_default())
        },
    }
}

macro_rules! all {
    ($($ty:ty),* $(,)?) => {
        /// Every message type Revisit reads and writes.
        pub static ALL: std::sync::LazyLock<Vec<MessageType>> =
            std::sync::LazyLock::new(|| vec![$(entry::<$ty>()),*]);
    };
}

all!(
    bi::Time,
    bi::Duration,
    std_::Header,
    geo::Point,
    geo::Vector3,
    geo::Quaternion,
    geo::Pose,
    geo::PoseStamped,
    geo::PoseWithCovariance,
    geo::PoseWithCovarianceStamped,
    geo::PoseArray,
    geo::Transform,
    geo::TransformStamped,
    geo::Twist,
    geo::TwistWithCovariance,
    sensor::Image,
    sensor::CompressedImage,
    sensor::RegionOfInterest,
    sensor::CameraInfo,
    sensor::PointField,
    sensor::PointCloud2,
    sensor::NavSatStatus,
    sensor::NavSatFix,
    sensor::Imu,
    nav::Path,
    nav::Odometry,
    tf2::TFMessage,
    diag::KeyValue,
    diag::DiagnosticStatus,
    diag::DiagnosticArray,
    graph::Clock,
    rv::SessionControl,
    rv::Keyframe,
    rv::Features,
    rv::PlaceCandidate,
    rv::PlaceCandidates,
    rv::CrossVisitMatches,
    rv::SessionStatus,
    rv::MapStatus,
);

/// The type of this full ROS name (`sensor_msgs/msg/Image`; `sensor_msgs/Image` also accepted).
pub fn find(name: &str) -> Option<&'static MessageType> {
    let full = match name.split('/').collect::<Vec<_>>()[..] {
        [package, typ] => format!("{package}/msg/{typ}"),
        _ => name.to_owned(),
    };
    ALL.iter().find(|t| t.definition.name == full)
}
