//! `revisit bag`: look into rosbag2 bags (mcap or sqlite3), export an image topic to a folder, and
//! pack image folders into a bag.

use std::path::PathBuf;
use std::time::Duration;

use anyhow::Result;

use revisit_bag::Bag;
use revisit_node::{Node, PlayOptions, RecordOptions, RosArgs};
use revisit_pipeline::{
    bags::{self, PackOptions},
    ingest::{self, SessionSpec},
};

use crate::progress::Bars;

#[derive(clap::Subcommand)]
pub enum Command {
    /// Topics, types, message counts, rates, duration and time range (read from the messages,
    /// like `ros2 bag info`).
    Info {
        /// A bag folder (with metadata.yaml) or a single .mcap or .db3 file.
        bag: PathBuf,
    },
    /// Write an image topic (sensor_msgs/Image or CompressedImage) to a folder of images, for
    /// COLMAP or any other tool: NNNNNN.png (raw images, lossless) or the compressed image's own
    /// .jpg/.png, with timestamps.csv. Messages that do not decode are skipped and counted.
    Export {
        /// A bag folder (with metadata.yaml) or a single .mcap or .db3 file.
        bag: PathBuf,
        /// The image topic, e.g. /camera/image_raw.
        #[arg(long)]
        topic: String,
        /// Output folder (created if missing; images already there are kept).
        #[arg(long)]
        out: PathBuf,
    },
    /// Pack image folders into one rosbag2 mcap bag: per visit, a revisit_msgs/SessionControl
    /// START and END on /revisit/session, each camera's images on /CAMERA/image_raw with
    /// /CAMERA/camera_info. Visits start a day apart.
    Pack {
        /// A visit as NAME=DIR (repeat, in visit order); DIR holds images, or a sub-folder per camera.
        #[arg(long = "session", value_name = "NAME=DIR", required = true)]
        sessions: Vec<SessionSpec>,
        /// The bag folder to create (it must not exist).
        #[arg(long)]
        out: PathBuf,
        /// Frames per second of each visit's timeline.
        #[arg(long, default_value_t = 10.0)]
        rate: f64,
        /// Store each image file's bytes as sensor_msgs/CompressedImage (lossless, small) instead of
        /// decoded sensor_msgs/Image pixels.
        #[arg(long)]
        compressed: bool,
    },
    /// Publish a bag's topics over DDS (ROS 2) at the bag's pace, in the domain ROS_DOMAIN_ID
    /// names, like `ros2 bag play`. Ctrl-C stops.
    Play {
        /// A bag folder (with metadata.yaml) or a single .mcap or .db3 file.
        bag: PathBuf,
        /// Speed against the bag's pace; 0: as fast as the subscribers take the messages.
        #[arg(long, default_value_t = 1.0)]
        rate: f64,
        /// Also publish /clock (rosgraph_msgs/Clock) with the bag's time, for nodes run with
        /// use_sim_time:=true.
        #[arg(long)]
        clock: bool,
        /// Only this topic (repeatable).
        #[arg(long = "topic", value_name = "TOPIC")]
        topics: Vec<String>,
        /// Wait until every topic has a subscriber before starting.
        #[arg(long)]
        wait_for_subscribers: bool,
        /// Seconds to wait before the first message.
        #[arg(long, default_value_t = 0.0)]
        delay: f64,
        /// ROS arguments, e.g. --ros-args -r /camera/image_raw:=/image -r __ns:=/auv.
        #[arg(long = "ros-args", num_args = 0.., allow_hyphen_values = true, value_name = "ARG")]
        ros_args: Vec<String>,
    },
    /// Record topics in the domain to a rosbag2 mcap bag, like `ros2 bag record`. Each topic is
    /// subscribed once a publisher of it appears. Ctrl-C stops and finishes the bag.
    Record {
        /// Topics to record.
        #[arg(required = true)]
        topics: Vec<String>,
        /// The bag folder to create (it must not exist).
        #[arg(long)]
        out: PathBuf,
        /// Stop after this many seconds.
        #[arg(long, value_name = "SECONDS")]
        duration: Option<f64>,
        /// Stop after this many messages.
        #[arg(long, value_name = "N")]
        max_messages: Option<u64>,
        /// ROS arguments, e.g. --ros-args -r __ns:=/auv -p use_sim_time:=true.
        #[arg(long = "ros-args", num_args = 0.., allow_hyphen_values = true, value_name = "ARG")]
        ros_args: Vec<String>,
    },
}

pub fn run(command: Command) -> Result<()> {
    match command {
        Command::Info { bag } => info(&Bag::open(&bag)?),
        Command::Export { bag, topic, out } => {
            let bag = Bag::open(&bag)?;
            let cancel = crate::signals::cancel_on_signals()?;
            let exported = bags::export(&bag, &topic, &out, &Bars::default(), &cancel)?;
            for why in exported.skipped.iter().take(5) {
                tracing::warn!("skipped: {why}");
            }
            println!(
                "exported {} images of {topic} to {} ({} messages skipped)",
                exported.images,
                out.display(),
                exported.skipped.len()
            );
            Ok(())
        }
        Command::Pack { sessions, out, rate, compressed } => {
            ingest::check_specs(&sessions)?;
            let scanned = sessions.iter().map(ingest::scan_session).collect::<Result<Vec<_>, _>>()?;
            let cancel = crate::signals::cancel_on_signals()?;
            let written =
                bags::pack(&scanned, &out, PackOptions { rate_hz: rate, compressed }, &Bars::default(), &cancel)?;
            println!("wrote {} messages to {}", written.messages, written.dir.display());
            Ok(())
        }
        Command::Play { bag, rate, clock, topics, wait_for_subscribers, delay, ros_args } => {
            let bag = Bag::open(&bag)?;
            let options = PlayOptions { rate, clock, topics, wait_for_subscribers, delay_s: delay };
            let played = in_node("revisit_bag_player", &ros_args, async |node| {
                let bar = crate::progress::bar(0, "play");
                let progress = |done, total| {
                    bar.set_length(total);
                    bar.set_position(done);
                };
                let played = revisit_node::play(node, &bag, &options, &progress).await;
                bar.finish_and_clear();
                Ok(played?)
            })?;
            println!("published {} messages in {:.1} s ({} skipped)", played.published, played.seconds, played.skipped);
            Ok(())
        }
        Command::Record { topics, out, duration, max_messages, ros_args } => {
            if duration.is_some_and(|d| !(d > 0.0 && d.is_finite())) {
                anyhow::bail!("--duration must be a positive number of seconds");
            }
            let options = RecordOptions { topics, duration: duration.map(Duration::from_secs_f64), max_messages };
            let written = in_node("revisit_bag_recorder", &ros_args, async |node| {
                let bar = crate::progress::spinner("record");
                let written = revisit_node::record(node, &out, &options, &|n| bar.set_position(n)).await;
                bar.finish_and_clear();
                Ok(written?)
            })?;
            println!("recorded {} messages to {}", written.messages, written.dir.display());
            Ok(())
        }
    }
}

/// Runs `work` with a node named `name` (ROS arguments applied) on a tokio runtime.
pub(crate) fn in_node<T>(name: &str, ros_args: &[String], work: impl AsyncFnOnce(&mut Node) -> Result<T>) -> Result<T> {
    let args = RosArgs::parse(ros_args)?;
    let runtime = tokio::runtime::Runtime::new()?;
    runtime.block_on(async {
        let mut node = Node::start(name, &args)?;
        let result = work(&mut node).await;
        node.shutdown().await;
        result
    })
}

fn info(bag: &Bag) -> Result<()> {
    let info = bag.info()?;
    let seconds = |ns: u64| format!("{}.{:09}", ns / 1_000_000_000, ns % 1_000_000_000);
    println!("Files:        {}", info.files.iter().map(|f| f.display().to_string()).collect::<Vec<_>>().join(", "));
    println!("Bag size:     {:.1} MiB", info.bytes as f64 / (1024.0 * 1024.0));
    println!("Storage id:   {}", info.storage.identifier());
    if let Some((first, last)) = info.time_range_ns() {
        println!("Duration:     {} s", seconds(last - first));
        println!("Start:        {} s", seconds(first));
        println!("End:          {} s", seconds(last));
    }
    println!("Messages:     {}", info.message_count());
    println!("Topics:       {}", info.topics.len());
    let width = info.topics.iter().map(|t| t.topic.name.len()).max().unwrap_or(0);
    let type_width = info.topics.iter().map(|t| t.topic.type_name.len()).max().unwrap_or(0);
    for stats in &info.topics {
        let rate = stats.rate_hz().map_or_else(|| "-".to_owned(), |hz| format!("{hz:.2} Hz"));
        println!(
            "  {:width$}  {:type_width$}  count {:>6}  rate {rate:>11}  format {}",
            stats.topic.name, stats.topic.type_name, stats.count, stats.topic.serialization_format
        );
    }
    Ok(())
}
