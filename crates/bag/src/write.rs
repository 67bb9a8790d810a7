//! Writing rosbag2-compatible mcap: a bag folder `NAME/` holding `NAME_0.mcap` and `metadata.yaml`.

use crate::{
    metadata::{
        FileInfo, Metadata, MetadataFile, Nanoseconds, NanosecondsSinceEpoch, QosProfile, TopicMetadata, TopicWithCount,
    },
    BagError,
};
use revisit_msgs::{Definition, Message};
use std::{
    collections::BTreeMap,
    fs,
    io::BufWriter,
    marker::PhantomData,
    path::{Path, PathBuf},
};

/// A topic added to a [`BagWriter`], typed by its message.
#[derive(Debug)]
pub struct TopicHandle<M> {
    index: usize,
    message: PhantomData<fn(&M)>,
}

impl<M> Clone for TopicHandle<M> {
    fn clone(&self) -> Self {
        *self
    }
}

impl<M> Copy for TopicHandle<M> {}

struct WriterTopic {
    channel_id: u16,
    name: String,
    type_name: &'static str,
    qos: QosProfile,
    count: u64,
    sequence: u32,
}

/// Writes one bag. Nothing is a bag until [`BagWriter::finish`] writes the summary and
/// `metadata.yaml`; a writer dropped before leaves a recoverable mcap without them.
pub struct BagWriter {
    dir: PathBuf,
    file_name: String,
    mcap: mcap::Writer<BufWriter<fs::File>>,
    topics: Vec<WriterTopic>,
    time_range_ns: Option<(u64, u64)>,
}

/// What [`BagWriter::finish`] wrote.
#[derive(Debug, Clone)]
pub struct WrittenBag {
    pub dir: PathBuf,
    pub mcap: PathBuf,
    pub messages: u64,
}

impl BagWriter {
    /// Creates the bag folder `dir` (which must not exist yet, as with `ros2 bag record`).
    pub fn create(dir: &Path) -> Result<BagWriter, BagError> {
        let io = |path: &Path| {
            let path = path.to_owned();
            move |source| BagError::Io { path, source }
        };
        let name = dir
            .file_name()
            .and_then(|n| n.to_str())
            .filter(|n| !n.is_empty())
            .ok_or_else(|| BagError::NotABag { path: dir.to_owned(), why: "a bag folder needs a UTF-8 name".into() })?;
        fs::create_dir(dir).map_err(io(dir))?;
        let file_name = format!("{name}_0.mcap");
        let path = dir.join(&file_name);
        let file = fs::File::create(&path).map_err(io(&path))?;
        let mcap = mcap::WriteOptions::new()
            .profile("ros2")
            .library(concat!("revisit ", env!("CARGO_PKG_VERSION")))
            .compression(Some(mcap::Compression::Zstd))
            .create(BufWriter::with_capacity(1 << 20, file))
            .map_err(|source| BagError::Mcap { path: path.clone(), source })?;
        Ok(BagWriter { dir: dir.to_owned(), file_name, mcap, topics: Vec::new(), time_range_ns: None })
    }

    fn mcap_path(&self) -> PathBuf {
        self.dir.join(&self.file_name)
    }

    /// Adds a topic of message type `M`, offered with `qos`.
    pub fn add_topic<M: Message>(&mut self, name: &str, qos: QosProfile) -> Result<TopicHandle<M>, BagError> {
        let index = self.add_raw_topic(name, M::DEFINITION, qos)?;
        Ok(TopicHandle { index, message: PhantomData })
    }

    /// Adds a topic of a type known at run time; [`BagWriter::write_raw`] writes its messages.
    pub fn add_raw_topic(
        &mut self,
        name: &str,
        definition: &'static Definition,
        qos: QosProfile,
    ) -> Result<usize, BagError> {
        let path = self.mcap_path();
        let mcap_error = |source| BagError::Mcap { path: path.clone(), source };
        if self.topics.iter().any(|t| t.name == name) {
            return Err(BagError::Topic { path: path.clone(), topic: name.to_owned(), why: "added twice".into() });
        }
        let schema_id =
            self.mcap.add_schema(definition.name, "ros2msg", definition.schema().as_bytes()).map_err(mcap_error)?;
        let qos_yaml =
            serde_yaml_ng::to_string(&[qos]).map_err(|source| BagError::Metadata { path: path.clone(), source })?;
        let metadata = BTreeMap::from([("offered_qos_profiles".to_owned(), qos_yaml)]);
        let channel_id = self.mcap.add_channel(schema_id, name, "cdr", &metadata).map_err(mcap_error)?;
        self.topics.push(WriterTopic {
            channel_id,
            name: name.to_owned(),
            type_name: definition.name,
            qos,
            count: 0,
            sequence: 0,
        });
        Ok(self.topics.len() - 1)
    }

    /// Writes one message received at `log_time_ns` (nanoseconds since the epoch).
    pub fn write<M: Message>(&mut self, topic: TopicHandle<M>, log_time_ns: u64, message: &M) -> Result<(), BagError> {
        let data = revisit_msgs::encode(message).map_err(|source| BagError::Encode {
            path: self.mcap_path(),
            topic: self.topics[topic.index].name.clone(),
            source,
        })?;
        self.write_raw(topic.index, log_time_ns, &data)
    }

    /// Writes one message's CDR bytes (with their encapsulation header) to a topic of
    /// [`BagWriter::add_raw_topic`].
    pub fn write_raw(&mut self, topic: usize, log_time_ns: u64, data: &[u8]) -> Result<(), BagError> {
        let path = self.mcap_path();
        let entry = &mut self.topics[topic];
        entry.count += 1;
        entry.sequence = entry.sequence.wrapping_add(1);
        let header = mcap::records::MessageHeader {
            channel_id: entry.channel_id,
            sequence: entry.sequence,
            log_time: log_time_ns,
            publish_time: log_time_ns,
        };
        self.mcap.write_to_known_channel(&header, data).map_err(|source| BagError::Mcap { path, source })?;
        self.time_range_ns = Some(match self.time_range_ns {
            None => (log_time_ns, log_time_ns),
            Some((first, last)) => (first.min(log_time_ns), last.max(log_time_ns)),
        });
        Ok(())
    }

    /// Writes the mcap summary (statistics, indexes) and `metadata.yaml`.
    pub fn finish(mut self) -> Result<WrittenBag, BagError> {
        let path = self.mcap_path();
        self.mcap.finish().map_err(|source| BagError::Mcap { path: path.clone(), source })?;
        let (first, last) = self.time_range_ns.unwrap_or((0, 0));
        let messages = self.topics.iter().map(|t| t.count).sum();
        let metadata = MetadataFile {
            rosbag2_bagfile_information: Metadata {
                version: 9,
                storage_identifier: "mcap".into(),
                duration: Nanoseconds { nanoseconds: last - first },
                starting_time: NanosecondsSinceEpoch { nanoseconds_since_epoch: first },
                message_count: messages,
                topics_with_message_count: self
                    .topics
                    .iter()
                    .map(|t| TopicWithCount {
                        topic_metadata: TopicMetadata {
                            name: t.name.clone(),
                            type_name: t.type_name.into(),
                            serialization_format: "cdr".into(),
                            offered_qos_profiles: vec![t.qos],
                            type_description_hash: String::new(),
                        },
                        message_count: t.count,
                    })
                    .collect(),
                relative_file_paths: vec![self.file_name.clone()],
                files: vec![FileInfo {
                    path: self.file_name.clone(),
                    starting_time: NanosecondsSinceEpoch { nanoseconds_since_epoch: first },
                    duration: Nanoseconds { nanoseconds: last - first },
                    message_count: messages,
                }],
                ..Metadata::default()
            },
        };
        let metadata_path = self.dir.join("metadata.yaml");
        let yaml = serde_yaml_ng::to_string(&metadata)
            .map_err(|source| BagError::Metadata { path: metadata_path.clone(), source })?;
        fs::write(&metadata_path, yaml).map_err(|source| BagError::Io { path: metadata_path, source })?;
        Ok(WrittenBag { dir: self.dir, mcap: path, messages })
    }
}
