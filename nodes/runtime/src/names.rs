//! Topic names as ROS 2 resolves them: relative names in the node's namespace, `~/` in the node's
//! own, then the remapping rules.

use crate::args::Remap;
use crate::NodeError;

/// A node's namespace, name and remapping rules.
#[derive(Clone, Debug)]
pub struct Names {
    namespace: String,
    name: String,
    remaps: Vec<(String, String)>,
}

impl Names {
    /// `namespace` is absolute (`/` for none); the remaps for other nodes are left out.
    pub fn new(namespace: &str, name: &str, remaps: &[Remap]) -> Result<Names, NodeError> {
        let namespace = match namespace.trim_end_matches('/') {
            "" => "/".to_owned(),
            ns if ns.starts_with('/') => ns.to_owned(),
            ns => format!("/{ns}"),
        };
        check_name(&namespace, "namespace")?;
        if name.is_empty() || name.contains('/') {
            return Err(NodeError::Args(format!("node name {name:?} must be one token without '/'")));
        }
        let mut names = Names { namespace, name: name.to_owned(), remaps: Vec::new() };
        for remap in remaps.iter().filter(|r| r.node.as_deref().is_none_or(|n| n == name)) {
            let from = names.expand(&remap.from)?;
            let to = names.expand(&remap.to)?;
            names.remaps.push((from, to));
        }
        Ok(names)
    }

    pub fn namespace(&self) -> &str {
        &self.namespace
    }

    pub fn name(&self) -> &str {
        &self.name
    }

    /// `/namespace/name`.
    pub fn full_name(&self) -> String {
        join(&self.namespace, &self.name)
    }

    /// The absolute name a topic or service name stands for, remapped.
    pub fn resolve(&self, name: &str) -> Result<String, NodeError> {
        let expanded = self.expand(name)?;
        let remapped = self.remaps.iter().find(|(from, _)| *from == expanded).map(|(_, to)| to.clone());
        Ok(remapped.unwrap_or(expanded))
    }

    fn expand(&self, name: &str) -> Result<String, NodeError> {
        let expanded = if name.starts_with('/') {
            name.to_owned()
        } else if name == "~" {
            self.full_name()
        } else if let Some(private) = name.strip_prefix("~/") {
            join(&self.full_name(), private)
        } else {
            join(&self.namespace, name)
        };
        check_name(&expanded, "topic name")?;
        Ok(expanded)
    }
}

fn join(namespace: &str, name: &str) -> String {
    if namespace == "/" {
        format!("/{name}")
    } else {
        format!("{namespace}/{name}")
    }
}

/// ROS 2's rules: tokens of letters, digits and `_`, not starting with a digit, no `__`, no empty
/// token.
fn check_name(name: &str, what: &str) -> Result<(), NodeError> {
    let bad = |why: &str| Err(NodeError::Args(format!("{what} {name:?}: {why}")));
    if name == "/" {
        return Ok(());
    }
    for token in name.trim_start_matches('/').split('/') {
        if token.is_empty() {
            return bad("has an empty token");
        }
        if token.starts_with(|c: char| c.is_ascii_digit()) || token.contains("__") {
            return bad("a token starts with a digit or holds '__'");
        }
        if let Some(c) = token.chars().find(|c| !(c.is_ascii_alphanumeric() || *c == '_')) {
            return bad(&format!("{c:?} is not allowed"));
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used)]
    use super::*;

    #[test]
    fn names_resolve_in_the_namespace_and_remap_on_resolved_names() {
        let remaps = [
            Remap { node: None, from: "image".into(), to: "/camera/image_raw".into() },
            Remap { node: Some("mapper".into()), from: "cloud".into(), to: "other".into() },
            Remap { node: Some("ingest".into()), from: "/odom".into(), to: "nav/odom".into() },
        ];
        let names = Names::new("/auv", "ingest", &remaps).unwrap();
        assert_eq!(names.full_name(), "/auv/ingest");
        assert_eq!(names.resolve("image").unwrap(), "/camera/image_raw");
        assert_eq!(names.resolve("/auv/image").unwrap(), "/camera/image_raw");
        assert_eq!(names.resolve("cloud").unwrap(), "/auv/cloud");
        assert_eq!(names.resolve("/odom").unwrap(), "/auv/nav/odom");
        assert_eq!(names.resolve("~/state").unwrap(), "/auv/ingest/state");
        assert_eq!(Names::new("/", "n", &[]).unwrap().resolve("clock").unwrap(), "/clock");
        assert!(names.resolve("bad name").unwrap_err().to_string().contains("' ' is not allowed"));
        assert!(names.resolve("a//b").is_err());
        assert!(Names::new("/1ns", "n", &[]).is_err());
    }
}
