//! [`BagReader`]: a whole MCAP file read into memory, tolerating truncation and bad chunks.

use super::error::BagError;
use super::format::*;
use std::collections::{BTreeMap, HashMap};
use std::path::{Path, PathBuf};

use mcap::records::Record;

use crate::msgs::{decode_cdr, MsgError, RosMessage};

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

    /// What was wrong with the file (truncation, a bad chunk), when anything was.
    pub fn damage_detail(&self) -> Option<&str> {
        self.damage.as_deref()
    }

    /// Messages read (those before any damage, and those of good chunks after it).
    pub fn message_count(&self) -> usize {
        self.messages.len()
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
