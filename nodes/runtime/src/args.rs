//! `--ros-args` as ROS 2 users type them: `-p name:=value`, `--params-file FILE`, `-r from:=to`,
//! `-r __ns:=/ns`, `-r __node:=name`, and a node-specific form `-r node:from:=to`.

use std::path::{Path, PathBuf};

use serde_yaml_ng::Value;

use crate::NodeError;

/// What `--ros-args ... [--]` said, in the order it was said.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct RosArgs {
    /// `-r __node:=name`.
    pub node_name: Option<String>,
    /// `-r __ns:=/ns`.
    pub namespace: Option<String>,
    /// Parameter sources in order: a later one overrides an earlier one.
    pub parameters: Vec<ParameterSource>,
    /// `-r [node:]from:=to`.
    pub remaps: Vec<Remap>,
}

/// Where a parameter value comes from.
#[derive(Clone, Debug, PartialEq)]
pub enum ParameterSource {
    /// `-p name:=value` (the value read as YAML, as ROS does).
    Assignment { name: String, value: Value },
    /// `--params-file FILE`.
    File(PathBuf),
}

/// A topic or service name remapping.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Remap {
    /// The node it applies to, or every node.
    pub node: Option<String>,
    pub from: String,
    pub to: String,
}

impl RosArgs {
    /// Splits a process's arguments into its own and the `--ros-args` sections (each runs to `--`
    /// or the end; there may be several).
    pub fn split<I: IntoIterator<Item = String>>(args: I) -> Result<(Vec<String>, RosArgs), NodeError> {
        let mut own = Vec::new();
        let mut ros = Vec::new();
        let mut in_ros = false;
        for arg in args {
            match (in_ros, arg.as_str()) {
                (_, "--ros-args") => in_ros = true,
                (true, "--") => in_ros = false,
                (true, _) => ros.push(arg),
                (false, _) => own.push(arg),
            }
        }
        Ok((own, RosArgs::parse(&ros)?))
    }

    /// Parses the words of `--ros-args` sections.
    pub fn parse(words: &[String]) -> Result<RosArgs, NodeError> {
        let mut parsed = RosArgs::default();
        let mut words = words.iter();
        while let Some(flag) = words.next() {
            let mut value =
                |what: &str| words.next().cloned().ok_or_else(|| NodeError::Args(format!("{flag} needs {what}")));
            match flag.as_str() {
                "-p" | "--param" => {
                    let assignment = value("NAME:=VALUE")?;
                    let (name, text) = split_assignment(flag, &assignment)?;
                    let value = serde_yaml_ng::from_str(text).unwrap_or_else(|_| Value::String(text.to_owned()));
                    parsed.parameters.push(ParameterSource::Assignment { name: name.to_owned(), value });
                }
                "--params-file" => parsed.parameters.push(ParameterSource::File(value("FILE")?.into())),
                "-r" | "--remap" => {
                    let assignment = value("FROM:=TO")?;
                    let (from, to) = split_assignment(flag, &assignment)?;
                    match from {
                        "__node" | "__name" => parsed.node_name = Some(to.to_owned()),
                        "__ns" => parsed.namespace = Some(to.to_owned()),
                        _ => {
                            let (node, from) = match from.split_once(':') {
                                Some((node, from)) => (Some(node.to_owned()), from),
                                None => (None, from),
                            };
                            parsed.remaps.push(Remap { node, from: from.to_owned(), to: to.to_owned() });
                        }
                    }
                }
                "--log-level" | "-e" | "--enclave" => {
                    value("a value")?;
                }
                "--disable-rosout-logs" | "--disable-stdout-logs" | "--enable-rosout-logs" | "--enable-stdout-logs" => {
                }
                other => return Err(NodeError::Args(format!("unknown --ros-args flag {other:?}"))),
            }
        }
        Ok(parsed)
    }
}

fn split_assignment<'a>(flag: &str, assignment: &'a str) -> Result<(&'a str, &'a str), NodeError> {
    match assignment.split_once(":=") {
        Some((name, value)) if !name.is_empty() => Ok((name, value)),
        _ => Err(NodeError::Args(format!("{flag} {assignment:?}: expected NAME:=VALUE"))),
    }
}

/// The parameters a params file gives a node: the sections `/**`, `/**/NAME`, `NAME` and
/// `/NAMESPACE/NAME` in file order, nested maps flattened with `.`.
pub fn read_params_file(path: &Path, namespace: &str, name: &str) -> Result<Vec<(String, Value)>, NodeError> {
    let fail = |reason: String| NodeError::Args(format!("--params-file {}: {reason}", path.display()));
    let text = std::fs::read_to_string(path).map_err(|e| fail(e.to_string()))?;
    let document: Value = serde_yaml_ng::from_str(&text).map_err(|e| fail(e.to_string()))?;
    let Value::Mapping(sections) = document else {
        return Err(fail("expected a map of node names".to_owned()));
    };
    let full_name = if namespace == "/" { format!("/{name}") } else { format!("{namespace}/{name}") };
    let mut parameters = Vec::new();
    for (key, section) in sections {
        let key = key.as_str().ok_or_else(|| fail("a node name is not a string".to_owned()))?;
        let applies = key == "/**" || key == name || key == full_name || key.strip_prefix("/**/") == Some(name);
        if !applies {
            continue;
        }
        let values =
            section.get("ros__parameters").ok_or_else(|| fail(format!("section {key:?} has no ros__parameters")))?;
        flatten("", values, &mut parameters);
    }
    Ok(parameters)
}

fn flatten(prefix: &str, value: &Value, out: &mut Vec<(String, Value)>) {
    match value {
        Value::Mapping(map) => {
            for (key, value) in map {
                let key = match key {
                    Value::String(s) => s.clone(),
                    other => serde_yaml_ng::to_string(other).unwrap_or_default().trim().to_owned(),
                };
                let name = if prefix.is_empty() { key } else { format!("{prefix}.{key}") };
                flatten(&name, value, out);
            }
        }
        _ => out.push((prefix.to_owned(), value.clone())),
    }
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used)]
    use super::*;

    fn words(text: &str) -> Vec<String> {
        text.split_whitespace().map(String::from).collect()
    }

    #[test]
    fn ros_args_are_split_from_the_programs_own_and_read_in_order() {
        let args =
            words("node --rate 2 --ros-args -p depth:=5 -p name:=reef -r __ns:=/auv -r image:=/cam/image -- --out x");
        let (own, ros) = RosArgs::split(args).unwrap();
        assert_eq!(own, words("node --rate 2 --out x"));
        assert_eq!(ros.namespace.as_deref(), Some("/auv"));
        assert_eq!(
            ros.parameters,
            vec![
                ParameterSource::Assignment { name: "depth".into(), value: Value::from(5) },
                ParameterSource::Assignment { name: "name".into(), value: Value::from("reef") },
            ]
        );
        assert_eq!(ros.remaps, vec![Remap { node: None, from: "image".into(), to: "/cam/image".into() }]);
    }

    #[test]
    fn bad_ros_args_name_the_flag() {
        let err = RosArgs::parse(&words("-p depth")).unwrap_err().to_string();
        assert!(err.contains("-p \"depth\""), "{err}");
        let err = RosArgs::parse(&words("-r")).unwrap_err().to_string();
        assert!(err.contains("-r needs"), "{err}");
        let err = RosArgs::parse(&words("--frobnicate")).unwrap_err().to_string();
        assert!(err.contains("--frobnicate"), "{err}");
    }

    #[test]
    fn params_files_apply_wildcard_and_own_sections_flattened() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("params.yaml");
        std::fs::write(
            &path,
            "/**:\n  ros__parameters:\n    use_sim_time: true\n\
             ingest:\n  ros__parameters:\n    session: a\n    qos_overrides:\n      /image:\n        subscription:\n          depth: 7\n\
             /auv/mapper:\n  ros__parameters:\n    session: b\n",
        )
        .unwrap();
        let ingest = read_params_file(&path, "/auv", "ingest").unwrap();
        assert_eq!(
            ingest,
            vec![
                ("use_sim_time".into(), Value::from(true)),
                ("session".into(), Value::from("a")),
                ("qos_overrides./image.subscription.depth".into(), Value::from(7)),
            ]
        );
        let mapper = read_params_file(&path, "/auv", "mapper").unwrap();
        assert_eq!(mapper[1], ("session".into(), Value::from("b")));
        assert_eq!(read_params_file(&path, "/other", "mapper").unwrap().len(), 1);
    }
}
