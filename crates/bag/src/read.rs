//! Reading bags: storage files found from `metadata.yaml` (or the folder's files, or the single file
//! given), then messages streamed file by file.

use crate::{
    metadata::{ReadMetadataFile, Storage},
    BagError,
};
use rusqlite::{Connection, OpenFlags, OptionalExtension};
use std::{
    collections::{BTreeMap, HashMap, VecDeque},
    fs,
    io::BufReader,
    path::{Path, PathBuf},
    sync::Arc,
};

/// A topic as the bag declares it.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Topic {
    pub name: String,
    /// The full ROS type name, e.g. `sensor_msgs/msg/Image`.
    pub type_name: String,
    /// `cdr` for ROS 2 bags.
    pub serialization_format: String,
    /// The ros2msg schema text, when the storage keeps it (mcap does, sqlite3 does not).
    pub schema: Option<String>,
    /// What its recorded publishers offered, when the bag says (`offered_qos_profiles`).
    pub offered: Option<Offered>,
}

/// The QoS a topic's publishers offered when it was recorded, as far as a player needs it.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Offered {
    /// Every publisher was reliable.
    pub reliable: bool,
    /// Every publisher kept its last messages for late subscribers (a latched topic).
    pub transient_local: bool,
}

impl Offered {
    /// From rosbag2's `offered_qos_profiles` YAML: a list of profiles whose `reliability` and
    /// `durability` are rmw's numbers (1 reliable / transient local) or, from Iron on, names.
    pub fn parse(yaml: &str) -> Option<Offered> {
        let profiles: Vec<serde_yaml_ng::Value> = serde_yaml_ng::from_str(yaml).ok()?;
        let is = |profile: &serde_yaml_ng::Value, key: &str, number: u64, name: &str| match profile.get(key) {
            Some(serde_yaml_ng::Value::Number(n)) => n.as_u64() == Some(number),
            Some(serde_yaml_ng::Value::String(s)) => s.eq_ignore_ascii_case(name),
            _ => false,
        };
        (!profiles.is_empty()).then(|| Offered {
            reliable: profiles.iter().all(|p| is(p, "reliability", 1, "reliable")),
            transient_local: profiles.iter().all(|p| is(p, "durability", 1, "transient_local")),
        })
    }
}

/// One message as stored: its topic, its receive time and its serialized bytes.
#[derive(Debug, Clone)]
pub struct RawMessage {
    pub topic: Arc<Topic>,
    /// When the recorder received it, nanoseconds since the epoch.
    pub log_time_ns: u64,
    pub data: Vec<u8>,
}

/// A bag opened for reading.
#[derive(Debug, Clone)]
pub struct Bag {
    path: PathBuf,
    storage: Storage,
    files: Vec<PathBuf>,
}

impl Bag {
    /// Opens a bag folder (with `metadata.yaml`, or holding `.mcap` or `.db3` files) or a single
    /// `.mcap` or `.db3` file. Reads nothing but the metadata.
    pub fn open(path: &Path) -> Result<Bag, BagError> {
        let not_a_bag = |why: &str| BagError::NotABag { path: path.to_owned(), why: why.to_owned() };
        let meta = fs::metadata(path).map_err(|source| BagError::Io { path: path.to_owned(), source })?;
        let files = if meta.is_dir() {
            let metadata_path = path.join("metadata.yaml");
            if metadata_path.is_file() {
                files_of_metadata(path, &metadata_path)?
            } else {
                let mut files = storage_files_in(path)?;
                files.sort();
                files
            }
        } else {
            vec![path.to_owned()]
        };
        let Some(first) = files.first() else {
            return Err(not_a_bag("no metadata.yaml and no .mcap or .db3 file in the folder"));
        };
        let storage = Storage::of_file(first).ok_or_else(|| not_a_bag("a bag's storage is a .mcap or .db3 file"))?;
        if let Some(other) = files.iter().find(|f| Storage::of_file(f) != Some(storage)) {
            return Err(not_a_bag(&format!("{} is not {} storage", other.display(), storage.identifier())));
        }
        for file in &files {
            if !file.is_file() {
                return Err(BagError::NotABag { path: file.clone(), why: "the storage file is missing".into() });
            }
        }
        Ok(Bag { path: path.to_owned(), storage, files })
    }

    pub fn path(&self) -> &Path {
        &self.path
    }

    pub fn storage(&self) -> Storage {
        self.storage
    }

    pub fn files(&self) -> &[PathBuf] {
        &self.files
    }

    /// Every message, file by file in storage order (time order within a file for sqlite3,
    /// recording order for mcap). After an error that leaves a file unreadable (truncated,
    /// corrupt), the iteration goes on with the next file.
    pub fn messages(&self) -> Messages {
        Messages { storage: self.storage, files: self.files.iter().cloned().collect(), current: None }
    }

    /// Topics, counts and times, from reading every message (not from metadata, which a recorder
    /// killed mid-way never wrote).
    pub fn info(&self) -> Result<BagInfo, BagError> {
        let mut topics: BTreeMap<String, TopicStats> = BTreeMap::new();
        for message in self.messages() {
            let message = message?;
            let stats = topics.entry(message.topic.name.clone()).or_insert_with(|| TopicStats {
                topic: Topic::clone(&message.topic),
                count: 0,
                first_ns: message.log_time_ns,
                last_ns: message.log_time_ns,
            });
            stats.count += 1;
            stats.first_ns = stats.first_ns.min(message.log_time_ns);
            stats.last_ns = stats.last_ns.max(message.log_time_ns);
        }
        let mut bytes = 0;
        for file in &self.files {
            bytes += fs::metadata(file).map_err(|source| BagError::Io { path: file.clone(), source })?.len();
        }
        Ok(BagInfo { storage: self.storage, files: self.files.clone(), bytes, topics: topics.into_values().collect() })
    }
}

/// What `bag info` shows.
#[derive(Debug, Clone)]
pub struct BagInfo {
    pub storage: Storage,
    pub files: Vec<PathBuf>,
    pub bytes: u64,
    /// By topic name.
    pub topics: Vec<TopicStats>,
}

impl BagInfo {
    pub fn message_count(&self) -> u64 {
        self.topics.iter().map(|t| t.count).sum()
    }

    /// First and last log times over all topics, nanoseconds; `None` for an empty bag.
    pub fn time_range_ns(&self) -> Option<(u64, u64)> {
        let first = self.topics.iter().map(|t| t.first_ns).min()?;
        let last = self.topics.iter().map(|t| t.last_ns).max()?;
        Some((first, last))
    }
}

#[derive(Debug, Clone)]
pub struct TopicStats {
    pub topic: Topic,
    pub count: u64,
    pub first_ns: u64,
    pub last_ns: u64,
}

impl TopicStats {
    /// Messages per second between the first and the last; `None` for fewer than two.
    pub fn rate_hz(&self) -> Option<f64> {
        let span_ns = self.last_ns.checked_sub(self.first_ns).filter(|&s| s > 0)?;
        (self.count > 1).then(|| (self.count - 1) as f64 * 1e9 / span_ns as f64)
    }
}

fn files_of_metadata(dir: &Path, metadata_path: &Path) -> Result<Vec<PathBuf>, BagError> {
    let text =
        fs::read_to_string(metadata_path).map_err(|source| BagError::Io { path: metadata_path.to_owned(), source })?;
    let metadata: ReadMetadataFile = serde_yaml_ng::from_str(&text)
        .map_err(|source| BagError::Metadata { path: metadata_path.to_owned(), source })?;
    let info = metadata.rosbag2_bagfile_information;
    if !info.compression_mode.is_empty() {
        return Err(BagError::NotABag {
            path: metadata_path.to_owned(),
            why: format!(
                "{} compression of whole files is not supported; decompress the bag first",
                info.compression_format
            ),
        });
    }
    if info.relative_file_paths.is_empty() {
        return storage_files_in(dir);
    }
    Ok(info.relative_file_paths.iter().map(|p| dir.join(p)).collect())
}

fn storage_files_in(dir: &Path) -> Result<Vec<PathBuf>, BagError> {
    let entries = fs::read_dir(dir).map_err(|source| BagError::Io { path: dir.to_owned(), source })?;
    let mut files = Vec::new();
    for entry in entries {
        let path = entry.map_err(|source| BagError::Io { path: dir.to_owned(), source })?.path();
        if Storage::of_file(&path).is_some() {
            files.push(path);
        }
    }
    Ok(files)
}

/// The messages of a bag, file by file.
pub struct Messages {
    storage: Storage,
    files: VecDeque<PathBuf>,
    current: Option<Source>,
}

enum Source {
    Mcap(Box<McapSource>),
    Sqlite(Box<SqliteSource>),
}

impl Iterator for Messages {
    type Item = Result<RawMessage, BagError>;

    fn next(&mut self) -> Option<Self::Item> {
        loop {
            let current = match &mut self.current {
                Some(current) => current,
                None => {
                    let path = self.files.pop_front()?;
                    let opened = match self.storage {
                        Storage::Mcap => McapSource::open(path).map(|s| Source::Mcap(Box::new(s))),
                        Storage::Sqlite3 => SqliteSource::open(path).map(|s| Source::Sqlite(Box::new(s))),
                    };
                    match opened {
                        Ok(source) => self.current.insert(source),
                        Err(error) => return Some(Err(error)),
                    }
                }
            };
            let next = match current {
                Source::Mcap(source) => source.next(),
                Source::Sqlite(source) => source.next(),
            };
            match next {
                Some(Ok(message)) => return Some(Ok(message)),
                Some(Err(error)) => {
                    // A file whose reader errs is left: it cannot go on past the damage. One bad
                    // row is only skipped.
                    if !matches!(error, BagError::BadMessage { .. }) {
                        self.current = None;
                    }
                    return Some(Err(error));
                }
                None => self.current = None,
            }
        }
    }
}

/// mcap read with the crate's sans-IO [`mcap::sans_io::LinearReader`] (chunks decompressed,
/// lengths checked against the file's size). Only schemas, channels and messages are parsed, and
/// only after every length prefix in them is checked to fit its record: the crate's parser would
/// otherwise allocate whatever a corrupt string length says.
struct McapSource {
    path: PathBuf,
    file: BufReader<fs::File>,
    reader: mcap::sans_io::LinearReader,
    schemas: HashMap<u16, (String, String)>,
    topics: HashMap<u16, Arc<Topic>>,
    done: bool,
}

impl McapSource {
    fn open(path: PathBuf) -> Result<Self, BagError> {
        let file = fs::File::open(&path).map_err(|source| BagError::Io { path: path.clone(), source })?;
        let len = file.metadata().map_err(|source| BagError::Io { path: path.clone(), source })?.len();
        // No record can be longer than the file: a corrupt length fails instead of allocating.
        let options = mcap::sans_io::LinearReaderOptions::default()
            .with_emit_chunks(false)
            .with_record_length_limit(usize::try_from(len).unwrap_or(usize::MAX));
        Ok(McapSource {
            path,
            file: BufReader::with_capacity(1 << 20, file),
            reader: mcap::sans_io::LinearReader::new_with_options(options),
            schemas: HashMap::new(),
            topics: HashMap::new(),
            done: false,
        })
    }

    fn next(&mut self) -> Option<Result<RawMessage, BagError>> {
        if self.done {
            return None;
        }
        let result = self.next_message();
        if !matches!(result, Some(Ok(_)) | Some(Err(BagError::BadMessage { .. }))) {
            self.done = true;
        }
        result
    }

    fn next_message(&mut self) -> Option<Result<RawMessage, BagError>> {
        use mcap::{records::op, records::Record, sans_io::LinearReadEvent};
        let corrupt = |path: &Path, source| BagError::Mcap { path: path.to_owned(), source };
        loop {
            let event = match self.reader.next_event()? {
                Ok(event) => event,
                Err(source) => return Some(Err(corrupt(&self.path, source))),
            };
            let (opcode, data) = match event {
                LinearReadEvent::ReadRequest(need) => {
                    let read = loop {
                        match std::io::Read::read(&mut self.file, self.reader.insert(need)) {
                            Ok(read) => break read,
                            Err(error) if error.kind() == std::io::ErrorKind::Interrupted => continue,
                            Err(source) => return Some(Err(BagError::Io { path: self.path.clone(), source })),
                        }
                    };
                    self.reader.notify_read(read);
                    continue;
                }
                LinearReadEvent::Record { opcode, data } => (opcode, data),
            };
            let fits = match opcode {
                op::SCHEMA => prefixed_end(data, 2, 3).is_some(),
                op::CHANNEL => prefixed_end(data, 4, 2).and_then(|end| string_map_end(data, end)).is_some(),
                op::MESSAGE => true,
                _ => continue,
            };
            if !fits {
                let why = format!("corrupt mcap: a length in a record of opcode {opcode:#04x} runs past the record");
                return Some(Err(BagError::NotABag { path: self.path.clone(), why }));
            }
            match mcap::parse_record(opcode, data) {
                Ok(Record::Schema { header, data }) => {
                    let text = String::from_utf8_lossy(&data).into_owned();
                    self.schemas.insert(header.id, (header.name, text));
                }
                Ok(Record::Channel(channel)) => {
                    let (type_name, schema) = match self.schemas.get(&channel.schema_id) {
                        Some((name, text)) => (name.clone(), Some(text.clone())),
                        None => (String::new(), None),
                    };
                    let offered = channel.metadata.get("offered_qos_profiles").and_then(|y| Offered::parse(y));
                    let topic = Topic {
                        name: channel.topic,
                        type_name,
                        serialization_format: channel.message_encoding,
                        schema,
                        offered,
                    };
                    self.topics.insert(channel.id, Arc::new(topic));
                }
                Ok(Record::Message { header, data }) => {
                    let Some(topic) = self.topics.get(&header.channel_id) else {
                        let why = format!(
                            "a message at {} ns names channel {}, which was not declared",
                            header.log_time, header.channel_id
                        );
                        return Some(Err(BagError::BadMessage { path: self.path.clone(), why }));
                    };
                    return Some(Ok(RawMessage {
                        topic: topic.clone(),
                        log_time_ns: header.log_time,
                        data: data.into_owned(),
                    }));
                }
                Ok(_) => {}
                Err(source) => return Some(Err(corrupt(&self.path, source))),
            }
        }
    }
}

/// The end of `count` u32-length-prefixed fields starting at `at`, if each fits in `record`.
fn prefixed_end(record: &[u8], mut at: usize, count: usize) -> Option<usize> {
    for _ in 0..count {
        let len = u32::from_le_bytes(record.get(at..at + 4)?.try_into().ok()?) as usize;
        at = at.checked_add(4)?.checked_add(len).filter(|&end| end <= record.len())?;
    }
    Some(at)
}

/// The end of a map of strings (u32 byte length, then key and value strings) at `at`, if it and
/// every string in it fit in `record`.
fn string_map_end(record: &[u8], at: usize) -> Option<usize> {
    let end = prefixed_end(record, at, 1)?;
    let map = &record[at + 4..end];
    let mut inner = 0;
    while inner < map.len() {
        inner = prefixed_end(map, inner, 2)?;
    }
    Some(end)
}

/// rosbag2's sqlite3 storage: tables `topics(id, name, type, serialization_format, ...)` and
/// `messages(id, topic_id, timestamp, data)`, read in time order a page at a time.
struct SqliteSource {
    path: PathBuf,
    connection: Connection,
    topics: HashMap<i64, Arc<Topic>>,
    page: VecDeque<(i64, i64, i64, Vec<u8>)>,
    after: (i64, i64),
    done: bool,
}

const SQLITE_PAGE: i64 = 64;

impl SqliteSource {
    fn open(path: PathBuf) -> Result<Self, BagError> {
        let sqlite = |source| BagError::Sqlite { path: path.clone(), source };
        let connection =
            Connection::open_with_flags(&path, OpenFlags::SQLITE_OPEN_READ_ONLY | OpenFlags::SQLITE_OPEN_NO_MUTEX)
                .map_err(sqlite)?;
        let has_tables: Option<i64> = connection
            .query_row(
                "SELECT count(*) FROM sqlite_master WHERE type = 'table' AND name IN ('topics', 'messages')",
                [],
                |row| row.get(0),
            )
            .optional()
            .map_err(sqlite)?;
        if has_tables != Some(2) {
            return Err(BagError::NotABag {
                path: path.clone(),
                why: "a rosbag2 .db3 has tables topics and messages".into(),
            });
        }
        let mut topics = HashMap::new();
        {
            // offered_qos_profiles came with rosbag2's schema version 2; older bags lack it.
            let mut statement = connection
                .prepare("SELECT id, name, type, serialization_format, offered_qos_profiles FROM topics")
                .or_else(|_| connection.prepare("SELECT id, name, type, serialization_format, NULL FROM topics"))
                .map_err(sqlite)?;
            let rows = statement
                .query_map([], |row| {
                    let qos: Option<String> = row.get(4).unwrap_or(None);
                    Ok((
                        row.get::<_, i64>(0)?,
                        Topic {
                            name: row.get(1)?,
                            type_name: row.get(2)?,
                            serialization_format: row.get(3)?,
                            schema: None,
                            offered: qos.as_deref().and_then(Offered::parse),
                        },
                    ))
                })
                .map_err(sqlite)?;
            for row in rows {
                let (id, topic) = row.map_err(sqlite)?;
                topics.insert(id, Arc::new(topic));
            }
        }
        Ok(SqliteSource { path, connection, topics, page: VecDeque::new(), after: (i64::MIN, i64::MIN), done: false })
    }

    fn fill_page(&mut self) -> Result<(), rusqlite::Error> {
        let mut statement = self.connection.prepare_cached(
            "SELECT id, topic_id, timestamp, data FROM messages \
             WHERE (timestamp, id) > (?1, ?2) ORDER BY timestamp, id LIMIT ?3",
        )?;
        let rows = statement.query_map((self.after.0, self.after.1, SQLITE_PAGE), |row| {
            Ok((row.get(0)?, row.get(1)?, row.get(2)?, row.get(3)?))
        })?;
        for row in rows {
            self.page.push_back(row?);
        }
        self.done = (self.page.len() as i64) < SQLITE_PAGE;
        Ok(())
    }

    fn next(&mut self) -> Option<Result<RawMessage, BagError>> {
        if self.page.is_empty() && !self.done {
            if let Err(source) = self.fill_page() {
                self.done = true;
                return Some(Err(BagError::Sqlite { path: self.path.clone(), source }));
            }
        }
        let (id, topic_id, timestamp, data) = self.page.pop_front()?;
        self.after = (timestamp, id);
        let bad_row =
            |why: String| BagError::BadMessage { path: self.path.clone(), why: format!("messages row {id}: {why}") };
        let Some(topic) = self.topics.get(&topic_id) else {
            return Some(Err(bad_row(format!("topic_id {topic_id} is not in the topics table"))));
        };
        let Ok(log_time_ns) = u64::try_from(timestamp) else {
            return Some(Err(bad_row(format!("negative timestamp {timestamp}"))));
        };
        Some(Ok(RawMessage { topic: topic.clone(), log_time_ns, data }))
    }
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used)]
    use super::*;
    use crate::QosProfile;

    #[test]
    fn offered_qos_reads_numbers_and_names_and_what_every_publisher_offered() {
        let latched = "- history: 1\n  depth: 1\n  reliability: 1\n  durability: 1\n";
        assert_eq!(Offered::parse(latched), Some(Offered { reliable: true, transient_local: true }));
        let named = "- history: keep_last\n  reliability: best_effort\n  durability: volatile\n";
        assert_eq!(Offered::parse(named), Some(Offered { reliable: false, transient_local: false }));
        let mixed = "- {reliability: reliable, durability: transient_local}\n- {reliability: 1, durability: 2}\n";
        assert_eq!(Offered::parse(mixed), Some(Offered { reliable: true, transient_local: false }));
        assert_eq!(Offered::parse("[]"), None);
        assert_eq!(Offered::parse(": not yaml"), None);
    }

    #[test]
    fn a_written_bag_reads_back_its_offered_qos() {
        let dir = tempfile::tempdir().unwrap();
        let mut writer = crate::BagWriter::create(&dir.path().join("bag")).unwrap();
        let latched = writer.add_topic::<revisit_msgs::builtin_interfaces::Time>("/latched", QosProfile::LATCHED);
        let sensor = writer.add_topic::<revisit_msgs::builtin_interfaces::Time>("/sensor", QosProfile::SENSOR_DATA);
        writer.write(latched.unwrap(), 1, &Default::default()).unwrap();
        writer.write(sensor.unwrap(), 2, &Default::default()).unwrap();
        let bag = Bag::open(&writer.finish().unwrap().dir).unwrap();
        let offered: Vec<_> = bag.messages().map(|m| m.unwrap().topic.offered).collect();
        assert_eq!(
            offered,
            [
                Some(Offered { reliable: true, transient_local: true }),
                Some(Offered { reliable: false, transient_local: false })
            ]
        );
    }
}
