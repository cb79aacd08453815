//! [`BagWriter`]: one schema per message type, one channel per topic, chunked and compressed.

use super::error::BagError;
use super::format::*;
use mode360_core::atomic_file::AtomicFile;
use std::collections::{BTreeMap, HashMap};
use std::fs::File;
use std::io::BufWriter;
use std::path::Path;

use mcap::records::{MessageHeader, Metadata};
use mcap::{Compression, WriteOptions, Writer};

use crate::msgs::{encode_cdr, RosMessage};

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

/// Writes a ROS 2 MCAP bag. The bag is written beside its path ([`AtomicFile`]) and
/// [`Self::finish`] renames it into place: a run that fails or is killed never touches an
/// existing file there. Dropping the writer without `finish` removes the unfinished bag; a
/// killed run leaves it as `.NAME.partial-PID`, readable by [`BagReader`] up to its last
/// complete chunk.
pub struct BagWriter {
    file: String,
    atomic: AtomicFile,
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
        let (atomic, handle) =
            AtomicFile::create(path.as_ref()).map_err(|source| BagError::Io {
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
            atomic,
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

    /// Flushes the last chunk, writes the summary and footer, and puts the bag in place.
    pub fn finish(mut self) -> Result<(), BagError> {
        self.writer
            .finish()
            .map_err(self.mcap_err("finishing the bag"))?;
        let file = self.file.clone();
        let handle = self
            .writer
            .into_inner()
            .into_inner()
            .map_err(|err| BagError::Io {
                file,
                action: "cannot flush bag",
                source: err.into_error(),
            })?;
        self.atomic.commit(handle).map_err(|source| BagError::Io {
            file: self.file.clone(),
            action: "cannot put the finished bag in place",
            source,
        })
    }
}
