//! Per-stage counters a node publishes on `/diagnostics` once a second.

use std::collections::BTreeMap;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Mutex};
use std::time::Duration;

use revisit_msgs::diagnostic_msgs::DiagnosticStatus;
use ros2_client::{Gid, MessageInfo};

use crate::node::key_value;

/// What one stage of a node has received, dropped, queued and done.
pub struct StageStats {
    name: String,
    received: AtomicU64,
    dropped: AtomicU64,
    /// Samples sent to this stage that never reached it (see [`Stage::sequenced`]).
    lost: AtomicU64,
    /// The newest sequence number seen from each publisher.
    sequences: Mutex<BTreeMap<Gid, i64>>,
    queued: AtomicU64,
    done: AtomicU64,
    busy_ns: AtomicU64,
    /// `(received, dropped + lost)` at the last report, for the rate and the level.
    last: Mutex<(u64, u64)>,
}

/// A handle the node's code counts with.
#[derive(Clone)]
pub struct Stage(pub(crate) Arc<StageStats>);

impl Stage {
    /// An item arrived.
    pub fn received(&self) {
        self.0.received.fetch_add(1, Ordering::Relaxed);
    }

    /// Items arrived.
    pub fn received_many(&self, count: u64) {
        self.0.received.fetch_add(count, Ordering::Relaxed);
    }

    /// Items were dropped (queue full, undecodable, not kept).
    pub fn dropped(&self, count: u64) {
        self.0.dropped.fetch_add(count, Ordering::Relaxed);
    }

    /// A sample arrived, numbered as its publisher numbers what it sends: the numbers skipped
    /// since that publisher's last sample are counted as lost (dropped in transport, as best
    /// effort allows, or overwritten in a full reader queue, before the node ever saw them).
    /// Returns how many were lost just before this one. A repeated or older number counts
    /// nothing.
    pub fn sequenced(&self, info: &MessageInfo) -> u64 {
        let mut sequences = self.0.sequences.lock().unwrap_or_else(|e| e.into_inner());
        let sequence = info.sequence_number();
        let lost = match sequences.get(&info.publisher_gid()) {
            Some(&last) if sequence > last => u64::try_from(sequence - last - 1).unwrap_or(0),
            Some(_) => return 0,
            None => 0,
        };
        sequences.insert(info.publisher_gid(), sequence);
        self.0.lost.fetch_add(lost, Ordering::Relaxed);
        lost
    }

    /// Items waiting now.
    pub fn queue_depth(&self, depth: usize) {
        self.0.queued.store(depth as u64, Ordering::Relaxed);
    }

    /// An item was done in `busy`.
    pub fn done(&self, busy: Duration) {
        self.0.done.fetch_add(1, Ordering::Relaxed);
        self.0.busy_ns.fetch_add(u64::try_from(busy.as_nanos()).unwrap_or(u64::MAX), Ordering::Relaxed);
    }

    /// `(received, dropped, done)` so far.
    pub fn counts(&self) -> (u64, u64, u64) {
        let s = &self.0;
        (s.received.load(Ordering::Relaxed), s.dropped.load(Ordering::Relaxed), s.done.load(Ordering::Relaxed))
    }

    /// Samples lost before they arrived, so far.
    pub fn lost(&self) -> u64 {
        self.0.lost.load(Ordering::Relaxed)
    }
}

impl StageStats {
    pub(crate) fn new(name: &str) -> StageStats {
        StageStats {
            name: name.to_owned(),
            received: AtomicU64::new(0),
            dropped: AtomicU64::new(0),
            lost: AtomicU64::new(0),
            sequences: Mutex::new(BTreeMap::new()),
            queued: AtomicU64::new(0),
            done: AtomicU64::new(0),
            busy_ns: AtomicU64::new(0),
            last: Mutex::new((0, 0)),
        }
    }

    /// The status since the last one, `seconds` ago: WARN while items are being dropped or lost.
    pub(crate) fn status(&self, node: &str, hardware_id: &str, seconds: f64) -> DiagnosticStatus {
        let received = self.received.load(Ordering::Relaxed);
        let dropped = self.dropped.load(Ordering::Relaxed);
        let lost = self.lost.load(Ordering::Relaxed);
        let done = self.done.load(Ordering::Relaxed);
        let busy_s = self.busy_ns.load(Ordering::Relaxed) as f64 * 1e-9;
        let mut last = self.last.lock().unwrap_or_else(|e| e.into_inner());
        let rate_hz = (received - last.0) as f64 / seconds.max(1e-9);
        let dropping = dropped + lost > last.1;
        *last = (received, dropped + lost);
        DiagnosticStatus {
            level: if dropping { DiagnosticStatus::WARN } else { DiagnosticStatus::OK },
            name: format!("{node}: {}", self.name),
            message: if dropping { "dropping items".into() } else { "ok".into() },
            hardware_id: hardware_id.to_owned(),
            values: vec![
                key_value("input_rate_hz", format!("{rate_hz:.2}")),
                key_value("queue_depth", self.queued.load(Ordering::Relaxed)),
                key_value("received", received),
                key_value("dropped", dropped),
                key_value("lost", lost),
                key_value("done", done),
                key_value("seconds_per_item", format!("{:.4}", if done > 0 { busy_s / done as f64 } else { 0.0 })),
            ],
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn status_reports_rate_drops_and_time_per_item() {
        let stage = Stage(Arc::new(StageStats::new("ingest")));
        for _ in 0..10 {
            stage.received();
        }
        stage.dropped(2);
        stage.done(Duration::from_millis(30));
        stage.done(Duration::from_millis(10));
        let status = stage.0.status("/auv/ingest", "host", 2.0);
        assert_eq!(status.name, "/auv/ingest: ingest");
        assert_eq!(status.level, DiagnosticStatus::WARN);
        let value = |k: &str| status.values.iter().find(|v| v.key == k).map(|v| v.value.clone()).unwrap_or_default();
        assert_eq!(value("input_rate_hz"), "5.00");
        assert_eq!(value("dropped"), "2");
        assert_eq!(value("seconds_per_item"), "0.0200");
        let again = stage.0.status("/auv/ingest", "host", 1.0);
        assert_eq!(again.level, DiagnosticStatus::OK);
        assert!(again.values.iter().any(|v| v.key == "input_rate_hz" && v.value == "0.00"));
    }

    #[test]
    fn gaps_in_each_publishers_numbers_are_lost_samples() {
        let stage = Stage(Arc::new(StageStats::new("frames")));
        let (camera, other) = (Gid::from([1; 16]), Gid::from([2; 16]));
        let sample = |publisher, sequence| MessageInfo::new(None, None, sequence, publisher, None);
        let lost: Vec<u64> = [(camera, 1), (camera, 2), (other, 7), (camera, 5), (camera, 5), (camera, 4), (other, 8)]
            .into_iter()
            .map(|(publisher, sequence)| stage.sequenced(&sample(publisher, sequence)))
            .collect();
        assert_eq!(lost, [0, 0, 0, 2, 0, 0, 0]);
        assert_eq!(stage.lost(), 2);
        let status = stage.0.status("/ingest", "host", 1.0);
        assert_eq!(status.level, DiagnosticStatus::WARN);
        assert!(status.values.iter().any(|v| v.key == "lost" && v.value == "2"));
    }
}
