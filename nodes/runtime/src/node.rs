//! A running node: ros2-client's node with what it leaves out filled in.

use std::sync::atomic::{AtomicI64, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use futures::StreamExt;
use revisit_msgs::builtin_interfaces::Time;
use revisit_msgs::diagnostic_msgs::{DiagnosticArray, DiagnosticStatus, KeyValue};
use revisit_msgs::rosgraph_msgs::Clock;
use revisit_msgs::std_msgs::Header;
use revisit_msgs::Message;
use ros2_client::dds::rustdds::{self, no_key};
use ros2_client::log::LogLevel;
use ros2_client::qos::{Durability, History, Reliability, WhenFull};
use ros2_client::{
    Context, MessageTypeName, Name, NodeName, NodeOptions, Publisher, QosProfile, RosoutRaw, Subscription,
};
use tokio::sync::watch;
use tokio::task::JoinHandle;

use crate::names::Names;
use crate::params::{Endpoint, Parameters};
use crate::raw::{RawAdapter, RawCdr};
use crate::stats::{Stage, StageStats};
use crate::{NodeError, RosArgs};

/// Reliable, keep the last 10: ROS 2's default.
pub const RELIABLE: QosProfile = QosProfile::publisher_default().history(History::KeepLast { depth: 10 });
/// Best effort, keep the last 5: ROS 2's sensor-data profile.
pub const SENSOR_DATA: QosProfile = QosProfile::subscription_default().history(History::KeepLast { depth: 5 });
/// Reliable and transient-local, keep the last 1: a late subscriber (Foxglove, RViz) gets the
/// latest value.
pub const LATCHED: QosProfile = QosProfile::publisher_default()
    .durability(Durability::TransientLocal)
    .reliability(Reliability::Reliable { when_full: WhenFull::DEFAULT })
    .history(History::KeepLast { depth: 1 });

/// Reliable and transient-local, keep the last 256: a work queue between nodes. A subscriber that
/// starts late or restarts receives the backlog the publisher still holds, and skips what its own
/// state says is done; a reader that falls behind slows the writer instead of losing items.
pub const WORK_QUEUE: QosProfile = LATCHED.history(History::KeepLast { depth: 256 });

/// A raw DDS writer for a type met at run time.
pub type RawPublisher = no_key::DataWriter<RawCdr, RawAdapter>;
/// A raw DDS reader for a type met at run time.
pub type RawSubscription = no_key::SimpleDataReader<RawCdr, RawAdapter>;

/// A topic announced in the domain.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct DiscoveredTopic {
    /// The ROS name, e.g. `/camera/image`.
    pub name: String,
    /// The ROS type name, e.g. `sensor_msgs/msg/Image`.
    pub type_name: String,
    /// Offered reliable.
    pub reliable: bool,
    /// Offered transient-local (latched: a late subscriber gets the last values).
    pub transient_local: bool,
}

/// One node in a DDS domain. Start it inside a tokio runtime: its background work (ros2-client's
/// spinner, `/clock`, `/diagnostics`, the signal handler) runs as tasks there.
/// End it with [`Node::shutdown`], which stops that work before DDS goes away.
pub struct Node {
    names: Names,
    parameters: Parameters,
    sim_time_ns: Option<Arc<AtomicI64>>,
    stages: Arc<Mutex<Vec<Arc<StageStats>>>>,
    stop: watch::Receiver<bool>,
    tasks: Vec<JoinHandle<()>>,
    spinner: Option<JoinHandle<()>>,
    raw_publisher: Option<rustdds::Publisher>,
    raw_subscriber: Option<rustdds::Subscriber>,
    // Dropped last: DDS entities must go before their participant.
    ros: ros2_client::Node,
    context: Context,
}

impl Node {
    /// Starts node `default_name` (or what `-r __node:=` says) in the domain ROS's variables name
    /// ([`Domain::from_env`]).
    pub fn start(default_name: &str, args: &RosArgs) -> Result<Node, NodeError> {
        Node::start_in(Domain::from_env()?, default_name, args)
    }

    /// [`Node::start`] in a given domain (several graphs in one process: tests, `--single-process`).
    pub fn start_in(domain: Domain, default_name: &str, args: &RosArgs) -> Result<Node, NodeError> {
        let name = args.node_name.as_deref().unwrap_or(default_name);
        let names = Names::new(args.namespace.as_deref().unwrap_or("/"), name, &args.remaps)?;
        let parameters = Parameters::from_args(args, names.namespace(), names.name())?;
        let use_sim_time = parameters.get("use_sim_time", false)?;

        let mut participant = rustdds::DomainParticipantBuilder::new(domain.id);
        if domain.localhost_only {
            participant = participant.with_only_networks([std::net::Ipv4Addr::LOCALHOST]);
        }
        let context = Context::from_domain_participant(participant.build().map_err(dds)?).map_err(dds)?;
        // ros2-client's own sim time listens for the wrong type, so `use_sim_time` stays ours.
        let mut options = NodeOptions::new().enable_rosout(true).allow_undeclared_parameters(true);
        for (name, value) in parameters.ros_values().filter(|(n, _)| *n != "use_sim_time") {
            options = options.declare_parameter(name, value);
        }
        let node_name = NodeName::new(names.namespace(), names.name()).map_err(|e| NodeError::Args(e.to_string()))?;
        let mut ros = context.new_node(node_name, options).map_err(dds)?;
        let spinner = ros.spinner().map_err(dds)?;
        let spinner = tokio::spawn(async move {
            if let Err(error) = spinner.spin().await {
                tracing::warn!("ros2-client's spinner stopped: {error:?}");
            }
        });

        let (stop_sender, stop) = watch::channel(false);
        let signals = tokio::spawn(async move {
            wait_for_signal().await;
            let _ = stop_sender.send(true);
        });

        let mut node = Node {
            context,
            ros,
            names,
            parameters,
            sim_time_ns: None,
            stages: Arc::default(),
            stop,
            tasks: vec![signals],
            spinner: Some(spinner),
            raw_publisher: None,
            raw_subscriber: None,
        };
        if use_sim_time {
            node.follow_clock()?;
        }
        node.publish_diagnostics()?;
        Ok(node)
    }

    pub(crate) fn ros(&self) -> &ros2_client::Node {
        &self.ros
    }

    pub(crate) fn ros_mut(&mut self) -> &mut ros2_client::Node {
        &mut self.ros
    }

    /// The node's name (`/namespace/name`).
    pub fn full_name(&self) -> String {
        self.names.full_name()
    }

    pub fn names(&self) -> &Names {
        &self.names
    }

    pub fn parameters(&self) -> &Parameters {
        &self.parameters
    }

    /// The DDS domain the node is in.
    pub fn domain_id(&self) -> u16 {
        self.context.domain_id()
    }

    /// The parameter `name`, or `default`; a wrong type is an error naming it.
    pub fn param<T: serde::de::DeserializeOwned>(&self, name: &str, default: T) -> Result<T, NodeError> {
        self.parameters.get(name, default)
    }

    /// A publisher of `M` on `topic` (resolved and remapped), QoS `default` unless
    /// `qos_overrides.TOPIC.publisher.*` say otherwise.
    pub fn publisher<M: Message>(&mut self, topic: &str, default: QosProfile) -> Result<Publisher<M>, NodeError> {
        let (topic, qos) = self.topic(topic, M::DEFINITION.name, Endpoint::Publisher, default)?;
        self.ros.create_publisher(&topic, Some(qos)).map_err(dds)
    }

    /// A subscription to `M` on `topic`, QoS as for [`Node::publisher`] with `.subscription.`.
    pub fn subscription<M: Message>(&mut self, topic: &str, default: QosProfile) -> Result<Subscription<M>, NodeError> {
        let (topic, qos) = self.topic(topic, M::DEFINITION.name, Endpoint::Subscription, default)?;
        self.ros.create_subscription(&topic, Some(qos)).map_err(dds)
    }

    /// A writer of CDR bytes of type `type_name` (`pkg/msg/Type`) on `topic`.
    pub fn raw_publisher(
        &mut self,
        topic: &str,
        type_name: &str,
        default: QosProfile,
    ) -> Result<RawPublisher, NodeError> {
        let (topic, qos) = self.topic(topic, type_name, Endpoint::Publisher, default)?;
        let qos = rustdds::QosPolicies::from(&qos);
        let publisher = match &self.raw_publisher {
            Some(p) => p.clone(),
            None => {
                let p = self.context.domain_participant().create_publisher(&qos).map_err(dds)?;
                self.raw_publisher.insert(p).clone()
            }
        };
        publisher.create_datawriter_no_key::<RawCdr, RawAdapter>(&topic, Some(qos)).map_err(dds)
    }

    /// A reader of CDR bytes of type `type_name` on `topic`.
    pub fn raw_subscription(
        &mut self,
        topic: &str,
        type_name: &str,
        default: QosProfile,
    ) -> Result<RawSubscription, NodeError> {
        let (topic, qos) = self.topic(topic, type_name, Endpoint::Subscription, default)?;
        let qos = rustdds::QosPolicies::from(&qos);
        let subscriber = match &self.raw_subscriber {
            Some(s) => s.clone(),
            None => {
                let s = self.context.domain_participant().create_subscriber(&qos).map_err(dds)?;
                self.raw_subscriber.insert(s).clone()
            }
        };
        subscriber.create_simple_datareader_no_key::<RawCdr, RawAdapter>(&topic, Some(qos)).map_err(dds)
    }

    fn topic(
        &self,
        name: &str,
        type_name: &str,
        endpoint: Endpoint,
        default: QosProfile,
    ) -> Result<(rustdds::Topic, QosProfile), NodeError> {
        let resolved = self.names.resolve(name)?;
        let qos = self.parameters.qos(&resolved, endpoint, default)?;
        let (package, ty) = match type_name.split('/').collect::<Vec<_>>()[..] {
            [package, "msg", ty] | [package, ty] => (package, ty),
            _ => return Err(NodeError::Args(format!("{type_name:?} is not a message type name (pkg/msg/Type)"))),
        };
        let ros_name = Name::parse(&resolved).map_err(|e| NodeError::Args(format!("topic {resolved:?}: {e}")))?;
        let topic = self.ros.create_topic(&ros_name, MessageTypeName::new(package, ty), &qos).map_err(dds)?;
        Ok((topic, qos))
    }

    /// Stops the node's background work, then leaves the domain (peers are told).
    pub async fn shutdown(self) {
        let Node { tasks, spinner, raw_publisher, raw_subscriber, ros, context, .. } = self;
        for task in tasks {
            task.abort();
            let _ = task.await;
        }
        drop((raw_publisher, raw_subscriber));
        // Dropping ros2-client's node tells its spinner to stop.
        drop(ros);
        if let Some(spinner) = spinner {
            if tokio::time::timeout(Duration::from_secs(2), spinner).await.is_err() {
                tracing::debug!("the spinner did not stop in 2 s");
            }
        }
        drop(context);
    }

    /// The topics publishers or subscribers in the domain have announced.
    pub fn discovered_topics(&self) -> Vec<DiscoveredTopic> {
        let mut topics: Vec<DiscoveredTopic> = self
            .context
            .discovered_topics_raw()
            .into_iter()
            .filter_map(|t| {
                let data = t.topic_data;
                let name = data.name.strip_prefix("rt")?.to_owned();
                let (package, rest) = data.type_name.split_once("::msg::dds_::")?;
                let type_name = format!("{package}/msg/{}", rest.strip_suffix('_')?);
                let reliable = matches!(data.reliability, Some(rustdds::policy::Reliability::Reliable { .. }));
                let transient_local = matches!(data.durability, Some(rustdds::policy::Durability::TransientLocal));
                Some(DiscoveredTopic { name, type_name, reliable, transient_local })
            })
            .collect();
        topics.sort_by(|a, b| a.name.cmp(&b.name));
        topics.dedup_by(|a, b| a.name == b.name);
        topics
    }

    /// How many readers in the domain (this process's included) subscribe to `topic` (resolved).
    pub fn readers_of(&self, topic: &str) -> usize {
        let dds_name = format!("rt{topic}");
        let readers = self.context.domain_participant().discovered_readers();
        readers.iter().filter(|r| r.subscription_topic_data.topic_name == dds_name).count()
    }

    /// The DDS identities of the other readers of `topic` (absolute) in the domain; with a
    /// subscription's own `guid()`, the members of a group of nodes sharing work.
    pub fn other_readers(&self, topic: &str) -> Vec<rustdds::GUID> {
        let dds_name = format!("rt{topic}");
        let readers = self.context.domain_participant().discovered_readers();
        readers
            .iter()
            .filter(|r| r.subscription_topic_data.topic_name == dds_name)
            .map(|r| r.reader_proxy.remote_reader_guid)
            .collect()
    }

    /// The node's time: the latest `/clock` with `use_sim_time` (zero until one arrives), else
    /// the system clock.
    pub fn now(&self) -> Time {
        time_now(self.sim_time_ns.as_deref())
    }

    /// A header stamped now.
    pub fn header(&self, frame_id: &str) -> Header {
        Header { stamp: self.now(), frame_id: frame_id.to_owned() }
    }

    /// Counters for one stage of the node's work, published on `/diagnostics`.
    pub fn stage(&self, name: &str) -> Stage {
        let stats = Arc::new(StageStats::new(name));
        self.stages.lock().unwrap_or_else(|e| e.into_inner()).push(Arc::clone(&stats));
        Stage(stats)
    }

    /// Resolves once SIGINT or SIGTERM arrived.
    pub fn stopped(&self) -> impl std::future::Future<Output = ()> + Send + 'static {
        let mut stop = self.stop.clone();
        async move {
            let _ = stop.wait_for(|stop| *stop).await;
        }
    }

    /// Whether SIGINT or SIGTERM arrived.
    pub fn stopping(&self) -> bool {
        *self.stop.borrow()
    }

    /// Logs to the terminal and `/rosout`.
    pub fn log(&self, level: LogLevel, message: &str) {
        let name = self.names.full_name();
        match level {
            LogLevel::Fatal | LogLevel::Error => tracing::error!("[{name}] {message}"),
            LogLevel::Warn => tracing::warn!("[{name}] {message}"),
            LogLevel::Info => tracing::info!("[{name}] {message}"),
            LogLevel::Debug => tracing::debug!("[{name}] {message}"),
        }
        let stamp = ros2_client::builtin_interfaces::Time::from_nanos(wall_clock_ns());
        self.ros.rosout_raw(stamp, level, self.names.name(), message, file!(), "", line!());
    }

    fn follow_clock(&mut self) -> Result<(), NodeError> {
        let clock = self.subscription::<Clock>("/clock", QosProfile::subscription_default())?;
        let now = Arc::new(AtomicI64::new(0));
        self.sim_time_ns = Some(Arc::clone(&now));
        self.tasks.push(tokio::spawn(async move {
            let mut stream = std::pin::pin!(clock.async_stream());
            while let Some(message) = stream.next().await {
                if let Ok((message, _)) = message {
                    now.store(message.clock.as_nanos(), Ordering::Relaxed);
                }
            }
        }));
        Ok(())
    }

    fn publish_diagnostics(&mut self) -> Result<(), NodeError> {
        let publisher = self.publisher::<DiagnosticArray>("/diagnostics", RELIABLE)?;
        let stages = Arc::clone(&self.stages);
        let name = self.names.full_name();
        let hardware_id = std::fs::read_to_string("/etc/hostname").unwrap_or_default().trim().to_owned();
        let sim_time = self.sim_time_ns.clone();
        self.tasks.push(tokio::spawn(async move {
            let mut tick = tokio::time::interval(Duration::from_secs(1));
            let mut last = Instant::now();
            loop {
                tick.tick().await;
                let seconds = last.elapsed().as_secs_f64();
                last = Instant::now();
                let status: Vec<DiagnosticStatus> = {
                    let stages = stages.lock().unwrap_or_else(|e| e.into_inner());
                    stages.iter().map(|s| s.status(&name, &hardware_id, seconds)).collect()
                };
                if status.is_empty() {
                    continue;
                }
                let stamp = time_now(sim_time.as_deref());
                let message = DiagnosticArray { header: Header { stamp, frame_id: String::new() }, status };
                if publisher.async_publish(message).await.is_err() {
                    break;
                }
            }
        }));
        Ok(())
    }
}

/// A diagnostic status's key-value pair.
pub(crate) fn key_value(key: &str, value: impl ToString) -> KeyValue {
    KeyValue { key: key.to_owned(), value: value.to_string() }
}

/// A DDS domain and whether to stay on this machine.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Domain {
    pub id: u16,
    pub localhost_only: bool,
}

impl Domain {
    /// What ROS's variables say: `ROS_DOMAIN_ID` (0 if unset), and loopback only with
    /// `ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST` (Jazzy) or `ROS_LOCALHOST_ONLY=1` (Humble).
    pub fn from_env() -> Result<Domain, NodeError> {
        let id = match std::env::var("ROS_DOMAIN_ID") {
            Err(_) => 0,
            Ok(text) if text.trim().is_empty() => 0,
            Ok(text) => match text.trim().parse::<u16>() {
                Ok(id) if id <= 232 => id,
                _ => return Err(NodeError::Args(format!("ROS_DOMAIN_ID={text:?} is not a domain id (0-232)"))),
            },
        };
        let localhost_only = std::env::var("ROS_AUTOMATIC_DISCOVERY_RANGE")
            .is_ok_and(|v| v.eq_ignore_ascii_case("localhost"))
            || std::env::var("ROS_LOCALHOST_ONLY").is_ok_and(|v| v.trim() == "1");
        Ok(Domain { id, localhost_only })
    }
}

/// The latest `/clock` time when following one, else the system clock.
fn time_now(sim_time_ns: Option<&AtomicI64>) -> Time {
    match sim_time_ns {
        Some(ns) => Time::from_nanos(ns.load(Ordering::Relaxed)),
        None => Time::from_nanos(wall_clock_ns()),
    }
}

fn wall_clock_ns() -> i64 {
    std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map_or(0, |d| i64::try_from(d.as_nanos()).unwrap_or(i64::MAX))
}

async fn wait_for_signal() {
    use tokio::signal::unix::{signal, SignalKind};
    let (Ok(mut interrupt), Ok(mut terminate)) = (signal(SignalKind::interrupt()), signal(SignalKind::terminate()))
    else {
        return std::future::pending().await;
    };
    tokio::select! {
        _ = interrupt.recv() => {}
        _ = terminate.recv() => {}
    }
}

pub(crate) fn dds(error: impl std::fmt::Debug) -> NodeError {
    NodeError::Dds(format!("{error:?}"))
}
