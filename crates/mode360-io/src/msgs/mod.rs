//! ROS 2 messages: serde structs in `.msg` field order ([`types`]), their CDR encoding
//! ([`encode_cdr`], [`decode_cdr`]), MCAP schema text ([`schema_text`]) and image
//! conversions ([`image`]).
//!
//! Serialized form (as rmw and rosbag2 write it): a 4-byte encapsulation header
//! `00 01 00 00` (CDR, little endian, no options), then the fields in order, each primitive
//! aligned to its size counted from the first byte after the header; strings as a u32 length
//! including the NUL terminator, the bytes, and the NUL; sequences as a u32 element count then
//! the elements.

pub mod compressed_depth;
pub mod image;
pub mod labels;
pub mod schema;
pub mod type_hash;
pub mod types;

use byteorder::{BigEndian, LittleEndian};
use serde::de::DeserializeOwned;
use serde::Serialize;

pub use image::{
    float_from_image_msg, image_msg_from_float, image_msg_from_rgb, rgb_from_compressed,
    rgb_from_image_msg, ImageMsgError,
};
pub use labels::{label_image_msgs, labels_from_image_msgs, LabelMsgError};
pub use schema::{schema_text, SCHEMA_SEPARATOR};
pub use types::*;

/// Length of the CDR encapsulation header.
pub const ENCAPSULATION_HEADER_LEN: usize = 4;
/// Encapsulation header of little-endian plain CDR (`CDR_LE`), as written by [`encode_cdr`].
pub const CDR_LE_HEADER: [u8; ENCAPSULATION_HEADER_LEN] = [0x00, 0x01, 0x00, 0x00];
/// Encapsulation identifier of big-endian plain CDR (`CDR_BE`), accepted by [`decode_cdr`].
const CDR_BE_ID: [u8; 2] = [0x00, 0x00];
/// Encapsulation identifier of little-endian plain CDR (`CDR_LE`).
const CDR_LE_ID: [u8; 2] = [0x00, 0x01];
/// Writers may pad a message to a multiple of 4 bytes; more trailing bytes than this mean the
/// bytes are not of the requested type.
const MAX_TRAILING_PADDING: usize = 3;

/// A message that cannot be encoded, decoded or described.
#[derive(Debug, thiserror::Error)]
pub enum MsgError {
    #[error("unknown message type '{type_name}' (expected pkg/msg/Type of a shipped .msg)")]
    UnknownType { type_name: String },
    #[error("schema of '{type_name}': dependency '{dependency}' has no .msg definition")]
    MissingDependency {
        type_name: String,
        dependency: String,
    },
    #[error("definition of '{type_name}', {problem}")]
    BadDefinition { type_name: String, problem: String },
    #[error("{type_name}: {len} bytes is too short for the 4-byte CDR encapsulation header")]
    TooShort { type_name: &'static str, len: usize },
    #[error(
        "{type_name}: unsupported encapsulation {header:02x?} (expected plain CDR 00 01 or 00 00)"
    )]
    BadEncapsulation {
        type_name: &'static str,
        header: [u8; ENCAPSULATION_HEADER_LEN],
    },
    #[error("{type_name}: malformed CDR ({len} bytes): {source}")]
    Cdr {
        type_name: &'static str,
        len: usize,
        #[source]
        source: cdr_encoding::Error,
    },
    #[error("{type_name}: {extra} unexpected bytes after the message (decoded {used} of {len})")]
    TrailingBytes {
        type_name: &'static str,
        extra: usize,
        used: usize,
        len: usize,
    },
    #[error("{type_name}: cannot encode: {source}")]
    Encode {
        type_name: &'static str,
        #[source]
        source: cdr_encoding::Error,
    },
}

/// A ROS 2 message type with a `.msg` definition under `msg/`.
pub trait RosMessage: Serialize + DeserializeOwned {
    /// The ROS type name, `pkg/msg/Type` (e.g. `sensor_msgs/msg/Image`).
    const TYPE_NAME: &'static str;

    /// The complete `ros2msg` schema text (see [`schema_text`]).
    fn schema_text() -> Result<String, MsgError> {
        schema::schema_text(Self::TYPE_NAME)
    }
}

/// Encodes `msg` as encapsulated little-endian CDR, or says why it cannot.
pub fn try_encode_cdr<T: RosMessage>(msg: &T) -> Result<Vec<u8>, MsgError> {
    let body = cdr_encoding::to_vec::<T, LittleEndian>(msg).map_err(|source| MsgError::Encode {
        type_name: T::TYPE_NAME,
        source,
    })?;
    let mut out = Vec::with_capacity(ENCAPSULATION_HEADER_LEN + body.len());
    out.extend_from_slice(&CDR_LE_HEADER);
    out.extend_from_slice(&body);
    Ok(out)
}

/// Encodes `msg` as `00 01 00 00` followed by little-endian CDR.
///
/// Encoding the structs of this module into memory cannot fail (every sequence has a known
/// length and writing to a `Vec` is infallible); should a foreign `RosMessage` impl fail, the
/// error is logged and only the encapsulation header is returned (use [`try_encode_cdr`] to
/// see the error).
pub fn encode_cdr<T: RosMessage>(msg: &T) -> Vec<u8> {
    match try_encode_cdr(msg) {
        Ok(bytes) => bytes,
        Err(err) => {
            tracing::error!("{err}");
            CDR_LE_HEADER.to_vec()
        }
    }
}

/// Decodes the start of `bytes` (encapsulation header + CDR) as `T`; returns the message and
/// the number of CDR bytes used after the header.
fn decode_prefix<T: RosMessage>(bytes: &[u8]) -> Result<(T, usize), MsgError> {
    let Some((header, body)) = bytes.split_first_chunk::<ENCAPSULATION_HEADER_LEN>() else {
        return Err(MsgError::TooShort {
            type_name: T::TYPE_NAME,
            len: bytes.len(),
        });
    };
    let id = [header[0], header[1]];
    let result = if id == CDR_LE_ID {
        cdr_encoding::from_bytes::<T, LittleEndian>(body)
    } else if id == CDR_BE_ID {
        cdr_encoding::from_bytes::<T, BigEndian>(body)
    } else {
        return Err(MsgError::BadEncapsulation {
            type_name: T::TYPE_NAME,
            header: *header,
        });
    };
    result.map_err(|source| MsgError::Cdr {
        type_name: T::TYPE_NAME,
        len: bytes.len(),
        source,
    })
}

/// Decodes encapsulated CDR (`00 01` little or `00 00` big endian) as `T`. Short, garbled or
/// over-long input (more than 3 bytes of trailing padding) is an error, never a panic.
pub fn decode_cdr<T: RosMessage>(bytes: &[u8]) -> Result<T, MsgError> {
    let (msg, used) = decode_prefix::<T>(bytes)?;
    let extra = bytes.len() - ENCAPSULATION_HEADER_LEN - used;
    if extra > MAX_TRAILING_PADDING {
        return Err(MsgError::TrailingBytes {
            type_name: T::TYPE_NAME,
            extra,
            used,
            len: bytes.len(),
        });
    }
    Ok(msg)
}

/// Decodes only the leading fields of a message: `T` is a struct holding a prefix of the
/// real type's fields (e.g. just the header), so large payloads are not copied.
pub(crate) fn decode_cdr_prefix<T: RosMessage>(bytes: &[u8]) -> Result<T, MsgError> {
    decode_prefix::<T>(bytes).map(|(msg, _)| msg)
}
