//! `revisit launch FILE`: starts Revisit's node graph as a launch file describes it, one process
//! per node (or all in this one with `--single-process`), passing parameters and remappings as
//! `--ros-args`, forwarding Ctrl-C and SIGTERM, and respawning a node that dies when asked to.
//!
//! The file (YAML):
//! ```yaml
//! namespace: /revisit              # optional, every node's namespace
//! parameters: {use_sim_time: true} # optional, given to every node
//! nodes:
//!   - node: ingest                 # which node (Revisit has: ingest, features, places, matcher, mapper)
//!     name: ingest                 # optional, the node's name
//!     parameters: {keyframe.min_overlap: 0.7}
//!     remappings: {image/compressed: /camera/image_raw/compressed}
//!     respawn: true                # optional: restart it when it dies
//!     respawn_delay_s: 1.0
//! ```

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::process::{Child, Command};
use std::time::{Duration, Instant};

use anyhow::{bail, Context, Result};
use revisit_node::{Names, Node, RosArgs};
use serde::Deserialize;

#[derive(clap::Args)]
pub struct Args {
    /// The launch file (YAML), e.g. launch-scripts/survey.yaml.
    file: PathBuf,
    /// Run every node in this process (one DDS participant each) instead of one process each.
    #[arg(long)]
    single_process: bool,
}

/// A launch file.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct LaunchFile {
    #[serde(default)]
    namespace: Option<String>,
    #[serde(default)]
    parameters: BTreeMap<String, serde_yaml_ng::Value>,
    nodes: Vec<NodeEntry>,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct NodeEntry {
    node: String,
    #[serde(default)]
    name: Option<String>,
    #[serde(default)]
    parameters: BTreeMap<String, serde_yaml_ng::Value>,
    #[serde(default)]
    remappings: BTreeMap<String, String>,
    #[serde(default)]
    respawn: bool,
    #[serde(default = "one_second")]
    respawn_delay_s: f64,
}

fn one_second() -> f64 {
    1.0
}

/// The nodes Revisit has (each also an executable `revisit-KIND`, and `revisit node KIND`).
const NODES: [&str; 5] = ["ingest", "features", "places", "matcher", "mapper"];

#[derive(clap::Args)]
pub struct NodeArgs {
    /// Which node: ingest, features, places, matcher or mapper.
    kind: String,
    /// ROS arguments: --ros-args -p NAME:=VALUE -r FROM:=TO -r __ns:=/NS ...
    #[arg(long = "ros-args", num_args = 0.., allow_hyphen_values = true, value_name = "ARG")]
    ros_args: Vec<String>,
}

/// `revisit node KIND`: one node in this process until Ctrl-C or SIGTERM.
pub fn run_node(args: NodeArgs) -> Result<()> {
    if !NODES.contains(&args.kind.as_str()) {
        bail!("no node {:?} (Revisit has: {})", args.kind, NODES.join(", "));
    }
    let ros_args = RosArgs::parse(&args.ros_args)?;
    let runtime = tokio::runtime::Runtime::new()?;
    runtime.block_on(async {
        let mut node = Node::start(&args.kind, &ros_args)?;
        let result = run_kind(&args.kind, &mut node).await;
        node.shutdown().await;
        result
    })
}

/// A node's loop, by kind.
async fn run_kind(kind: &str, node: &mut Node) -> Result<()> {
    let summary = match kind {
        "ingest" => revisit_ingest_node::run(node).await?.to_string(),
        "features" => revisit_features_node::run(node).await?.to_string(),
        "places" => revisit_places_node::run(node).await?.to_string(),
        "matcher" => revisit_matcher_node::run(node).await?.to_string(),
        "mapper" => revisit_mapper_node::run(node).await?.to_string(),
        other => bail!("no node {other:?}"),
    };
    tracing::info!("{}: {summary}", node.full_name());
    Ok(())
}

/// One node to start: its name and its `--ros-args`.
struct Planned {
    kind: String,
    name: String,
    ros_args: Vec<String>,
    respawn: Option<Duration>,
}

pub fn run(args: Args) -> Result<()> {
    let planned = plan(&args.file)?;
    if args.single_process {
        single_process(planned)
    } else {
        let cancel = crate::signals::cancel_on_signals()?;
        supervise(planned, &cancel)
    }
}

fn plan(path: &Path) -> Result<Vec<Planned>> {
    let text = std::fs::read_to_string(path).with_context(|| format!("{}", path.display()))?;
    let file: LaunchFile = serde_yaml_ng::from_str(&text).with_context(|| format!("{}", path.display()))?;
    let mut planned = Vec::new();
    for (i, entry) in file.nodes.iter().enumerate() {
        if !NODES.contains(&entry.node.as_str()) {
            bail!("{}: nodes[{i}]: no node {:?} (Revisit has: {})", path.display(), entry.node, NODES.join(", "));
        }
        if !(entry.respawn_delay_s.is_finite() && entry.respawn_delay_s >= 0.0) {
            bail!("{}: nodes[{i}]: respawn_delay_s must be a number of seconds >= 0", path.display());
        }
        let name = entry.name.clone().unwrap_or_else(|| entry.node.clone());
        let mut ros_args = vec!["-r".to_owned(), format!("__node:={name}")];
        if let Some(namespace) = &file.namespace {
            ros_args.extend(["-r".to_owned(), format!("__ns:={namespace}")]);
        }
        for (key, value) in file.parameters.iter().chain(&entry.parameters) {
            let value = serde_yaml_ng::to_string(value)?.trim().to_owned();
            ros_args.extend(["-p".to_owned(), format!("{key}:={value}")]);
        }
        for (from, to) in &entry.remappings {
            ros_args.extend(["-r".to_owned(), format!("{from}:={to}")]);
        }
        // Checked now, so that a bad name or value fails before anything starts.
        let at = || format!("{}: nodes[{i}]", path.display());
        let parsed = RosArgs::parse(&ros_args).with_context(at)?;
        Names::new(parsed.namespace.as_deref().unwrap_or("/"), &name, &parsed.remaps).with_context(at)?;
        let respawn = entry.respawn.then(|| Duration::from_secs_f64(entry.respawn_delay_s));
        planned.push(Planned { kind: entry.node.clone(), name, ros_args, respawn });
    }
    if planned.is_empty() {
        bail!("{}: no nodes", path.display());
    }
    Ok(planned)
}

/// A node's process: this executable, `revisit node KIND --ros-args ...`.
fn start(node: &Planned) -> Result<Child> {
    let exe = std::env::current_exe()?;
    let child = Command::new(&exe)
        .args(["node", &node.kind, "--ros-args"])
        .args(&node.ros_args)
        .spawn()
        .with_context(|| format!("starting node {} ({})", node.name, exe.display()))?;
    tracing::info!("started {} (pid {})", node.name, child.id());
    Ok(child)
}

/// Runs the processes until Ctrl-C/SIGTERM, respawning those that ask for it, then stops them
/// all with SIGINT (SIGKILL after 10 s).
fn supervise(planned: Vec<Planned>, cancel: &revisit_pipeline::Cancel) -> Result<()> {
    let mut running: Vec<(Planned, Option<Child>, Option<Instant>)> = Vec::new();
    for node in planned {
        let child = start(&node)?;
        running.push((node, Some(child), None));
    }
    while !cancel.is_cancelled() {
        for (node, child, due) in &mut running {
            if let Some(process) = child {
                if let Some(status) = process.try_wait()? {
                    *child = None;
                    match node.respawn {
                        Some(delay) => {
                            tracing::warn!(
                                "{} exited ({status}); respawning in {:.1} s",
                                node.name,
                                delay.as_secs_f64()
                            );
                            *due = Some(Instant::now() + delay);
                        }
                        None => tracing::warn!("{} exited ({status})", node.name),
                    }
                }
            } else if due.is_some_and(|due| Instant::now() >= due) {
                *due = None;
                *child = Some(start(node)?);
                tracing::info!("respawned {}", node.name);
            }
        }
        if running.iter().all(|(node, child, _)| child.is_none() && node.respawn.is_none()) {
            bail!("every node has exited");
        }
        std::thread::sleep(Duration::from_millis(100));
    }
    let mut clean = true;
    for (node, child, _) in &mut running {
        let Some(process) = child else { continue };
        let pid = rustix::process::Pid::from_raw(process.id() as i32);
        if let Some(pid) = pid {
            let _ = rustix::process::kill_process(pid, rustix::process::Signal::INT);
        }
        let deadline = Instant::now() + Duration::from_secs(10);
        let status = loop {
            if let Some(status) = process.try_wait()? {
                break status;
            }
            if Instant::now() > deadline {
                tracing::warn!("{} did not stop in 10 s: killed", node.name);
                process.kill()?;
                break process.wait()?;
            }
            std::thread::sleep(Duration::from_millis(50));
        };
        clean &= status.success();
        tracing::info!("{} stopped ({status})", node.name);
    }
    if !clean {
        bail!("a node did not stop cleanly");
    }
    Ok(())
}

/// Every node as a task of one runtime, each with its own DDS participant.
fn single_process(planned: Vec<Planned>) -> Result<()> {
    let runtime = tokio::runtime::Runtime::new()?;
    runtime.block_on(async {
        let mut tasks = Vec::new();
        for node in planned {
            let args = RosArgs::parse(&node.ros_args)?;
            let mut started = Node::start(&node.kind, &args)?;
            tracing::info!("started {} in this process", started.full_name());
            tasks.push(tokio::spawn(async move {
                let result = run_kind(&node.kind, &mut started).await;
                started.shutdown().await;
                (node.name, result)
            }));
        }
        for task in tasks {
            let (name, result) = task.await?;
            result.with_context(|| format!("node {name}"))?;
        }
        Ok(())
    })
}
