//! `revisit bench bag`: bag read throughput beside Python `mcap` + `mcap-ros2-support` on the same
//! file. Both sides read every message, decode it by its type and turn every image message into
//! pixels, on one thread; each pass is timed whole, and the median of `--repeat` passes is shown.

use std::{
    path::{Path, PathBuf},
    process::Command,
    time::Instant,
};

use anyhow::{bail, ensure, Context};
use revisit_bag::{Bag, Storage};
use revisit_msgs::sensor_msgs::{CompressedImage, Image};
use revisit_msgs::Message;
use revisit_pipeline::images;

/// The bag used when none is given.
const DEFAULT_BAG: &str = "../shared/data/t265_locoffice";

#[derive(clap::Args)]
pub struct Args {
    /// An mcap bag (folder or file). Default ../shared/data/t265_locoffice.
    bag: Option<PathBuf>,
    /// Timed passes per side; the median is reported.
    #[arg(long, default_value_t = 20)]
    repeat: usize,
    /// Python interpreter with mcap and mcap-ros2-support.
    #[arg(long, default_value = ".venv/bin/python")]
    python: PathBuf,
    /// The Python side's script.
    #[arg(long, default_value = "python/bag_read.py")]
    script: PathBuf,
}

struct Pass {
    messages: usize,
    images: usize,
}

/// One pass: every message decoded, every image to pixels.
fn read_pass(bag: &Bag) -> anyhow::Result<Pass> {
    let mut pass = Pass { messages: 0, images: 0 };
    for message in bag.messages() {
        let message = message?;
        pass.messages += 1;
        let origin = Path::new(&message.topic.name);
        let type_name = message.topic.type_name.as_str();
        if type_name == Image::DEFINITION.name {
            images::from_raw(&revisit_msgs::decode(&message.data)?, origin)?;
            pass.images += 1;
        } else if type_name == CompressedImage::DEFINITION.name {
            images::from_compressed(&revisit_msgs::decode(&message.data)?, origin)?;
            pass.images += 1;
        } else if let Some(known) = revisit_msgs::find(type_name) {
            (known.check)(&message.data)?;
        }
    }
    Ok(pass)
}

fn median(mut values: Vec<f64>) -> f64 {
    values.sort_by(f64::total_cmp);
    values[values.len() / 2]
}

pub fn run(args: Args) -> anyhow::Result<()> {
    let path = args.bag.clone().unwrap_or_else(|| PathBuf::from(DEFAULT_BAG));
    let bag = Bag::open(&path)?;
    ensure!(bag.storage() == Storage::Mcap, "{}: the Python side reads mcap bags only", path.display());
    ensure!(args.repeat >= 1, "--repeat must be at least 1");
    let bytes: u64 = bag.files().iter().map(|f| f.metadata().map(|m| m.len()).unwrap_or(0)).sum();

    let mut seconds = Vec::new();
    let mut pass = Pass { messages: 0, images: 0 };
    for _ in 0..args.repeat {
        let start = Instant::now();
        pass = read_pass(&bag)?;
        seconds.push(start.elapsed().as_secs_f64());
    }
    let revisit = median(seconds);

    // The Python side reads each storage file; its times add up.
    let mut python_total = 0.0;
    for file in bag.files() {
        let output = Command::new(&args.python)
            .arg(&args.script)
            .arg(file)
            .arg(args.repeat.to_string())
            .output()
            .with_context(|| format!("starting {}", args.python.display()))?;
        if !output.status.success() {
            bail!("{} failed: {}", args.script.display(), String::from_utf8_lossy(&output.stderr).trim());
        }
        let figures: serde_json::Value =
            serde_json::from_slice(&output.stdout).context("reading the Python side's figures")?;
        python_total += figures["seconds_median"].as_f64().context("the Python side gave no time")?;
    }

    let mb = bytes as f64 / 1e6;
    println!(
        "bag {} ({:.1} MB, {} messages, {} images), median of {} passes, one thread each",
        path.display(),
        mb,
        pass.messages,
        pass.images,
        args.repeat
    );
    println!("{:<36} {:>10} {:>12} {:>12}", "", "MB/s", "messages/s", "images/s");
    for (name, seconds) in
        [("revisit (mcap crate, cdr-encoding)", revisit), ("python mcap + mcap-ros2-support", python_total)]
    {
        println!(
            "{name:<36} {:>10.1} {:>12.0} {:>12.1}",
            mb / seconds,
            pass.messages as f64 / seconds,
            pass.images as f64 / seconds
        );
    }
    println!("revisit is {:.1}x the Python reader's throughput", python_total / revisit);
    Ok(())
}
