//! `revisit service`: call the mapper node's services from a shell without a ROS install (with
//! one, `ros2 service call` does the same).

use std::path::PathBuf;
use std::time::Duration;

use anyhow::{bail, Result};
use revisit_msgs::services::{Save, SaveRequest, Service, Trigger, TriggerRequest};

use super::bag::in_node;

#[derive(clap::Subcommand)]
pub enum Command {
    /// Write the mapper's map as `revisit reconstruct` does (model/, points.ply, poses.csv,
    /// report.json) to a folder: `/mapper/save` (revisit_msgs/srv/Save).
    Save {
        /// The folder to write to (created if missing), on the mapper's computer; without it, the
        /// mapper's `save_dir` parameter.
        dir: Option<PathBuf>,
        #[command(flatten)]
        call: Call,
    },
    /// Map now, without waiting for the visit in progress to end: `/mapper/map`
    /// (std_srvs/srv/Trigger). Returns once the map is published.
    Map {
        #[command(flatten)]
        call: Call,
    },
}

/// Where the service is and how long to wait.
#[derive(clap::Args)]
pub struct Call {
    /// The mapper node's full name (its services are NODE/save and NODE/map).
    #[arg(long, default_value = "/mapper")]
    node: String,
    /// Seconds to wait for the mapper to appear.
    #[arg(long, default_value_t = 30.0)]
    wait: f64,
    /// ROS arguments, e.g. --ros-args -r __ns:=/auv.
    #[arg(long = "ros-args", num_args = 0.., allow_hyphen_values = true, value_name = "ARG")]
    ros_args: Vec<String>,
}

pub fn run(command: Command) -> Result<()> {
    let (success, message) = match command {
        Command::Save { dir, call } => {
            let directory = dir.map(|d| d.display().to_string()).unwrap_or_default();
            let response = call_service::<Save>(&call, "save", SaveRequest { directory })?;
            (response.success, response.message)
        }
        Command::Map { call } => {
            let response = call_service::<Trigger>(&call, "map", TriggerRequest::default())?;
            (response.success, response.message)
        }
    };
    if !success {
        bail!("{message}");
    }
    println!("{message}");
    Ok(())
}

fn call_service<S: Service>(call: &Call, service: &str, request: S::Request) -> Result<S::Response> {
    if !(call.wait.is_finite() && call.wait > 0.0) {
        bail!("--wait must be a positive number of seconds");
    }
    let name = format!("{}/{service}", call.node.trim_end_matches('/'));
    in_node("revisit_service_client", &call.ros_args, async |node| {
        let client = node.client::<S>(&name)?;
        // Waiting for the server, then for the work (a mapping takes minutes): no limit on that.
        let wait = Duration::from_secs_f64(call.wait);
        Ok(client.call(node, request, wait).await?)
    })
}
