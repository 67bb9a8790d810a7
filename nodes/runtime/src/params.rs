//! A node's parameters (from `-p` and params files) and the QoS they set.

use std::collections::BTreeMap;

use ros2_client::qos::{Durability, History, Reliability, WhenFull};
use ros2_client::{ParameterValue, QosProfile};
use serde::de::DeserializeOwned;
use serde_yaml_ng::Value;

use crate::args::{read_params_file, ParameterSource, RosArgs};
use crate::NodeError;

/// Which end of a topic a QoS is for (ROS's `qos_overrides.TOPIC.publisher|subscription`).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Endpoint {
    Publisher,
    Subscription,
}

/// Parameter values by name; later sources override earlier ones.
#[derive(Clone, Debug, Default)]
pub struct Parameters {
    values: BTreeMap<String, Value>,
}

impl Parameters {
    /// The parameters `args` give the node `/namespace/name`.
    pub fn from_args(args: &RosArgs, namespace: &str, name: &str) -> Result<Parameters, NodeError> {
        let mut values = BTreeMap::new();
        for source in &args.parameters {
            match source {
                ParameterSource::Assignment { name, value } => {
                    values.insert(name.clone(), value.clone());
                }
                ParameterSource::File(path) => values.extend(read_params_file(path, namespace, name)?),
            }
        }
        Ok(Parameters { values })
    }

    /// Sets one value (as `-p` would).
    pub fn set(&mut self, name: &str, value: impl Into<Value>) {
        self.values.insert(name.to_owned(), value.into());
    }

    /// The parameter's value, or `default` when it is not set; a value of the wrong type is an
    /// error naming the parameter.
    pub fn get<T: DeserializeOwned>(&self, name: &str, default: T) -> Result<T, NodeError> {
        match self.values.get(name) {
            None => Ok(default),
            Some(value) => serde_yaml_ng::from_value(value.clone())
                .map_err(|e| NodeError::Parameter { name: name.to_owned(), reason: e.to_string() }),
        }
    }

    /// Every value, as ROS parameter values (for `ros2 param`).
    pub fn ros_values(&self) -> impl Iterator<Item = (&str, ParameterValue)> {
        self.values.iter().map(|(name, value)| (name.as_str(), ros_value(value)))
    }

    /// The QoS of `topic` (resolved) at `endpoint`: `default` with what
    /// `qos_overrides.TOPIC.ENDPOINT.{reliability,durability,history,depth}` change.
    pub fn qos(&self, topic: &str, endpoint: Endpoint, default: QosProfile) -> Result<QosProfile, NodeError> {
        let end = match endpoint {
            Endpoint::Publisher => "publisher",
            Endpoint::Subscription => "subscription",
        };
        let key = |policy: &str| format!("qos_overrides.{topic}.{end}.{policy}");
        let bad = |policy: &str, value: &str, allowed: &str| NodeError::Parameter {
            name: key(policy),
            reason: format!("{value:?} is not one of {allowed}"),
        };
        let mut qos = default;
        if let Some(value) = self.get::<Option<String>>(&key("reliability"), None)? {
            qos.reliability = match value.as_str() {
                "reliable" => Reliability::Reliable { when_full: WhenFull::DEFAULT },
                "best_effort" => Reliability::BestEffort,
                _ => return Err(bad("reliability", &value, "reliable, best_effort")),
            };
        }
        if let Some(value) = self.get::<Option<String>>(&key("durability"), None)? {
            qos.durability = match value.as_str() {
                "volatile" => Durability::Volatile,
                "transient_local" => Durability::TransientLocal,
                _ => return Err(bad("durability", &value, "volatile, transient_local")),
            };
        }
        let depth = self.get::<Option<usize>>(&key("depth"), None)?;
        match self.get::<Option<String>>(&key("history"), None)?.as_deref() {
            Some("keep_all") => qos.history = History::KeepAll,
            Some("keep_last") | None => {
                if let Some(depth) = depth.filter(|d| *d > 0) {
                    qos.history = History::KeepLast { depth };
                } else if depth == Some(0) {
                    return Err(NodeError::Parameter { name: key("depth"), reason: "must be at least 1".into() });
                }
            }
            Some(other) => return Err(bad("history", other, "keep_last, keep_all")),
        }
        Ok(qos)
    }
}

fn ros_value(value: &Value) -> ParameterValue {
    fn all<T>(items: &[Value], f: impl Fn(&Value) -> Option<T>) -> Option<Vec<T>> {
        items.iter().map(f).collect()
    }
    match value {
        Value::Bool(b) => ParameterValue::Boolean(*b),
        Value::Number(n) if n.is_i64() => ParameterValue::Integer(n.as_i64().unwrap_or_default()),
        Value::Number(n) => ParameterValue::Double(n.as_f64().unwrap_or_default()),
        Value::String(s) => ParameterValue::String(s.clone()),
        Value::Sequence(items) => {
            if let Some(v) = all(items, Value::as_bool) {
                ParameterValue::BooleanArray(v)
            } else if let Some(v) = all(items, Value::as_i64) {
                ParameterValue::IntegerArray(v)
            } else if let Some(v) = all(items, Value::as_f64) {
                ParameterValue::DoubleArray(v)
            } else {
                let text = |v: &Value| v.as_str().map(str::to_owned);
                ParameterValue::StringArray(all(items, text).unwrap_or_default())
            }
        }
        other => ParameterValue::String(serde_yaml_ng::to_string(other).unwrap_or_default().trim().to_owned()),
    }
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used)]
    use super::*;

    fn parameters(words: &str) -> Parameters {
        let words: Vec<String> = words.split_whitespace().map(String::from).collect();
        Parameters::from_args(&RosArgs::parse(&words).unwrap(), "/", "node").unwrap()
    }

    #[test]
    fn typed_values_with_defaults_and_errors_naming_the_parameter() {
        let p = parameters("-p rate:=2.5 -p session:=reef -p depth:=3 -p depth:=4");
        assert_eq!(p.get("rate", 1.0).unwrap(), 2.5);
        assert_eq!(p.get("depth", 0u32).unwrap(), 4);
        assert_eq!(p.get("session", String::new()).unwrap(), "reef");
        assert_eq!(p.get("missing", 9).unwrap(), 9);
        let err = p.get("session", 0u32).unwrap_err().to_string();
        assert!(err.starts_with("parameter session:"), "{err}");
    }

    #[test]
    fn qos_overrides_follow_ros_names() {
        let p = parameters(
            "-p qos_overrides./image.subscription.reliability:=best_effort \
             -p qos_overrides./image.subscription.depth:=5 \
             -p qos_overrides./map/cloud.publisher.durability:=transient_local \
             -p qos_overrides./bad.publisher.reliability:=sometimes",
        );
        let image = p.qos("/image", Endpoint::Subscription, QosProfile::publisher_default()).unwrap();
        assert_eq!(image.reliability, Reliability::BestEffort);
        assert_eq!(image.history, History::KeepLast { depth: 5 });
        let cloud = p.qos("/map/cloud", Endpoint::Publisher, QosProfile::publisher_default()).unwrap();
        assert_eq!(cloud.durability, Durability::TransientLocal);
        let err = p.qos("/bad", Endpoint::Publisher, QosProfile::default()).unwrap_err().to_string();
        assert!(err.contains("qos_overrides./bad.publisher.reliability") && err.contains("sometimes"), "{err}");
    }
}
