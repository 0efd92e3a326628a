//! What every message is: a versioned name ([`Message`]), how a record of it fails to read
//! ([`DecodeError`]) and what a recording holds of it ([`Record`]). This module uses nothing else
//! of the crate, so that each message's own file can use it.

use serde::Serialize;
use serde::de::DeserializeOwned;

/// A message type with a versioned name, e.g. `asbuilt.PoseSnapshot.v2`.
pub trait Message: Serialize + DeserializeOwned {
    /// The iceoryx2 type name and the MCAP schema name.
    const TYPE_NAME: &'static str;
    /// The version this build writes.
    const VERSION: u16;
    /// The oldest version this build still reads (its layout and encoding are this one's).
    const OLDEST: u16 = Self::VERSION;
    /// The version this instance claims (the payload's own field).
    fn version(&self) -> u16;
}

/// Implements [`Message`] for a payload with a `version: u16` field. The name must match the
/// type's `#[type_name]`, which iceoryx2 compares; a test checks that they agree.
macro_rules! message {
    ($ty:ty, $name:literal, $version:literal) => {
        impl $crate::message::Message for $ty {
            const TYPE_NAME: &'static str = $name;
            const VERSION: u16 = $version;
            fn version(&self) -> u16 {
                self.version
            }
        }
    };
    ($ty:ty, $name:literal, $version:literal, oldest $oldest:literal) => {
        impl $crate::message::Message for $ty {
            const TYPE_NAME: &'static str = $name;
            const VERSION: u16 = $version;
            const OLDEST: u16 = $oldest;
            fn version(&self) -> u16 {
                self.version
            }
        }
    };
}
pub(crate) use message;

/// A record that cannot be read back as the message it claims to be.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum DecodeError {
    #[error(
        "{message} version {found} cannot be read by this build, which reads versions {oldest} \
         to {expected}: use the asbuilt release that wrote it, or re-record"
    )]
    /// Written by a release with another version of the message.
    VersionMismatch {
        /// The message's type name.
        message: &'static str,
        /// The version the record claims.
        found: u16,
        /// The newest version this build reads.
        expected: u16,
        /// The oldest version this build reads.
        oldest: u16,
    },
    /// Postcard could not decode the record (cut short, or not this message).
    #[error("corrupt {message} record: {reason}")]
    Corrupt {
        /// The message's type name.
        message: &'static str,
        /// What postcard said.
        reason: String,
    },
    /// More bytes than the message holds: the record is another message.
    #[error("{message} record has {extra} unread bytes after the message: it is not a {message}")]
    TrailingBytes {
        /// The message's type name.
        message: &'static str,
        /// Bytes left after the message.
        extra: usize,
    },
}

/// Checks the version field that every payload carries, for payloads that arrive through shared
/// memory (where the codec's check does not run).
pub fn check_version<M: Message>(found: u16) -> Result<(), DecodeError> {
    if (M::OLDEST..=M::VERSION).contains(&found) {
        Ok(())
    } else {
        Err(DecodeError::VersionMismatch {
            message: M::TYPE_NAME,
            found,
            expected: M::VERSION,
            oldest: M::OLDEST,
        })
    }
}

/// A message as a recording holds it: the schema its channel declares, its record's bytes and
/// its own time. Implemented in `records.rs` for every payload of the message table
/// (`table.rs`).
pub trait Record: Sized {
    /// The MCAP schema name, e.g. `asbuilt.PoseSnapshot.v2`.
    const SCHEMA_NAME: &'static str;
    /// The MCAP schema data: the record's fields, in encoding order, with units, for a reader
    /// without asbuilt.
    const SCHEMA_TEXT: &'static str;
    /// Whether Foxglove's channels repeat it as JSON (the agent's per-station results).
    const FOXGLOVE_JSON: bool = false;
    /// The record's bytes.
    fn encode(&self) -> Vec<u8>;
    /// A record back into its message.
    fn decode(bytes: &[u8]) -> Result<Self, DecodeError>;
    /// The message's own timestamp, nanoseconds since the Unix epoch (0 when it has none).
    fn timestamp_ns(&self) -> u64 {
        0
    }
}

/// A chunk as a recording holds it: its header, then its points. Implemented in `records.rs`
/// for the chunk streams of the message table.
pub trait ChunkRecord: Sized {
    /// What the chunk carries after its header.
    type Point;
    /// The MCAP schema name, e.g. `asbuilt.ScanChunk.v3`.
    const SCHEMA_NAME: &'static str;
    /// The MCAP schema data, as [`Record::SCHEMA_TEXT`].
    const SCHEMA_TEXT: &'static str;
    /// The record's bytes: this header, then `points`.
    fn encode(&self, points: &[Self::Point]) -> Vec<u8>;
    /// A record back into its header and points.
    fn decode(bytes: &[u8]) -> Result<(Self, Vec<Self::Point>), DecodeError>;
    /// The chunk's own timestamp, nanoseconds since the Unix epoch.
    fn timestamp_ns(&self) -> u64;
}
