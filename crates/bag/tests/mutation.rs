//! Damaged bags never panic, hang or allocate without bound: thousands of deterministic
//! truncations and byte flips of a real bag (the shared t265 mcap), a bag Revisit writes (zstd
//! chunks) and a sqlite3 bag `rosbags` writes, each read to the end with every message decoded.
//! `MUTATION_TRACE=1` prints each mutation before it is read (run with `--nocapture`).

#![allow(clippy::unwrap_used, clippy::expect_used)]

use cap::Cap;
use revisit_bag::{Bag, BagWriter, QosProfile};
use std::{alloc, path::Path, process::Command, sync::mpsc, time::Duration};

#[global_allocator]
static ALLOCATOR: Cap<alloc::System> = Cap::new(alloc::System, usize::MAX);

const TRUNCATIONS: u64 = 300;
const FLIPS: u64 = 1000;

/// Reads every message and decodes it by its type; errors are fine, panics are not.
fn read_all(path: &Path) -> (usize, usize) {
    let (mut read, mut failed) = (0, 0);
    let Ok(bag) = Bag::open(path) else { return (0, 1) };
    for message in bag.messages() {
        match message {
            Ok(message) => {
                read += 1;
                if let Some(t) = revisit_msgs::find(&message.topic.type_name) {
                    failed += usize::from((t.check)(&message.data).is_err());
                }
            }
            Err(_) => failed += 1,
        }
    }
    (read, failed)
}

/// A xorshift generator: the same mutations on every run.
struct Xorshift(u64);

impl Xorshift {
    fn next(&mut self) -> u64 {
        self.0 ^= self.0 << 13;
        self.0 ^= self.0 >> 7;
        self.0 ^= self.0 << 17;
        self.0
    }
}

enum Mutation {
    Truncate(usize),
    Flip { at: usize, bit: u8 },
}

/// Runs every mutation of `original` (stored as `name` in `dir`) and returns how many there were.
fn mutate(dir: &Path, name: &str, original: &[u8]) -> u64 {
    let path = dir.join(name);
    let (intact_read, intact_failed) = {
        std::fs::write(&path, original).unwrap();
        read_all(&path)
    };
    assert!(
        intact_read > 0 && intact_failed == 0,
        "{name}: the intact bag reads ({intact_read} read, {intact_failed} failed)"
    );
    let len = original.len() as u64;
    let mut random = Xorshift(0x9E37_79B9_7F4A_7C15 ^ len);
    let mut mutations = Vec::new();
    for i in 0..TRUNCATIONS {
        mutations.push(Mutation::Truncate((len * i / TRUNCATIONS) as usize));
    }
    for _ in 0..FLIPS {
        // Half the flips hit the first 4 KiB, where headers, schemas and lengths are.
        let at = if random.next().is_multiple_of(2) { random.next() % len.min(4096) } else { random.next() % len };
        mutations.push(Mutation::Flip { at: at as usize, bit: 1u8 << (random.next() % 8) });
    }
    // Live heap allowed while reading: the file twice over plus the 1 MiB read buffer.
    let allowed = 2 * original.len() + (2 << 20);
    let count = mutations.len() as u64;
    for mutation in mutations {
        let mut bytes = original.to_vec();
        let what = match mutation {
            Mutation::Truncate(keep) => {
                bytes.truncate(keep);
                format!("truncated to {keep} bytes")
            }
            Mutation::Flip { at, bit } => {
                bytes[at] ^= bit;
                format!("bit {bit:#04x} of byte {at} flipped")
            }
        };
        std::fs::write(&path, &bytes).unwrap();
        drop(bytes);
        if std::env::var_os("MUTATION_TRACE").is_some() {
            eprintln!("{name}: {what}");
        }
        let baseline = ALLOCATOR.allocated();
        ALLOCATOR.set_limit(baseline + allowed).unwrap();
        let (done, finished) = mpsc::channel();
        let worker_path = path.clone();
        let worker = std::thread::spawn(move || {
            let outcome = std::panic::catch_unwind(|| read_all(&worker_path));
            let _ = done.send(outcome.is_ok());
        });
        let outcome = finished.recv_timeout(Duration::from_secs(20));
        ALLOCATOR.set_limit(usize::MAX).unwrap();
        match outcome {
            Ok(true) => worker.join().unwrap(),
            Ok(false) => panic!("{name}, {what}: reading panicked"),
            Err(_) => panic!("{name}, {what}: reading hung for 20 s"),
        }
    }
    count
}

#[test]
fn damaged_bags_give_errors_never_panics_hangs_or_unbounded_allocations() {
    let dir = tempfile::tempdir().unwrap();
    // A bag Revisit writes: every type, three times, in zstd chunks.
    let written = dir.path().join("written");
    let mut writer = BagWriter::create(&written).unwrap();
    for (i, t) in revisit_msgs::ALL.iter().enumerate() {
        let topic = writer.add_raw_topic(&format!("/t{i}"), t.definition, QosProfile::RELIABLE).unwrap();
        for seed in 0..3 {
            writer.write_raw(topic, 10 * i as u64 + seed, &(t.sample)(seed).0).unwrap();
        }
    }
    let written = writer.finish().unwrap();
    // A sqlite3 bag rosbags writes, of the same messages.
    let expected = serde_json::Value::Object(
        revisit_msgs::ALL
            .iter()
            .map(|t| {
                let value = serde_json::json!({"type": t.definition.name, "schema": t.definition.schema(),
                    "values": [(t.sample)(1).1]});
                (format!("/t/{}", t.definition.name.replace("/msg/", "/")), value)
            })
            .collect(),
    );
    let expected_path = dir.path().join("expected.json");
    std::fs::write(&expected_path, expected.to_string()).unwrap();
    let script = revisit_testkit::repo().join("crates/bag/tests/interop.py");
    let status =
        Command::new(revisit_testkit::python()).arg(script).arg("write").arg(dir.path()).arg(&expected_path).status();
    assert!(status.unwrap().success());
    let db3 = std::fs::read_dir(dir.path().join("rosbags_db3"))
        .unwrap()
        .map(|e| e.unwrap().path())
        .find(|p| p.extension().is_some_and(|e| e == "db3"));

    let real = std::fs::read(revisit_testkit::shared("data/t265_locoffice/locoffice_ros2_mcap.mcap")).unwrap();
    let work = tempfile::tempdir().unwrap();
    let mut count = mutate(work.path(), "t265.mcap", &real);
    count += mutate(work.path(), "written.mcap", &std::fs::read(&written.mcap).unwrap());
    count += mutate(work.path(), "rosbags.db3", &std::fs::read(db3.unwrap()).unwrap());
    assert!(count >= 3 * (TRUNCATIONS + FLIPS));
}
