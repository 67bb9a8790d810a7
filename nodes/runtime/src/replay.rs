//! `bag play` and `bag record`: a bag's topics published at the bag's pace (with `/clock`), and
//! topics in the domain recorded to a rosbag2 mcap bag.

use std::collections::BTreeMap;
use std::path::Path;
use std::time::{Duration, Instant};

use revisit_bag::{Bag, BagError, BagWriter, WrittenBag};
use revisit_msgs::builtin_interfaces::Time;
use revisit_msgs::rosgraph_msgs::Clock;
use ros2_client::qos::{Durability, History, Reliability, WhenFull};
use ros2_client::QosProfile;

use crate::node::{dds, Node, RawPublisher, RawSubscription, LATCHED, RELIABLE};
use crate::raw::RawCdr;
use crate::NodeError;

/// How long discovery takes to finish both ways on one machine, with room to spare.
const MATCH_GRACE: Duration = Duration::from_millis(1000);
/// How long `play` waits for subscribers to acknowledge the last messages.
const ACK_WAIT: Duration = Duration::from_secs(30);

/// How a bag is played.
#[derive(Clone, Debug)]
pub struct PlayOptions {
    /// Speed against the bag's own pace; 0 publishes as fast as the subscribers take messages
    /// (reliable, keep all: a publisher waits for the slowest).
    pub rate: f64,
    /// Publish `/clock` (rosgraph_msgs/Clock) with the bag's time, for `use_sim_time` nodes.
    pub clock: bool,
    /// Only these topics (as stored in the bag); empty: all.
    pub topics: Vec<String>,
    /// Wait until every topic has a subscriber (and a moment more) before starting.
    pub wait_for_subscribers: bool,
    /// Seconds to wait before the first message (discovery).
    pub delay_s: f64,
}

impl Default for PlayOptions {
    fn default() -> Self {
        Self { rate: 1.0, clock: false, topics: Vec::new(), wait_for_subscribers: false, delay_s: 0.0 }
    }
}

/// What a play did.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Played {
    pub published: u64,
    /// Messages left out: unreadable, or not little-endian CDR.
    pub skipped: u64,
    pub seconds: f64,
}

/// What can go wrong replaying or recording.
#[derive(Debug, thiserror::Error)]
pub enum ReplayError {
    #[error(transparent)]
    Bag(#[from] BagError),
    #[error(transparent)]
    Node(#[from] NodeError),
    #[error("{0}")]
    Invalid(String),
}

/// Publishes the bag's messages in log-time order at `rate` times their pace; `progress` is
/// told each message published, with the number to publish. Returns early (with what was done) when the node is stopped.
pub async fn play(
    node: &mut Node,
    bag: &Bag,
    options: &PlayOptions,
    progress: &dyn Fn(u64, u64),
) -> Result<Played, ReplayError> {
    if !(options.rate >= 0.0 && options.rate.is_finite()) {
        return Err(ReplayError::Invalid(format!("--rate {} must be a number >= 0", options.rate)));
    }
    let info = bag.info()?;
    for wanted in &options.topics {
        if !info.topics.iter().any(|t| &t.topic.name == wanted) {
            return Err(ReplayError::Invalid(format!("{}: no topic {wanted}", bag.path().display())));
        }
    }
    let qos = if options.rate == 0.0 {
        QosProfile::publisher_default()
            .history(History::KeepAll)
            .reliability(Reliability::Reliable { when_full: WhenFull::Block })
    } else {
        RELIABLE.history(History::KeepLast { depth: 100 })
    };
    // Each bag topic's writer, under the name it is published as (remapped).
    let mut writers: BTreeMap<String, (String, RawPublisher)> = BTreeMap::new();
    let mut total = 0;
    for stats in &info.topics {
        let topic = &stats.topic;
        if options.topics.is_empty() || options.topics.contains(&topic.name) {
            total += stats.count;
            let published = node.names().resolve(&topic.name)?;
            // Latched when it was recorded latched (session control, maps): a late subscriber
            // still gets it. Reliable always: it matches best-effort subscribers too.
            let qos = match topic.offered {
                Some(offered) if offered.transient_local => qos.clone().durability(Durability::TransientLocal),
                _ => qos.clone(),
            };
            let writer = node.raw_publisher(&topic.name, &topic.type_name, qos)?;
            writers.insert(topic.name.clone(), (published, writer));
        }
    }
    let clock = match options.clock {
        true => Some(node.publisher::<Clock>("/clock", RELIABLE.history(History::KeepLast { depth: 1 }))?),
        false => None,
    };
    if options.wait_for_subscribers {
        while !node.stopping() && writers.values().any(|(name, _)| node.readers_of(name) == 0) {
            tokio::time::sleep(Duration::from_millis(50)).await;
        }
        // We know the readers; give them the same moment to know our writers, or a volatile
        // reader drops what comes before.
        tokio::time::sleep(MATCH_GRACE).await;
    }
    tokio::time::sleep(Duration::from_secs_f64(options.delay_s.max(0.0))).await;

    let started = Instant::now();
    let mut played = Played::default();
    let mut first_ns = None;
    for message in bag.messages() {
        if node.stopping() {
            break;
        }
        let message = match message {
            Ok(message) => message,
            Err(BagError::BadMessage { .. }) => {
                played.skipped += 1;
                continue;
            }
            Err(error) => return Err(error.into()),
        };
        let Some((_, writer)) = writers.get(&message.topic.name) else { continue };
        let Some(raw) = RawCdr::from_encapsulated(&message.data) else {
            played.skipped += 1;
            continue;
        };
        let first = *first_ns.get_or_insert(message.log_time_ns);
        if options.rate > 0.0 {
            let due = Duration::from_secs_f64(message.log_time_ns.saturating_sub(first) as f64 * 1e-9 / options.rate);
            if let Some(wait) = due.checked_sub(started.elapsed()) {
                tokio::select! {
                    () = tokio::time::sleep(wait) => {}
                    () = node.stopped() => break,
                }
            }
        }
        if let Some(clock) = &clock {
            let time = Time::from_nanos(i64::try_from(message.log_time_ns).unwrap_or(i64::MAX));
            clock.async_publish(Clock { clock: time }).await.map_err(dds)?;
        }
        writer.async_write(raw, None).await.map_err(dds)?;
        played.published += 1;
        progress(played.published, total);
    }
    // Every reliable reader has the last messages before the writers go (a busy graph can take a
    // while to acknowledge).
    for (topic, (_, writer)) in &writers {
        if tokio::time::timeout(ACK_WAIT, writer.async_wait_for_acknowledgments()).await.is_err() {
            tracing::warn!("{topic}: not every subscriber acknowledged the last messages within {ACK_WAIT:?}");
        }
    }
    played.seconds = started.elapsed().as_secs_f64();
    Ok(played)
}

/// How topics are recorded.
#[derive(Clone, Debug, Default)]
pub struct RecordOptions {
    /// Topic names (resolved in the node's namespace).
    pub topics: Vec<String>,
    /// Stop after this long.
    pub duration: Option<Duration>,
    /// Stop after this many messages.
    pub max_messages: Option<u64>,
}

/// Records `options.topics` into a new bag folder `out` until the node is stopped or a limit is
/// reached. A topic is subscribed once a publisher of it is discovered (its type then known);
/// the subscription is reliable when the topic is offered reliable, else best effort, and
/// transient-local when it is offered so (a latched topic's last value is recorded too).
pub async fn record(
    node: &mut Node,
    out: &Path,
    options: &RecordOptions,
    progress: &dyn Fn(u64),
) -> Result<WrittenBag, ReplayError> {
    if options.topics.is_empty() {
        return Err(ReplayError::Invalid("name at least one topic to record".into()));
    }
    let wanted = options.topics.iter().map(|t| node.names().resolve(t)).collect::<Result<Vec<_>, _>>()?;
    let mut writer = BagWriter::create(out)?;
    let mut readers: Vec<(usize, RawSubscription)> = Vec::new();
    let mut pending = wanted.clone();
    let started = Instant::now();
    let mut recorded = 0u64;
    tracing::info!("waiting for {} to appear; Ctrl-C stops", wanted.join(", "));
    let deadline = options.duration.map(|d| started + d);
    loop {
        if node.stopping() || deadline.is_some_and(|d| Instant::now() >= d) {
            break;
        }
        if options.max_messages.is_some_and(|max| recorded >= max) {
            break;
        }
        if !pending.is_empty() {
            for found in node.discovered_topics() {
                let Some(index) = pending.iter().position(|t| *t == found.name) else { continue };
                let known = revisit_msgs::find(&found.type_name).ok_or_else(|| {
                    ReplayError::Invalid(format!(
                        "topic {}: type {} is not one Revisit knows",
                        found.name, found.type_name
                    ))
                })?;
                let (qos, bag_qos) = match (found.reliable, found.transient_local) {
                    (true, true) => {
                        (LATCHED.history(History::KeepLast { depth: 100 }), revisit_bag::QosProfile::LATCHED)
                    }
                    (true, false) => {
                        (RELIABLE.history(History::KeepLast { depth: 100 }), revisit_bag::QosProfile::RELIABLE)
                    }
                    (false, _) => (
                        QosProfile::subscription_default().history(History::KeepLast { depth: 100 }),
                        revisit_bag::QosProfile::SENSOR_DATA,
                    ),
                };
                let reader = node.raw_subscription(&found.name, &found.type_name, qos)?;
                let reliability = if found.reliable { "reliable" } else { "best effort" };
                tracing::info!("recording {} ({}, {reliability})", found.name, found.type_name);
                let id = writer.add_raw_topic(&found.name, known.definition, bag_qos)?;
                readers.push((id, reader));
                pending.remove(index);
            }
        }
        let mut took = false;
        for (id, reader) in &readers {
            while let Ok(Some(sample)) = reader.try_take_one() {
                let log_time_ns = u64::try_from(node.now().as_nanos()).unwrap_or_default();
                writer.write_raw(*id, log_time_ns, &sample.sample.encapsulated())?;
                recorded += 1;
                took = true;
                progress(recorded);
            }
        }
        if !took {
            tokio::select! {
                () = tokio::time::sleep(Duration::from_millis(2)) => {}
                () = node.stopped() => {}
            }
        }
    }
    Ok(writer.finish()?)
}
