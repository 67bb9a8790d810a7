//! Matcher nodes share a visit's cross-visit pairs over DDS: two instances (one ONNX thread each,
//! separate processes on loopback) both take pairs, every pair is answered, and none is matched
//! twice. The work is what `reconstruct` did for the second visit of a synthetic survey: its
//! learned features and its place-recognition pairs, published to the matchers as the features
//! and places nodes would.

#![allow(clippy::unwrap_used, clippy::expect_used)]

mod common;

use std::collections::BTreeMap;
use std::path::Path;
use std::process::{Child, Command};
use std::time::{Duration, Instant};

use common::{read_json, reconstruct, run_ok};
use futures::StreamExt;
use revisit_core::{PairKind, Roll};
use revisit_msgs::revisit_msgs::{CrossVisitMatches, Features, PlaceCandidate, PlaceCandidates};
use revisit_node::{Domain, Node, RosArgs, WORK_QUEUE};
use revisit_pipeline::messages;
use revisit_store::Store;

/// What a graph's features and places nodes would send the matchers for the second visit.
struct Work {
    features: Vec<Features>,
    candidates: Vec<PlaceCandidates>,
    pairs: usize,
}

fn work_of(store: &Store, method: &str) -> Work {
    let names: BTreeMap<_, _> = store.image_ids().unwrap().into_iter().map(|(name, id)| (id, name)).collect();
    let split = |id| {
        let name: &String = &names[&id];
        let (session, file) = name.split_once('/').unwrap();
        (session.to_owned(), file.to_owned())
    };
    let mut features = Vec::new();
    for (id, roll) in store.learned_feature_keys(method).unwrap() {
        let (session, file) = split(id);
        let learned = store.read_learned_features(id, method, roll).unwrap();
        let roll = Roll::from_degrees(roll).unwrap();
        features.push(messages::learned_message(Default::default(), &session, &file, method, roll, &learned));
    }
    let mut by_query: BTreeMap<(String, String), Vec<PlaceCandidate>> = BTreeMap::new();
    let mut pairs = 0;
    for record in store.pair_records().unwrap().into_iter().filter(|r| r.kind == PairKind::Cross) {
        let ((s1, f1), query) = (split(record.image_id1), split(record.image_id2));
        by_query.entry(query).or_default().push(PlaceCandidate { session: s1, image_name: f1, ..Default::default() });
        pairs += 1;
    }
    let candidates = by_query
        .into_iter()
        .map(|((session, image_name), candidates)| PlaceCandidates {
            session,
            image_name,
            candidates,
            ..Default::default()
        })
        .collect();
    Work { features, candidates, pairs }
}

/// An answer's pair, `session/file session/file`.
fn pair_of(answer: &CrossVisitMatches) -> String {
    format!("{}/{} {}/{}", answer.session1, answer.image_name1, answer.session2, answer.image_name2)
}

/// Starts `count` matcher nodes in `domain`; returns them and the seconds until every pair was
/// answered, with how many times each pair was answered.
fn match_with(count: usize, domain: u16, dir: &Path, options: &Path, work: &Work) -> (f64, BTreeMap<String, usize>) {
    let mut matchers: Vec<Child> = (0..count)
        .map(|k| {
            let state = dir.join(format!("matchers-{count}/matcher-{k}"));
            let mut command = common::revisit();
            command.env("ROS_DOMAIN_ID", domain.to_string()).env("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST");
            command.args(["node", "matcher", "--ros-args", "-r", &format!("__node:=matcher_{k}")]);
            command.args(["-p", &format!("state_dir:={}", state.display())]);
            command.args(["-p", &format!("options_file:={}", options.display()), "-p", "onnx_threads:=1"]);
            command.spawn().unwrap()
        })
        .collect();
    let runtime = tokio::runtime::Runtime::new().unwrap();
    let result = runtime.block_on(async {
        let domain = Domain { id: domain, localhost_only: true };
        let mut node = Node::start_in(domain, "matchers_test", &RosArgs::default()).unwrap();
        let features = node.publisher::<Features>("/features", WORK_QUEUE).unwrap();
        let candidates = node.publisher::<PlaceCandidates>("/places/candidates", WORK_QUEUE).unwrap();
        let answers = node.subscription::<CrossVisitMatches>("/matches", WORK_QUEUE).unwrap();
        let mut answers = std::pin::pin!(answers.async_stream());
        // Every matcher reads the candidates and sees the others.
        let up = Instant::now();
        while node.readers_of("/places/candidates") < count || node.readers_of("/revisit/matchers") < count {
            assert!(up.elapsed() < Duration::from_secs(60), "the matchers did not come up");
            tokio::time::sleep(Duration::from_millis(100)).await;
        }
        tokio::time::sleep(Duration::from_secs(2)).await;
        for message in &work.features {
            features.async_publish(message.clone()).await.unwrap();
        }
        let started = Instant::now();
        for message in &work.candidates {
            candidates.async_publish(message.clone()).await.unwrap();
        }
        let mut answered: BTreeMap<String, usize> = BTreeMap::new();
        while answered.len() < work.pairs {
            let next = tokio::time::timeout(Duration::from_secs(600), answers.next()).await;
            let (answer, _) = next.expect("no answer in 10 min").unwrap().unwrap();
            *answered.entry(pair_of(&answer)).or_default() += 1;
        }
        let seconds = started.elapsed().as_secs_f64();
        // Anything still on its way (a pair matched twice).
        while let Ok(Some(Ok((answer, _)))) = tokio::time::timeout(Duration::from_secs(3), answers.next()).await {
            *answered.entry(pair_of(&answer)).or_default() += 1;
        }
        node.shutdown().await;
        (seconds, answered)
    });
    for matcher in &mut matchers {
        let _ = Command::new("kill").args(["-INT", &matcher.id().to_string()]).status();
        assert!(matcher.wait().unwrap().success(), "a matcher did not stop cleanly");
    }
    result
}

#[test]
fn two_matchers_share_a_visits_pairs_and_match_no_pair_twice() {
    let dir = tempfile::tempdir().unwrap();
    let reef = dir.path().join("reef");
    let synth = ["synth", "--out", reef.to_str().unwrap(), "--sessions", "2", "--images-per-session", "5"];
    run_ok(&[&synth[..], &["--change", "mild", "--seed", "0"]].concat());
    let offline = dir.path().join("offline");
    let report = reconstruct(&reef, &["s1", "s2"], &offline, &["--vpr-top-k", "2"]);
    let options = dir.path().join("options.json");
    std::fs::write(&options, report["options"].to_string()).unwrap();
    let method = report["options"]["learned"].as_str().unwrap().to_owned();
    let store = Store::open_read_only(&offline.join("database.db")).unwrap();
    let work = work_of(&store, &method);
    assert_eq!(work.pairs as u64, read_json(&offline.join("report.json"))["pairs"]["cross"]["tried"]);

    let (seconds, answered) = match_with(2, 59, dir.path(), &options, &work);
    println!("{} pairs: two matchers {seconds:.1} s", work.pairs);
    assert_eq!(answered.len(), work.pairs, "{answered:?}");
    let twice: Vec<_> = answered.iter().filter(|(_, n)| **n > 1).collect();
    assert!(twice.is_empty(), "pairs matched twice: {twice:?}");
    // Each of the two did some of the pairs.
    for k in 0..2 {
        let journal = std::fs::read_to_string(dir.path().join(format!("matchers-2/matcher-{k}/journal"))).unwrap();
        assert!(journal.lines().any(|l| l.starts_with("done")), "matcher {k} of 2 matched no pair");
    }
}
