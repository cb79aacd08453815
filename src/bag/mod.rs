//! ROS 2 bags as MCAP files: profile `ros2`, schema encoding `ros2msg` (see
//! [`crate::msgs::schema_text`]), message encoding `cdr`.
//!
//! [`BagWriter`] writes one schema per message type and one channel per topic.
//! [`BagReader`] reads a whole file into memory, tolerating damage: every message before a
//! truncation is kept, a chunk whose CRC fails is dropped whole while the chunks after it
//! are kept, and the damage is reported as an error naming the file after the good
//! messages.

pub mod rig_bag;
pub mod same_image;

use std::collections::{BTreeMap, HashMap};
use std::fs::File;
use std::io::BufWriter;
use std::path::{Path, PathBuf};

use mcap::records::{MessageHeader, Metadata, Record};
use mcap::{Compression, WriteOptions, Writer};

use crate::geometry::rig::RigError;
use crate::msgs::{decode_cdr, encode_cdr, ImageMsgError, MsgError, RosMessage};

pub use rig_bag::{
    rig_tf_static, RigBagReader, RigBagWriter, DEFAULT_MAX_DEPTH_M, GROUND_TRUTH_TOPIC,
    MAX_DEPTH_KEY, RIG_METADATA, RIG_YAML_KEY, SOILED_KEY, SYNTH_METADATA, TF_STATIC_TOPIC,
};
pub use same_image::{write_same_image_bag, SameImageSummary, SAME_IMAGE_METADATA};

/// MCAP profile of ROS 2 bags.
pub const PROFILE: &str = "ros2";
/// MCAP schema encoding of `.msg` text.
pub const SCHEMA_ENCODING: &str = "ros2msg";
/// MCAP message encoding of ROS 2 messages.
pub const MESSAGE_ENCODING: &str = "cdr";
/// Channel metadata key rosbag2 uses for the publisher QoS.
const QOS_METADATA_KEY: &str = "offered_qos_profiles";
/// rosbag2's QoS durability code of a latched (transient local) publisher.
const DURABILITY_TRANSIENT_LOCAL: u8 = 1;
/// rosbag2's QoS durability code of an ordinary (volatile) publisher.
const DURABILITY_VOLATILE: u8 = 2;

/// rosbag2 (Humble) QoS YAML: keep-last history, reliable, with the given durability,
/// infinite deadline, lifespan and lease.
fn qos_yaml(durability: u8) -> String {
    const INFINITE: &str = "\n    sec: 2147483647\n    nsec: 4294967295";
    format!(
        "- history: 1\n  depth: 1\n  reliability: 1\n  durability: {durability}\n  \
         deadline:{INFINITE}\n  lifespan:{INFINITE}\n  liveliness: 1\n  \
         liveliness_lease_duration:{INFINITE}\n  avoid_ros_namespace_conventions: false"
    )
}

/// A bag that cannot be written or read. Every variant names the file.
#[derive(Debug, thiserror::Error)]
pub enum BagError {
    #[error("{file}: {action}: {source}")]
    Io {
        file: String,
        action: &'static str,
        #[source]
        source: std::io::Error,
    },
    #[error("{file}: MCAP error while {action}: {source}")]
    Mcap {
        file: String,
        action: &'static str,
        #[source]
        source: mcap::McapError,
    },
    #[error("{file}: damaged bag ({detail}); {good_messages} good messages were kept")]
    Damaged {
        file: String,
        detail: String,
        good_messages: usize,
    },
    #[error("{file}: not a readable MCAP file: {detail}")]
    NotMcap { file: String, detail: String },
    #[error("{file}: topic '{topic}': {source}")]
    Msg {
        file: String,
        topic: String,
        #[source]
        source: MsgError,
    },
    #[error("{file}: topic '{topic}' carries '{found}', not '{expected}'")]
    TypeMismatch {
        file: String,
        topic: String,
        expected: String,
        found: String,
    },
    #[error("{file}: topic '{topic}' has no messages")]
    MissingTopic { file: String, topic: String },
    #[error("{file}: metadata record '{name}' (key '{key}') is missing")]
    MissingMetadata {
        file: String,
        name: String,
        key: String,
    },
    #[error("{file}: rig from metadata: {source}")]
    Rig {
        file: String,
        #[source]
        source: RigError,
    },
    #[error("{file}: topic '{topic}', stamp {stamp_ns} ns: {source}")]
    Image {
        file: String,
        topic: String,
        stamp_ns: u64,
        #[source]
        source: ImageMsgError,
    },
    #[error("{file}: topic '{topic}', stamp {stamp_ns} ns, field '{field}': {problem}")]
    Frame {
        file: String,
        topic: String,
        stamp_ns: u64,
        field: String,
        problem: String,
    },
}

/// Chunk compression of a written bag.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum BagCompression {
    /// No compression (rosbag2's default; every MCAP reader handles it).
    #[default]
    None,
    /// Zstandard chunks (smaller; readers need a zstd decompressor).
    Zstd,
    /// LZ4 frame chunks.
    Lz4,
}

/// Options of [`BagWriter::create_with`].
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct BagWriteOptions {
    pub compression: BagCompression,
    /// Uncompressed bytes buffered per chunk before it is written; `None` keeps the mcap
    /// crate's default. Smaller chunks lose less data when a recording is cut off.
    pub chunk_size_bytes: Option<u64>,
}

#[derive(Clone, Debug)]
struct WriterChannel {
    id: u16,
    type_name: &'static str,
    sequence: u32,
}

/// Writes a ROS 2 MCAP bag. Call [`Self::finish`] to write the summary and see any error;
/// dropping the writer also finishes the file (the mcap crate does so), silently. A
/// recording cut off by a crash is still readable by [`BagReader`] up to its last complete
/// chunk.
pub struct BagWriter {
    file: String,
    writer: Writer<BufWriter<File>>,
    schemas: HashMap<&'static str, u16>,
    channels: HashMap<String, WriterChannel>,
}

impl BagWriter {
    /// Creates (or truncates) an uncompressed bag at `path`.
    pub fn create(path: impl AsRef<Path>) -> Result<Self, BagError> {
        Self::create_with(path, BagWriteOptions::default())
    }

    /// Creates (or truncates) a bag at `path` with `options`.
    pub fn create_with(path: impl AsRef<Path>, options: BagWriteOptions) -> Result<Self, BagError> {
        let file = path.as_ref().display().to_string();
        let handle = File::create(path.as_ref()).map_err(|source| BagError::Io {
            file: file.clone(),
            action: "cannot create bag",
            source,
        })?;
        let compression = match options.compression {
            BagCompression::None => None,
            BagCompression::Zstd => Some(Compression::Zstd),
            BagCompression::Lz4 => Some(Compression::Lz4),
        };
        let writer = WriteOptions::new()
            .profile(PROFILE)
            .library(concat!("mode360 ", env!("CARGO_PKG_VERSION")))
            .compression(compression)
            .chunk_size(
                options
                    .chunk_size_bytes
                    .or(Some(WriteOptions::DEFAULT_CHUNK_SIZE)),
            )
            .create(BufWriter::new(handle))
            .map_err(|source| BagError::Mcap {
                file: file.clone(),
                action: "writing the header",
                source,
            })?;
        Ok(Self {
            file,
            writer,
            schemas: HashMap::new(),
            channels: HashMap::new(),
        })
    }

    /// The bag's path as given to [`Self::create`].
    pub fn file(&self) -> &str {
        &self.file
    }

    fn mcap_err(&self, action: &'static str) -> impl FnOnce(mcap::McapError) -> BagError + '_ {
        move |source| BagError::Mcap {
            file: self.file.clone(),
            action,
            source,
        }
    }

    /// The channel of `topic` for type `T`, adding schema and channel on first use.
    fn channel_for<T: RosMessage>(&mut self, topic: &str) -> Result<&mut WriterChannel, BagError> {
        if !self.channels.contains_key(topic) {
            let schema_id = match self.schemas.get(T::TYPE_NAME) {
                Some(&id) => id,
                None => {
                    let text = T::schema_text().map_err(|source| BagError::Msg {
                        file: self.file.clone(),
                        topic: topic.to_string(),
                        source,
                    })?;
                    let id = self
                        .writer
                        .add_schema(T::TYPE_NAME, SCHEMA_ENCODING, text.as_bytes())
                        .map_err(|source| BagError::Mcap {
                            file: self.file.clone(),
                            action: "adding a schema",
                            source,
                        })?;
                    self.schemas.insert(T::TYPE_NAME, id);
                    id
                }
            };
            // tf2's static broadcaster latches /tf_static.
            let durability = if topic == TF_STATIC_TOPIC {
                DURABILITY_TRANSIENT_LOCAL
            } else {
                DURABILITY_VOLATILE
            };
            let metadata = BTreeMap::from([(QOS_METADATA_KEY.to_string(), qos_yaml(durability))]);
            let id = self
                .writer
                .add_channel(schema_id, topic, MESSAGE_ENCODING, &metadata)
                .map_err(|source| BagError::Mcap {
                    file: self.file.clone(),
                    action: "adding a channel",
                    source,
                })?;
            self.channels.insert(
                topic.to_string(),
                WriterChannel {
                    id,
                    type_name: T::TYPE_NAME,
                    sequence: 0,
                },
            );
        }
        let file = self.file.clone();
        match self.channels.get_mut(topic) {
            Some(channel) if channel.type_name == T::TYPE_NAME => Ok(channel),
            Some(channel) => Err(BagError::TypeMismatch {
                file,
                topic: topic.to_string(),
                expected: channel.type_name.to_string(),
                found: T::TYPE_NAME.to_string(),
            }),
            None => Err(BagError::MissingTopic {
                file,
                topic: topic.to_string(),
            }),
        }
    }

    /// Writes `msg` on `topic` at `log_time_ns` (also used as publish time). A topic keeps the
    /// type of its first message; writing another type there is an error.
    pub fn write<T: RosMessage>(
        &mut self,
        topic: &str,
        log_time_ns: u64,
        msg: &T,
    ) -> Result<(), BagError> {
        let data = encode_cdr(msg);
        let channel = self.channel_for::<T>(topic)?;
        let header = MessageHeader {
            channel_id: channel.id,
            sequence: channel.sequence,
            log_time: log_time_ns,
            publish_time: log_time_ns,
        };
        channel.sequence = channel.sequence.wrapping_add(1);
        self.writer
            .write_to_known_channel(&header, &data)
            .map_err(self.mcap_err("writing a message"))
    }

    /// Writes an MCAP metadata record `name` holding `entries`.
    pub fn write_metadata(
        &mut self,
        name: &str,
        entries: BTreeMap<String, String>,
    ) -> Result<(), BagError> {
        let record = Metadata {
            name: name.to_string(),
            metadata: entries,
        };
        self.writer
            .write_metadata(&record)
            .map_err(self.mcap_err("writing metadata"))
    }

    /// Flushes the last chunk and writes the summary and footer.
    pub fn finish(mut self) -> Result<(), BagError> {
        self.writer
            .finish()
            .map_err(self.mcap_err("finishing the bag"))?;
        let file = self.file.clone();
        self.writer
            .into_inner()
            .into_inner()
            .map_err(|err| BagError::Io {
                file,
                action: "cannot flush bag",
                source: err.into_error(),
            })?
            .sync_all()
            .map_err(|source| BagError::Io {
                file: self.file.clone(),
                action: "cannot sync bag",
                source,
            })
    }
}

/// A channel of a read bag.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct TopicInfo {
    pub topic: String,
    /// Schema name, e.g. `sensor_msgs/msg/Image` (empty for a channel without schema).
    pub type_name: String,
    pub message_encoding: String,
    pub message_count: usize,
}

#[derive(Clone, Debug)]
struct StoredMessage {
    /// Index into `BagReader::channels`.
    channel: usize,
    log_time_ns: u64,
    publish_time_ns: u64,
    data: Vec<u8>,
}

/// One message of a read bag, borrowed from the [`BagReader`].
#[derive(Clone, Copy, Debug)]
pub struct BagMessage<'a> {
    pub file: &'a str,
    pub topic: &'a str,
    /// Schema name, e.g. `sensor_msgs/msg/Image`.
    pub schema_name: &'a str,
    pub message_encoding: &'a str,
    pub log_time_ns: u64,
    pub publish_time_ns: u64,
    /// Encapsulated CDR.
    pub data: &'a [u8],
}

impl BagMessage<'_> {
    fn check_type<T: RosMessage>(&self) -> Result<(), BagError> {
        if self.schema_name != T::TYPE_NAME || self.message_encoding != MESSAGE_ENCODING {
            return Err(BagError::TypeMismatch {
                file: self.file.to_string(),
                topic: self.topic.to_string(),
                expected: format!("{} ({MESSAGE_ENCODING})", T::TYPE_NAME),
                found: format!("{} ({})", self.schema_name, self.message_encoding),
            });
        }
        Ok(())
    }

    fn msg_err(&self) -> impl FnOnce(MsgError) -> BagError + '_ {
        move |source| BagError::Msg {
            file: self.file.to_string(),
            topic: self.topic.to_string(),
            source,
        }
    }

    /// Decodes the message as `T`, checking that the channel's schema is `T`'s.
    pub fn decode<T: RosMessage>(&self) -> Result<T, BagError> {
        self.check_type::<T>()?;
        decode_cdr(self.data).map_err(self.msg_err())
    }

    /// Decodes only a leading part of the message (see `msgs::decode_cdr_prefix`), after
    /// checking the schema is `Full`'s.
    pub(crate) fn decode_prefix<Full: RosMessage, Prefix: RosMessage>(
        &self,
    ) -> Result<Prefix, BagError> {
        self.check_type::<Full>()?;
        crate::msgs::decode_cdr_prefix(self.data).map_err(self.msg_err())
    }
}

#[derive(Clone, Debug)]
struct ReaderChannel {
    topic: String,
    schema_name: String,
    message_encoding: String,
}

/// A channel record as read, before its schema is resolved.
#[derive(Clone, Debug)]
struct RawChannel {
    topic: String,
    schema_id: u16,
    message_encoding: String,
}

/// What [`BagReader`] collects while scanning records.
#[derive(Debug, Default)]
struct ScanState {
    profile: String,
    saw_header: bool,
    saw_data_end: bool,
    saw_footer: bool,
    schema_names: HashMap<u16, String>,
    channels: HashMap<u16, RawChannel>,
    /// Channel ids in order of first appearance.
    channel_order: Vec<u16>,
    /// (MCAP channel id, message) in file order.
    messages: Vec<(u16, StoredMessage)>,
    metadata: BTreeMap<String, BTreeMap<String, String>>,
}

impl ScanState {
    fn take(&mut self, record: Record<'_>) {
        match record {
            Record::Header(header) => {
                self.saw_header = true;
                self.profile = header.profile;
            }
            Record::Schema { header, .. } => {
                self.schema_names.entry(header.id).or_insert(header.name);
            }
            Record::Channel(channel) => {
                if let std::collections::hash_map::Entry::Vacant(slot) =
                    self.channels.entry(channel.id)
                {
                    self.channel_order.push(channel.id);
                    slot.insert(RawChannel {
                        topic: channel.topic,
                        schema_id: channel.schema_id,
                        message_encoding: channel.message_encoding,
                    });
                }
            }
            Record::Message { header, data } => self.messages.push((
                header.channel_id,
                StoredMessage {
                    channel: usize::MAX,
                    log_time_ns: header.log_time,
                    publish_time_ns: header.publish_time,
                    data: data.into_owned(),
                },
            )),
            Record::Metadata(record) => {
                self.metadata.insert(record.name, record.metadata);
            }
            Record::DataEnd(_) => self.saw_data_end = true,
            Record::Footer(_) => self.saw_footer = true,
            _ => {}
        }
    }
}

/// A whole MCAP bag read into memory, messages sorted by log time.
#[derive(Debug)]
pub struct BagReader {
    path: PathBuf,
    file: String,
    profile: String,
    channels: Vec<ReaderChannel>,
    messages: Vec<StoredMessage>,
    metadata: BTreeMap<String, BTreeMap<String, String>>,
    /// What was wrong with the file, if anything; everything before it was kept.
    damage: Option<String>,
}

impl BagReader {
    /// Reads the bag at `path`. Fails only if the file cannot be read or does not start as an
    /// MCAP file; later damage (truncation, corrupt records) keeps the messages before it
    /// and is reported by [`Self::check_complete`] and at the end of [`Self::messages`].
    pub fn open(path: impl AsRef<Path>) -> Result<Self, BagError> {
        let path = path.as_ref().to_path_buf();
        let file = path.display().to_string();
        let bytes = std::fs::read(&path).map_err(|source| BagError::Io {
            file: file.clone(),
            action: "cannot read bag",
            source,
        })?;
        let mut reader = Self {
            path,
            file,
            profile: String::new(),
            channels: Vec::new(),
            messages: Vec::new(),
            metadata: BTreeMap::new(),
            damage: None,
        };
        reader.scan(&bytes)?;
        reader.messages.sort_by_key(|m| m.log_time_ns);
        Ok(reader)
    }

    /// Notes damage (several pieces are joined).
    fn note_damage(&mut self, detail: String) {
        match &mut self.damage {
            Some(existing) => {
                existing.push_str("; ");
                existing.push_str(&detail);
            }
            None => self.damage = Some(detail),
        }
    }

    /// Reads every top-level record in file order. A chunk that fails to decompress or
    /// whose CRC does not match is dropped whole (so no corrupt message is kept) and reading
    /// goes on with the next record; broken record framing (truncation) ends the scan.
    fn scan(&mut self, bytes: &[u8]) -> Result<(), BagError> {
        let options = mcap::read::Options::IgnoreEndMagic.into();
        let records =
            mcap::read::LinearReader::new_with_options(bytes, options).map_err(|err| {
                BagError::NotMcap {
                    file: self.file.clone(),
                    detail: err.to_string(),
                }
            })?;
        let mut state = ScanState::default();
        for record in records {
            let record = match record {
                Ok(record) => record,
                Err(err) if !state.saw_header => {
                    return Err(BagError::NotMcap {
                        file: self.file.clone(),
                        detail: err.to_string(),
                    })
                }
                Err(err) => {
                    self.note_damage(err.to_string());
                    break;
                }
            };
            if let Record::Chunk { header, data } = record {
                let (start_ns, end_ns) = (header.message_start_time, header.message_end_time);
                let inner: Result<Vec<Record<'_>>, mcap::McapError> =
                    mcap::read::ChunkReader::new(header, &data).and_then(|chunk| chunk.collect());
                match inner {
                    Ok(inner) => inner.into_iter().for_each(|r| state.take(r)),
                    Err(err) => self.note_damage(format!(
                        "chunk with log times {start_ns}..={end_ns} ns dropped: {err}"
                    )),
                }
            } else {
                state.take(record);
            }
        }
        if !state.saw_header {
            return Err(BagError::NotMcap {
                file: self.file.clone(),
                detail: "no header record".into(),
            });
        }
        if !state.saw_data_end {
            self.note_damage("file ends before the data-end record (truncated)".into());
        } else if !state.saw_footer || !bytes.ends_with(mcap::MAGIC) {
            self.note_damage("file ends before the footer and end magic (truncated)".into());
        }
        self.finish_scan(state);
        Ok(())
    }

    /// Links messages to channels and channels to schemas once every record was seen
    /// (the summary repeats schemas and channels, so a lost chunk does not orphan later
    /// messages).
    fn finish_scan(&mut self, state: ScanState) {
        self.profile = state.profile;
        let mut index_of: HashMap<u16, usize> = HashMap::new();
        for id in &state.channel_order {
            let Some(channel) = state.channels.get(id) else {
                continue;
            };
            let schema_name = if channel.schema_id == 0 {
                String::new()
            } else if let Some(name) = state.schema_names.get(&channel.schema_id) {
                name.clone()
            } else {
                self.note_damage(format!(
                    "channel '{}' refers to unknown schema id {}",
                    channel.topic, channel.schema_id
                ));
                String::new()
            };
            index_of.insert(*id, self.channels.len());
            self.channels.push(ReaderChannel {
                topic: channel.topic.clone(),
                schema_name,
                message_encoding: channel.message_encoding.clone(),
            });
        }
        let mut orphans: BTreeMap<u16, usize> = BTreeMap::new();
        for (channel_id, mut message) in state.messages {
            match index_of.get(&channel_id) {
                Some(&index) => {
                    message.channel = index;
                    self.messages.push(message);
                }
                None => *orphans.entry(channel_id).or_default() += 1,
            }
        }
        for (channel_id, count) in orphans {
            self.note_damage(format!(
                "{count} messages on unknown channel id {channel_id} dropped"
            ));
        }
        self.metadata = state.metadata;
    }

    /// The bag's path.
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// The bag's path as text (as it appears in errors).
    pub fn file(&self) -> &str {
        &self.file
    }

    /// The MCAP profile from the header (`ros2` for ROS 2 bags).
    pub fn profile(&self) -> &str {
        &self.profile
    }

    /// The damage error, if the file was truncated or corrupt.
    pub fn damage(&self) -> Option<BagError> {
        self.damage.as_ref().map(|detail| BagError::Damaged {
            file: self.file.clone(),
            detail: detail.clone(),
            good_messages: self.messages.len(),
        })
    }

    /// `Ok` if the whole file was read without damage.
    pub fn check_complete(&self) -> Result<(), BagError> {
        self.damage().map_or(Ok(()), Err)
    }

    fn view<'a>(&'a self, m: &'a StoredMessage) -> BagMessage<'a> {
        let channel = &self.channels[m.channel];
        BagMessage {
            file: &self.file,
            topic: &channel.topic,
            schema_name: &channel.schema_name,
            message_encoding: &channel.message_encoding,
            log_time_ns: m.log_time_ns,
            publish_time_ns: m.publish_time_ns,
            data: &m.data,
        }
    }

    /// Every good message in log-time order (stable for equal times), then, if the file
    /// was damaged, one `Err` naming the file.
    pub fn messages(&self) -> impl Iterator<Item = Result<BagMessage<'_>, BagError>> + '_ {
        self.messages
            .iter()
            .map(|m| Ok(self.view(m)))
            .chain(self.damage().map(Err))
    }

    /// The good messages of `topic` in log-time order (damage is not reported here).
    pub fn messages_on<'a>(&'a self, topic: &'a str) -> impl Iterator<Item = BagMessage<'a>> + 'a {
        self.messages
            .iter()
            .map(|m| self.view(m))
            .filter(move |m| m.topic == topic)
    }

    /// Decodes every message of `topic` as `T`, in log-time order.
    pub fn decode_topic<T: RosMessage>(&self, topic: &str) -> Result<Vec<T>, BagError> {
        self.messages_on(topic).map(|m| m.decode::<T>()).collect()
    }

    /// The metadata record `name`, if the bag has one.
    pub fn metadata(&self, name: &str) -> Option<BTreeMap<String, String>> {
        self.metadata.get(name).cloned()
    }

    /// Names of all metadata records.
    pub fn metadata_names(&self) -> Vec<String> {
        self.metadata.keys().cloned().collect()
    }

    /// Every channel with its type and message count, in order of first appearance.
    pub fn topics(&self) -> Vec<TopicInfo> {
        let mut counts = vec![0usize; self.channels.len()];
        for m in &self.messages {
            counts[m.channel] += 1;
        }
        self.channels
            .iter()
            .zip(counts)
            .map(|(c, message_count)| TopicInfo {
                topic: c.topic.clone(),
                type_name: c.schema_name.clone(),
                message_encoding: c.message_encoding.clone(),
                message_count,
            })
            .collect()
    }
}
