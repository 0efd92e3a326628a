//! The records of an MCAP file, each checked before the `mcap` crate parses it.
//!
//! `mcap` reserves a string's memory from its 32-bit length field before it reads the bytes,
//! so one flipped bit in a damaged recording asked for up to 4 GiB; a chunk's claimed
//! uncompressed size was taken as it came. Here every length inside a record must fit in what
//! is left of that record, and a chunk may not claim to open to more than its compression can
//! make of its bytes (and a zstd chunk to no more than 1 GiB), before any record is parsed. What does not fit is a [`Damaged`] error naming the
//! record and the field. Chunks are opened one at a time and all or nothing.

use mcap::records::{Record, op};
use mcap::sans_io::linear_reader::{LinearReadEvent, LinearReader, LinearReaderOptions};

/// A record whose lengths do not fit: the file is damaged there.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("damaged {record} record: {what}")]
pub struct Damaged {
    /// The record's kind.
    pub record: &'static str,
    /// Which length does not fit, and by how much.
    pub what: String,
}

/// Why a record cannot be read.
#[derive(Debug, thiserror::Error)]
pub enum RecordError {
    /// The `mcap` crate refused it.
    #[error(transparent)]
    Mcap(#[from] mcap::McapError),
    /// Its lengths do not fit.
    #[error(transparent)]
    Damaged(#[from] Damaged),
}

/// Whether chunks are opened (their records come out one by one) or passed over whole.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Chunks {
    /// Each chunk's records come out.
    Open,
    /// Chunks are passed over.
    Skip,
}

/// Where the records' bytes come from.
enum Source<'a> {
    /// A file's bytes in memory (or mapped).
    Bytes(&'a [u8]),
    /// A file read as the records come, so that memory holds one chunk at a time.
    File(std::io::BufReader<std::fs::File>),
}

/// The records of `buf` in file order, each checked, then parsed.
pub struct Records<'a> {
    src: Source<'a>,
    /// Bytes handed to the reader so far, from the start of the file.
    fed: u64,
    /// Where the top-level record the last item came from starts in the file (a message of a
    /// chunk: the chunk's).
    top: u64,
    reader: LinearReader,
    chunks: Chunks,
    /// The records of the chunk being handed out.
    opened: std::collections::VecDeque<Record<'static>>,
    /// After an error nothing more is read: a damaged file's reader could loop on it.
    failed: bool,
}

/// lz4 opens at most 255 bytes from one.
const MAX_RATIO: u64 = 255;
/// zstd at most 32,768 (a 4-byte block of one repeated byte opens to 128 KiB)...
const ZSTD_MAX_RATIO: u64 = 1 << 15;
/// ...and a zstd chunk is taken to claim no more than this: well above any chunk this build
/// writes (chunks close at 4 MiB, and the largest single message is a design's mesh), so that a
/// damaged size field cannot ask for more memory than that.
const ZSTD_MAX_CHUNK: u64 = 1 << 30;

impl<'a> Records<'a> {
    /// `ends_cleanly`: false for a file whose writer died (no end magic to expect).
    pub fn new(buf: &'a [u8], chunks: Chunks, ends_cleanly: bool) -> Self {
        let options = LinearReaderOptions::default()
            .with_record_length_limit(buf.len())
            .with_skip_end_magic(!ends_cleanly)
            // Chunks come out whole and are opened here, one at a time, all or nothing.
            .with_emit_chunks(true);
        Self {
            src: Source::Bytes(buf),
            fed: 0,
            top: 0,
            reader: LinearReader::new_with_options(options),
            chunks,
            opened: std::collections::VecDeque::new(),
            failed: false,
        }
    }
}

impl Records<'static> {
    /// The records of a file read as they come, from the top-level record at byte `at` (0: the
    /// file's start and its magic); the end magic is not required.
    pub fn from_file(mut file: std::fs::File, chunks: Chunks, at: u64) -> std::io::Result<Self> {
        use std::io::{Seek, SeekFrom};
        let len = file.metadata()?.len();
        file.seek(SeekFrom::Start(at))?;
        let options = LinearReaderOptions::default()
            .with_record_length_limit(len as usize)
            .with_skip_start_magic(at > 0)
            .with_skip_end_magic(true)
            .with_emit_chunks(true);
        Ok(Self {
            src: Source::File(std::io::BufReader::with_capacity(1 << 20, file)),
            fed: at,
            top: at,
            reader: LinearReader::new_with_options(options),
            chunks,
            opened: std::collections::VecDeque::new(),
            failed: false,
        })
    }
}

impl Records<'_> {
    /// Where the top-level record of the last item starts in the file: a record read again
    /// with [`Records::from_file`] at this offset comes first (a message of a chunk: its chunk).
    pub fn record_offset(&self) -> u64 {
        self.top
    }
}

impl Iterator for Records<'_> {
    type Item = Result<Record<'static>, RecordError>;

    fn next(&mut self) -> Option<Self::Item> {
        if self.failed {
            return None;
        }
        let item = self.read();
        self.failed = matches!(item, Some(Err(_)));
        item
    }
}

impl Records<'_> {
    fn read(&mut self) -> Option<Result<Record<'static>, RecordError>> {
        loop {
            if let Some(r) = self.opened.pop_front() {
                return Some(Ok(r));
            }
            let (opcode, data) = match self.reader.next_event()? {
                Ok(LinearReadEvent::ReadRequest(need)) => {
                    // Never more than asked: the reader then holds nothing past the record it
                    // reads, and `fed` is where that record ends.
                    let len = match &mut self.src {
                        Source::Bytes(buf) => {
                            let len = need.min(buf.len());
                            self.reader.insert(len).copy_from_slice(&buf[..len]);
                            *buf = &buf[len..];
                            len
                        }
                        Source::File(f) => match std::io::Read::read(f, self.reader.insert(need)) {
                            Ok(n) => n,
                            Err(e) => return Some(Err(mcap::McapError::Io(e).into())),
                        },
                    };
                    self.reader.notify_read(len);
                    self.fed += len as u64;
                    continue;
                }
                Ok(LinearReadEvent::Record { data, opcode }) => {
                    // An opcode, a length, the body.
                    self.top = self.fed - 9 - data.len() as u64;
                    (opcode, data)
                }
                Err(e) => return Some(Err(e.into())),
            };
            // Every record is checked once: an opened chunk by `open_chunk`, which also cuts
            // it at the end of its records.
            let checked = match (opcode, self.chunks) {
                (op::CHUNK, Chunks::Open) => open_chunk(data).map(|r| self.opened = r.into()),
                _ => check(opcode, data).map(|_| ()).map_err(RecordError::from),
            };
            if let Err(e) = checked {
                return Some(Err(e));
            }
            if opcode != op::CHUNK {
                return Some(
                    mcap::parse_record(opcode, data)
                        .map(Record::into_owned)
                        .map_err(RecordError::from),
                );
            }
        }
    }
}

/// Every record of a chunk (its body `body`, checked here), or the first error.
fn open_chunk(body: &[u8]) -> Result<Vec<Record<'static>>, RecordError> {
    // Only up to the end of its records: mcap bounds a record inside an uncompressed chunk by
    // the bytes it is given, not by the records' length, so a damaged record that ran past
    // them into bytes after them underflowed its count of what is left.
    let body = &body[..check(op::CHUNK, body)?];
    let uncompressed = u64::from_le_bytes(body[16..24].try_into().expect("checked"));
    let name_len = u32::from_le_bytes(body[28..32].try_into().expect("checked")) as usize;
    let limit = match &body[32..32 + name_len] {
        b"zstd" => (body.len() as u64)
            .saturating_mul(ZSTD_MAX_RATIO)
            .min(ZSTD_MAX_CHUNK),
        _ => (body.len() as u64).saturating_mul(MAX_RATIO),
    }
    .saturating_add(1 << 16);
    if uncompressed > limit {
        return Err(Damaged {
            record: "chunk",
            what: format!(
                "claims {uncompressed} bytes uncompressed from {} compressed",
                body.len()
            ),
        }
        .into());
    }
    // The chunk as a stream of one record, opened by a reader of its own: its opcode and
    // length, then its body, fed straight from the file's bytes.
    let mut head = [0u8; 9];
    head[0] = op::CHUNK;
    head[1..].copy_from_slice(&(body.len() as u64).to_le_bytes());
    let mut reader = LinearReader::new_with_options(
        LinearReaderOptions::default()
            .with_skip_start_magic(true)
            .with_skip_end_magic(true)
            .with_emit_chunks(false)
            .with_record_length_limit(limit as usize),
    );
    let mut parts = [&head[..], body];
    let mut out = Vec::new();
    while let Some(event) = reader.next_event() {
        match event? {
            LinearReadEvent::ReadRequest(need) => {
                let rest = parts.iter_mut().find(|p| !p.is_empty());
                let len = rest.as_ref().map_or(0, |r| need.min(r.len()));
                if let Some(rest) = rest {
                    reader.insert(len).copy_from_slice(&rest[..len]);
                    *rest = &rest[len..];
                }
                reader.notify_read(len);
            }
            LinearReadEvent::Record { data, opcode } => {
                check(opcode, data)?;
                out.push(mcap::parse_record(opcode, data)?.into_owned());
            }
        }
    }
    Ok(out)
}

/// A cursor over a record's body that refuses any length beyond what is left.
struct Fields<'a> {
    record: &'static str,
    rest: &'a [u8],
}

impl<'a> Fields<'a> {
    fn fail(&self, what: String) -> Damaged {
        Damaged {
            record: self.record,
            what,
        }
    }

    /// The next `n` bytes, which must all be there.
    fn claim(&mut self, n: u64, field: &str) -> Result<&'a [u8], Damaged> {
        if n > self.rest.len() as u64 {
            return Err(self.fail(format!(
                "{field} claims {n} bytes where {} are left",
                self.rest.len()
            )));
        }
        let (claimed, rest) = self.rest.split_at(n as usize);
        self.rest = rest;
        Ok(claimed)
    }

    fn skip(&mut self, n: u64, field: &str) -> Result<(), Damaged> {
        self.claim(n, field).map(|_| ())
    }

    fn le_bytes<const N: usize>(&mut self, field: &str) -> Result<[u8; N], Damaged> {
        let (b, rest) = self
            .rest
            .split_first_chunk::<N>()
            .ok_or_else(|| self.fail(format!("{field} cut off")))?;
        self.rest = rest;
        Ok(*b)
    }

    fn u32(&mut self, field: &str) -> Result<u64, Damaged> {
        self.le_bytes(field).map(|b| u32::from_le_bytes(b).into())
    }

    fn u64(&mut self, field: &str) -> Result<u64, Damaged> {
        self.le_bytes(field).map(u64::from_le_bytes)
    }

    /// A string or byte array behind a 32-bit length.
    fn bytes32(&mut self, field: &str) -> Result<(), Damaged> {
        let n = self.u32(field)?;
        self.skip(n, field)
    }

    /// A map of strings behind its 32-bit length in bytes. Every entry must end inside it
    /// (mcap reads whole entries while it has not reached the length).
    fn string_map(&mut self, field: &str) -> Result<(), Damaged> {
        let n = self.u32(field)?;
        let mut m = Fields {
            record: self.record,
            rest: self.claim(n, field)?,
        };
        while !m.rest.is_empty() {
            m.bytes32(field)?;
            m.bytes32(field)?;
        }
        Ok(())
    }

    /// Entries of `entry` bytes behind a 32-bit length in bytes: mcap reads whole entries while
    /// it has not reached the length, so a length that is not a multiple reads one entry more.
    fn entries(&mut self, field: &str, entry: u64) -> Result<(), Damaged> {
        let n = self.u32(field)?;
        self.skip(n.div_ceil(entry) * entry, field)
    }
}

/// Checks that every length inside a record fits in what is left of it; returns how many bytes
/// of `body` its fields span (bytes after them are fields of a later version).
fn check(opcode: u8, body: &[u8]) -> Result<usize, Damaged> {
    let name = match opcode {
        op::HEADER => "header",
        op::SCHEMA => "schema",
        op::CHANNEL => "channel",
        op::CHUNK => "chunk",
        op::MESSAGE_INDEX => "message index",
        op::CHUNK_INDEX => "chunk index",
        op::ATTACHMENT => "attachment",
        op::ATTACHMENT_INDEX => "attachment index",
        op::STATISTICS => "statistics",
        op::METADATA => "metadata",
        op::METADATA_INDEX => "metadata index",
        // Fixed-size records, messages and records of later versions: nothing to check.
        _ => return Ok(body.len()),
    };
    let mut f = Fields {
        record: name,
        rest: body,
    };
    match opcode {
        op::HEADER => {
            f.bytes32("profile")?;
            f.bytes32("library")?;
        }
        op::SCHEMA => {
            f.skip(2, "id")?;
            f.bytes32("name")?;
            f.bytes32("encoding")?;
            f.bytes32("data")?;
        }
        op::CHANNEL => {
            f.skip(4, "ids")?;
            f.bytes32("topic")?;
            f.bytes32("message encoding")?;
            f.string_map("metadata")?;
        }
        op::CHUNK => {
            f.skip(16, "times")?;
            f.u64("uncompressed size")?;
            f.skip(4, "checksum")?;
            f.bytes32("compression")?;
            let n = f.u64("records length")?;
            f.skip(n, "records")?;
        }
        op::MESSAGE_INDEX => {
            f.skip(2, "channel id")?;
            f.entries("entries", 16)?;
        }
        op::CHUNK_INDEX => {
            f.skip(32, "times and offsets")?;
            f.entries("message index offsets", 10)?;
            f.skip(8, "message index length")?;
            f.bytes32("compression")?;
        }
        op::ATTACHMENT => {
            f.skip(16, "times")?;
            f.bytes32("name")?;
            f.bytes32("media type")?;
            let n = f.u64("data length")?;
            f.skip(n, "data")?;
        }
        op::ATTACHMENT_INDEX => {
            f.skip(40, "offsets, times and size")?;
            f.bytes32("name")?;
            f.bytes32("media type")?;
        }
        op::STATISTICS => {
            f.skip(8 + 2 + 4 * 4 + 16, "counts and times")?;
            f.entries("channel message counts", 10)?;
        }
        op::METADATA => {
            f.bytes32("name")?;
            f.string_map("metadata")?;
        }
        op::METADATA_INDEX => {
            f.skip(16, "offset and length")?;
            f.bytes32("name")?;
        }
        _ => {}
    }
    Ok(body.len() - f.rest.len())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_string_longer_than_its_record_is_damage_not_an_allocation() {
        // A metadata record whose name claims 4 GiB.
        let mut body = u32::MAX.to_le_bytes().to_vec();
        body.extend_from_slice(b"job");
        let e = check(op::METADATA, &body).unwrap_err();
        assert_eq!(e.record, "metadata");
        assert!(e.what.contains("name claims 4294967295 bytes"), "{e}");
        // One string of a map that claims more than the map.
        let mut body = 3u32.to_le_bytes().to_vec();
        body.extend_from_slice(b"job");
        body.extend_from_slice(&12u32.to_le_bytes());
        body.extend_from_slice(&1000u32.to_le_bytes());
        body.extend_from_slice(b"abcdefgh");
        assert!(check(op::METADATA, &body).is_err());
        // The same record, well formed.
        let mut body = 3u32.to_le_bytes().to_vec();
        body.extend_from_slice(b"job");
        body.extend_from_slice(&10u32.to_le_bytes());
        body.extend_from_slice(&1u32.to_le_bytes());
        body.push(b'k');
        body.extend_from_slice(&1u32.to_le_bytes());
        body.push(b'v');
        check(op::METADATA, &body).unwrap();
        assert!(mcap::parse_record(op::METADATA, &body).is_ok());
    }

    /// An uncompressed chunk of one message record, with `after` bytes behind its records;
    /// `claimed` is the records' length as the chunk states it.
    fn chunk(claimed: u64, after: &[u8]) -> Vec<u8> {
        let mut message = 1u16.to_le_bytes().to_vec();
        message.extend_from_slice(&[0; 4 + 8 + 8]);
        message.extend_from_slice(b"hi");
        let mut records = vec![op::MESSAGE];
        records.extend_from_slice(&(message.len() as u64).to_le_bytes());
        records.extend_from_slice(&message);
        let mut body = [0u8; 16].to_vec();
        body.extend_from_slice(&(records.len() as u64).to_le_bytes());
        body.extend_from_slice(&[0; 4 + 4]); // no checksum, no compression
        body.extend_from_slice(&claimed.to_le_bytes());
        body.extend_from_slice(&records);
        body.extend_from_slice(after);
        body
    }

    #[test]
    fn a_record_that_runs_past_its_chunks_records_is_an_error() {
        let whole = 9 + 24;
        assert_eq!(open_chunk(&chunk(whole, b"")).unwrap().len(), 1);
        // Bytes after the records are skipped, as a later version's fields.
        assert_eq!(open_chunk(&chunk(whole, b"later")).unwrap().len(), 1);
        // The records' length cuts the message short, and bytes follow the records.
        assert!(open_chunk(&chunk(whole - 5, b"")).is_err());
        assert!(open_chunk(&chunk(whole - 5, &[7; 64])).is_err());
    }
}
