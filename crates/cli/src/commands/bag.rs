//! `revisit bag`: look into rosbag2 bags (mcap or sqlite3), export an image topic to a folder, and
//! pack image folders into a bag.

use std::path::PathBuf;

use anyhow::Result;

use revisit_bag::Bag;
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
    }
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
