//! The ROS 2 messages Revisit reads and writes.
//!
//! Each message is a serde type mirroring its `.msg` file field by field (the files are in
//! `interfaces/` for ROS's own packages and in `revisit_msgs/msg/` for Revisit's, a ROS 2 interface
//! package a user can build with colcon). [`Message::DEFINITION`] carries the full ROS type name and
//! the `.msg` text; [`Definition::schema`] is the ros2msg schema rosbag2 writes (dependencies
//! concatenated). [`encode`] and [`decode`] speak CDR with its encapsulation header, as DDS and
//! rosbag2 carry it. `tests/python.rs` checks every type against independent decoders.

mod cdr;
mod fixed;
mod registry;
pub mod sample;

pub mod builtin_interfaces;
pub mod diagnostic_msgs;
pub mod geometry_msgs;
pub mod nav_msgs;
pub mod revisit_msgs;
pub mod rosgraph_msgs;
pub mod sensor_msgs;
pub mod services;
pub mod std_msgs;
pub mod tf2_msgs;

pub use cdr::{decode, encode, CdrError};
pub use registry::{find, MessageType, ALL};

use serde::{de::DeserializeOwned, Serialize};

/// A message type: its name, its `.msg` text and the types its fields use.
#[derive(Debug)]
pub struct Definition {
    /// The full ROS type name, e.g. `sensor_msgs/msg/Image`.
    pub name: &'static str,
    /// The `.msg` file's text.
    pub text: &'static str,
    /// The message types its fields name, each once.
    pub uses: &'static [&'static Definition],
}

impl Definition {
    /// The ros2msg schema as rosbag2 writes it: this type's text, then every type it uses (depth
    /// first, each once) after a line of 80 `=` and `MSG: package/Type`.
    pub fn schema(&self) -> String {
        let mut schema = self.text.trim_end().to_owned();
        schema.push('\n');
        let mut seen = vec![self.name];
        self.append_uses(&mut schema, &mut seen);
        schema
    }

    fn append_uses(&self, schema: &mut String, seen: &mut Vec<&'static str>) {
        for used in self.uses {
            if seen.contains(&used.name) {
                continue;
            }
            seen.push(used.name);
            schema.push_str(&"=".repeat(80));
            schema.push_str("\nMSG: ");
            schema.push_str(&used.name.replacen("/msg/", "/", 1));
            schema.push('\n');
            schema.push_str(used.text.trim_end());
            schema.push('\n');
            used.append_uses(schema, seen);
        }
    }
}

/// A ROS 2 message type with its definition.
pub trait Message: Serialize + DeserializeOwned + 'static {
    const DEFINITION: &'static Definition;
}

/// Declares a type's [`Message`] implementation from its `.msg` file.
macro_rules! message {
    ($ty:ident, $package:literal, $dir:expr, [$($used:ty),* $(,)?]) => {
        impl $crate::Message for $ty {
            const DEFINITION: &'static $crate::Definition = &$crate::Definition {
                name: concat!($package, "/msg/", stringify!($ty)),
                text: include_str!(concat!(
                    env!("CARGO_MANIFEST_DIR"), "/", $dir, "/msg/", stringify!($ty), ".msg"
                )),
                uses: &[$(<$used as $crate::Message>::DEFINITION),*],
            };
        }
    };
}

/// [`message!`] for ROS's own packages, whose `.msg` files are in `interfaces/PACKAGE`.
macro_rules! ros_message {
    ($ty:ident, $package:literal, [$($used:ty),* $(,)?]) => {
        $crate::message!($ty, $package, concat!("interfaces/", $package), [$($used),*]);
    };
}

pub(crate) use {message, ros_message};
