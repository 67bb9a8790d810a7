//! A vehicle's recent odometry, to give each keyframe the pose the vehicle had when the frame was
//! taken: camera and odometry topics arrive in no fixed order with each other, so a frame is
//! matched to odometry by stamp, interpolated between the two messages around it. Sans-IO.

use std::collections::VecDeque;

use revisit_msgs::geometry_msgs::{Point, PoseWithCovariance};

/// Odometry messages kept (at 50 Hz, 10 s).
const KEPT: usize = 500;

/// How far from the nearest odometry a frame may be, outside the span odometry covers, and
/// still take its pose, ns.
const NEAREST_WITHIN_NS: u64 = 500_000_000;

/// The newest odometry poses, by stamp (a live stream's last 10 s by default, or a whole
/// recording's with [`OdometryTrack::whole`]).
pub struct OdometryTrack {
    poses: VecDeque<(u64, PoseWithCovariance)>,
    kept: usize,
}

impl Default for OdometryTrack {
    fn default() -> Self {
        OdometryTrack { poses: VecDeque::new(), kept: KEPT }
    }
}

impl OdometryTrack {
    /// A track that keeps every pose (a recording read from start to end).
    pub fn whole() -> Self {
        OdometryTrack { poses: VecDeque::new(), kept: usize::MAX }
    }

    /// Keeps a pose stamped `stamp_ns` (out of order ones are placed by stamp).
    pub fn push(&mut self, stamp_ns: u64, pose: PoseWithCovariance) {
        let at = self.poses.partition_point(|(t, _)| *t <= stamp_ns);
        self.poses.insert(at, (stamp_ns, pose));
        if self.poses.len() > self.kept {
            self.poses.pop_front();
        }
    }

    /// Whether any odometry has come.
    pub fn is_empty(&self) -> bool {
        self.poses.is_empty()
    }

    /// Whether odometry at or after `stamp_ns` has come (so [`OdometryTrack::at`] interpolates).
    pub fn covers(&self, stamp_ns: u64) -> bool {
        self.poses.back().is_some_and(|(t, _)| *t >= stamp_ns)
    }

    /// The pose at `stamp_ns`: positions interpolated linearly between the poses around it (the
    /// orientation and covariance of the nearer), or the nearest pose within half a second.
    pub fn at(&self, stamp_ns: u64) -> Option<PoseWithCovariance> {
        let after = self.poses.partition_point(|(t, _)| *t < stamp_ns);
        let nearest =
            |(t, pose): &(u64, PoseWithCovariance)| (t.abs_diff(stamp_ns) <= NEAREST_WITHIN_NS).then_some(*pose);
        match (after.checked_sub(1).and_then(|i| self.poses.get(i)), self.poses.get(after)) {
            (Some((t0, p0)), Some((t1, p1))) => {
                let fraction = if t1 > t0 { (stamp_ns - t0) as f64 / (t1 - t0) as f64 } else { 0.0 };
                let (a, b) = (p0.pose.position, p1.pose.position);
                let lerp = |u: f64, v: f64| u + fraction * (v - u);
                let mut pose = if fraction < 0.5 { *p0 } else { *p1 };
                pose.pose.position = Point { x: lerp(a.x, b.x), y: lerp(a.y, b.y), z: lerp(a.z, b.z) };
                Some(pose)
            }
            (Some(before), None) => nearest(before),
            (None, Some(after)) => nearest(after),
            (None, None) => None,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn at_x(x: f64) -> PoseWithCovariance {
        let mut pose = PoseWithCovariance::default();
        pose.pose.position.x = x;
        pose
    }

    #[test]
    fn a_frame_takes_the_pose_interpolated_at_its_stamp() {
        let mut track = OdometryTrack::default();
        assert!(track.is_empty() && track.at(0).is_none());
        // Out of order, as topics come.
        for (t, x) in [(2_000_000_000, 2.0), (1_000_000_000, 1.0), (3_000_000_000, 3.0)] {
            track.push(t, at_x(x));
        }
        let x = |t| track.at(t).map(|p| p.pose.position.x);
        assert_eq!(x(1_500_000_000), Some(1.5));
        assert_eq!(x(2_000_000_000), Some(2.0));
        assert_eq!(x(3_400_000_000), Some(3.0));
        assert_eq!(x(3_600_000_000), None);
        assert_eq!(x(600_000_000), Some(1.0));
        assert!(track.covers(3_000_000_000) && !track.covers(3_000_000_001));
    }
}
