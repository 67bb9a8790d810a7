//! The runtime every Revisit ROS 2 node shares, over `ros2-client` (RustDDS) on tokio.
//!
//! It fills what `ros2-client` leaves out: the domain from `ROS_DOMAIN_ID`; `--ros-args` as ROS
//! users type them (`-p`, `--params-file`, `-r`, `__ns`, `__node`) with relative names resolved in
//! the node's namespace; `use_sim_time` driven by `rosgraph_msgs/Clock` on `/clock`; QoS per topic
//! from ROS's `qos_overrides.TOPIC.publisher|subscription.*` parameters; `/diagnostics` once a
//! second per stage; logging to the terminal and `/rosout`; SIGINT and SIGTERM as a stop request
//! the node's loop selects on. Messages are `revisit-msgs` types; tools that meet types at run
//! time publish and read raw CDR.

mod args;
mod journal;
mod names;
mod node;
mod params;
mod raw;
mod replay;
mod services;
mod stats;

pub use args::{read_params_file, ParameterSource, Remap, RosArgs};
pub use journal::Journal;
pub use names::Names;
pub use node::{
    DiscoveredTopic, Domain, Node, RawPublisher, RawSubscription, LATCHED, RELIABLE, SENSOR_DATA, WORK_QUEUE,
};
pub use params::{Endpoint, Parameters};
pub use raw::{RawAdapter, RawCdr};
pub use replay::{play, record, PlayOptions, Played, RecordOptions, ReplayError};
pub use ros2_client::dds::rustdds::GUID as Guid;
pub use ros2_client::log::LogLevel;
pub use ros2_client::qos::{Durability, History, Reliability};
pub use ros2_client::{MessageInfo, Publisher, QosProfile, Subscription};
pub use services::{Client, RequestId, Server};
pub use stats::Stage;

/// Log filter directives that keep DDS's chatter off the terminal: RustDDS narrates discovery at
/// info level, warns about every large message it fragments, and complains about leaving
/// multicast groups it never joined (loopback only).
pub const QUIET_DDS: &str =
    "rustdds=error,ros2_client=warn,rosout_raw=off,ros2_client::distributions=error,rustdds::network::udp_listener=off";

/// Terminal logging for a node process: info and up, `RUST_LOG` overriding.
pub fn init_logging() {
    use tracing_subscriber::EnvFilter;
    let filter = EnvFilter::try_from_default_env().unwrap_or_else(|_| EnvFilter::new(format!("info,{QUIET_DDS}")));
    tracing_subscriber::fmt().with_env_filter(filter).with_writer(std::io::stderr).with_target(false).init();
}

/// What can go wrong starting or running a node; each names what is at fault.
#[derive(Debug, thiserror::Error)]
pub enum NodeError {
    /// A command-line argument, name or environment variable.
    #[error("{0}")]
    Args(String),
    /// A parameter's value.
    #[error("parameter {name}: {reason}")]
    Parameter { name: String, reason: String },
    /// DDS (RustDDS) refused.
    #[error("DDS: {0}")]
    Dds(String),
    /// The node's persistent state could not be read or written.
    #[error("state: {0}")]
    State(String),
    /// The node's work failed (the message says on what).
    #[error("{0}")]
    Work(String),
}
