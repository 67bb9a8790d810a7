//! Every message type against independent implementations (PyPI `mcap-ros2-support` and `rosbags`):
//! bags Revisit writes decode there to the values Revisit wrote, and bags they write (mcap and
//! sqlite3) decode in Revisit to the values they wrote. The schemas Revisit writes come from the
//! `.msg` files, so this also checks each Rust type against its `.msg` field by field.

#![allow(clippy::unwrap_used, clippy::expect_used)]

use revisit_bag::{Bag, BagWriter, QosProfile};
use serde_json::{json, Map, Value};

/// Two sample messages of every type, one topic per type: topic -> {type, schema, values}.
fn expected() -> Map<String, Value> {
    revisit_msgs::ALL
        .iter()
        .map(|t| {
            let values: Vec<Value> = (1..=2).map(|seed| (t.sample)(seed).1).collect();
            let topic = format!("/sample/{}", t.definition.name.replace("/msg/", "/"));
            (topic, json!({"type": t.definition.name, "schema": t.definition.schema(), "values": values}))
        })
        .collect()
}

#[test]
fn bags_revisit_writes_decode_in_python_to_the_same_values() {
    let dir = tempfile::tempdir().unwrap();
    let expected = expected();
    let bag = dir.path().join("samples");
    let mut writer = BagWriter::create(&bag).unwrap();
    for (i, t) in revisit_msgs::ALL.iter().enumerate() {
        let topic = format!("/sample/{}", t.definition.name.replace("/msg/", "/"));
        let handle = writer.add_raw_topic(&topic, t.definition, QosProfile::RELIABLE).unwrap();
        for seed in 1..=2 {
            writer.write_raw(handle, 1_000 * i as u64 + seed, &(t.sample)(seed).0).unwrap();
        }
    }
    let written = writer.finish().unwrap();
    assert_eq!(written.messages, 2 * revisit_msgs::ALL.len() as u64);
    let expected_path = dir.path().join("expected.json");
    std::fs::write(&expected_path, Value::Object(expected).to_string()).unwrap();
    revisit_testkit::interop("check", &bag, &expected_path);
}

#[test]
fn bags_python_writes_decode_in_revisit_to_the_same_values() {
    let dir = tempfile::tempdir().unwrap();
    let expected = expected();
    let expected_path = dir.path().join("expected.json");
    std::fs::write(&expected_path, Value::Object(expected.clone()).to_string()).unwrap();
    revisit_testkit::interop("write", dir.path(), &expected_path);
    for bag in ["rosbags_db3", "rosbags_mcap", "mcap_ros2.mcap"] {
        let bag = Bag::open(&dir.path().join(bag)).unwrap();
        let mut decoded: Map<String, Value> = Map::new();
        for message in bag.messages() {
            let message = message.unwrap();
            let t = revisit_msgs::find(&message.topic.type_name).expect("a known type");
            let value = (t.decode_json)(&message.data).unwrap_or_else(|e| panic!("{}: {e}", message.topic.name));
            decoded.entry(message.topic.name.clone()).or_insert_with(|| json!([])).as_array_mut().unwrap().push(value);
        }
        assert_eq!(decoded.len(), expected.len(), "{}: topics", bag.path().display());
        for (topic, entry) in &expected {
            assert_eq!(decoded[topic], entry["values"], "{}: {topic}", bag.path().display());
        }
    }
}

/// A few types against Cyclone DDS's IDL (PyPI `cyclonedds`), the CDR that DDS peers speak:
/// Revisit's bytes decode there to the same values, and its bytes decode in Revisit to them.
#[test]
fn cdr_agrees_with_cyclone_dds_both_ways() {
    let types = [
        "builtin_interfaces/msg/Time",
        "std_msgs/msg/Header",
        "sensor_msgs/msg/Image",
        "sensor_msgs/msg/CameraInfo",
        "sensor_msgs/msg/NavSatFix",
        "nav_msgs/msg/Odometry",
    ];
    let dir = tempfile::tempdir().unwrap();
    let mut expected = Map::new();
    for name in types {
        let t = revisit_msgs::find(name).unwrap();
        let samples: Vec<(Vec<u8>, Value)> = (1..=2).map(|seed| (t.sample)(seed)).collect();
        let cdr: Vec<String> =
            samples.iter().map(|(bytes, _)| bytes.iter().map(|b| format!("{b:02x}")).collect()).collect();
        let values: Vec<Value> = samples.into_iter().map(|(_, value)| value).collect();
        expected.insert(name.to_owned(), json!({"values": values, "cdr": cdr}));
    }
    let expected_path = dir.path().join("expected.json");
    std::fs::write(&expected_path, Value::Object(expected.clone()).to_string()).unwrap();
    let out = dir.path().join("cyclonedds.json");
    revisit_testkit::interop("cyclonedds", &out, &expected_path);
    let encoded: Map<String, Value> = serde_json::from_str(&std::fs::read_to_string(&out).unwrap()).unwrap();
    for name in types {
        let t = revisit_msgs::find(name).unwrap();
        for (hex, value) in encoded[name].as_array().unwrap().iter().zip(expected[name]["values"].as_array().unwrap()) {
            let hex = hex.as_str().unwrap();
            let bytes: Vec<u8> =
                (0..hex.len()).step_by(2).map(|i| u8::from_str_radix(&hex[i..i + 2], 16).unwrap()).collect();
            assert_eq!(&(t.decode_json)(&bytes).unwrap(), value, "{name}");
        }
    }
}
