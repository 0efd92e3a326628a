//! The MCAP recording of a job: which channels it has, what each message's bytes are, and
//! what the metadata records hold. The agent's recorder, `asbuilt pack`, `replay`, `recover`
//! and `report` all write or read through this module, so a recording means the same to each.
//!
//! - One channel per message stream, topic as the iceoryx2 service without its prefix
//!   (`/scanner/chunks`), message encoding [`MESSAGE_ENCODING`] (the `codec`
//!   records: a postcard varint version, then the message).
//! - Each channel's schema is named for the message type and version
//!   (`asbuilt.ScanChunk.v3`); its data is a text that lists the fields ([`schema_text`]),
//!   encoding [`SCHEMA_ENCODING`].
//! - Metadata record [`METADATA_JOB`]: agent version, configuration, design file and its
//!   SHA-256, calibrations. The design file itself is attached as [`ATTACHMENT_DESIGN`].
//! - `log_time` is when the message was received (or, for a packed file, when a scanner at the
//!   packed rate would have sent it); `publish_time` is the message's own timestamp.

use std::collections::BTreeMap;
use std::io::{Seek, Write};

use serde::{Deserialize, Serialize};

use crate::codec::{self, DecodeError};
use crate::foxglove::{Colour, FoxgloveChannels};
use crate::mcap_records::{Chunks, Damaged, RecordError, Records};
use crate::{ChunkHeader, DeviationHeader, PointDeviation, ScanPoint, StationEvent};

/// The MCAP message encoding of the asbuilt channels: [`crate::codec`]'s postcard records.
pub const MESSAGE_ENCODING: &str = "asbuilt-postcard";
/// The MCAP schema encoding: the message's fields as text, for a reader without asbuilt.
pub const SCHEMA_ENCODING: &str = "asbuilt-fields-text";
/// The MCAP profile of an asbuilt recording.
pub const PROFILE: &str = "asbuilt";
/// The metadata record holding [`JobMetadata`].
pub const METADATA_JOB: &str = "asbuilt.job";
/// The attachment name prefix of the design file (`design/<file name>`).
pub const ATTACHMENT_DESIGN: &str = "design";

/// The attachment that holds a scan layer's findings state after a station
/// ([`ScanLayerStateRecord`]): an agent that resumes the job goes on from it instead of
/// replaying the scan layer's points.
pub const ATTACHMENT_SCAN_LAYER_STATE: &str = "asbuilt.scan_layer_state";

/// A scan layer's findings state as the agent had it after a station closed: which station
/// attempt, the scan layer (its printed height), and the state itself, postcard-encoded by the
/// agent (`asbuilt_core::scan_layer::ScanLayerState`: per design sample, so its size is the
/// design's, not the scan's).
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct ScanLayerStateRecord {
    /// The record's version.
    pub version: u16,
    /// The job.
    pub job: u64,
    /// The station whose close the state follows.
    pub station: u32,
    /// Its attempt.
    pub attempt: u8,
    /// The scan layer's printed height, metres (NaN: the whole design).
    pub printed_height: f64,
    /// The state.
    pub state: Vec<u8>,
}

impl ScanLayerStateRecord {
    /// The version this build writes and reads. 3: coverage keeps what line profilers' passes
    /// swept. 2: M3C2's cylinders in core point order (1 held them in the order of a grid
    /// that has changed since). A state of another version is skipped, and an agent resuming
    /// replays the scan layer's inputs instead.
    pub const VERSION: u16 = 3;
}

pub use crate::table::{Channel, Recorded};

/// The schema data of a channel: its fields, in encoding order, with units.
pub fn schema_text(channel: Channel) -> &'static str {
    channel.schema_text()
}

/// What the `asbuilt.job` metadata record holds.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct JobMetadata {
    /// What wrote the recording: `asbuilt agent`, `asbuilt pack`...
    pub writer: String,
    /// The asbuilt release that wrote it.
    pub asbuilt_version: String,
    /// The design file as the writer named it.
    pub design_path: String,
    /// The design file's declared units, `m` or `mm`.
    pub design_units: String,
    /// SHA-256 of the design file's bytes, hexadecimal.
    pub design_sha256: String,
    /// The agent's configuration file as it was, or how a packed file was made.
    pub config: String,
    /// `t_design_base`, `t_flange_scanner` and `r_base_flange_xyzw`, as written in the config.
    pub calibrations: String,
}

impl JobMetadata {
    /// The record's key-value map.
    pub fn to_map(&self) -> BTreeMap<String, String> {
        [
            ("writer", &self.writer),
            ("asbuilt_version", &self.asbuilt_version),
            ("design_path", &self.design_path),
            ("design_units", &self.design_units),
            ("design_sha256", &self.design_sha256),
            ("config", &self.config),
            ("calibrations", &self.calibrations),
        ]
        .into_iter()
        .map(|(k, v)| (k.to_string(), v.clone()))
        .collect()
    }

    /// Back from the record's map; a key left out reads as empty.
    pub fn from_map(m: &BTreeMap<String, String>) -> Self {
        let g = |k: &str| m.get(k).cloned().unwrap_or_default();
        Self {
            writer: g("writer"),
            asbuilt_version: g("asbuilt_version"),
            design_path: g("design_path"),
            design_units: g("design_units"),
            design_sha256: g("design_sha256"),
            config: g("config"),
            calibrations: g("calibrations"),
        }
    }
}

/// An MCAP file in the recording layout: every channel declared up front.
pub struct RecordingWriter<W: Write + Seek> {
    mcap: mcap::Writer<W>,
    channels: BTreeMap<Channel, u16>,
    sequence: u32,
    /// Foxglove's channels, when asked for ([`RecordingWriter::with_foxglove`]).
    foxglove: Option<FoxgloveChannels>,
}

/// Messages are collected into chunks of about this many bytes; a station's end always closes
/// one, so a crash loses at most the station in progress.
pub const CHUNK_BYTES: u64 = 4 << 20;

/// zstd's level for [`ChunkCompression::Zstd`]: one of its fast, negative levels. Against
/// level 1, on the agent benchmark's scan chunks, the writer thread spent 13.9 ns a point
/// instead of 18.6 (medians of nine pairs, `tools/bench/recorder_cost.sh`) and the file grew
/// 2.7 %; levels below -5 saved no more time (one run each, `--recorder 6`).
pub const ZSTD_LEVEL: i32 = -5;

/// How a recording's chunks are compressed. Every reader of this build opens all three.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum ChunkCompression {
    /// Chunks as they are: no CPU spent, the most disk.
    None,
    /// LZ4: scan points in 8.9 bytes of their 20 on the demo's chunks. The mcap crate's LZ4
    /// frames carry a content checksum, which took a third of the writer's CPU in the agent
    /// benchmark: no cheaper than zstd at level 1 there, and larger.
    Lz4,
    /// zstd at [`ZSTD_LEVEL`] on the writer's own thread: the default demo's whole recording
    /// in 11.7 bytes a point (11.3 at level 1). Level 3 made scan points 1.5 % smaller than
    /// level 1 for 45 % more time (one run).
    #[default]
    Zstd,
}

impl ChunkCompression {
    fn mcap(self) -> Option<mcap::Compression> {
        match self {
            ChunkCompression::None => None,
            ChunkCompression::Lz4 => Some(mcap::Compression::Lz4),
            ChunkCompression::Zstd => Some(mcap::Compression::Zstd),
        }
    }
}

impl<W: Write + Seek> RecordingWriter<W> {
    /// A recording compressed as [`ChunkCompression::default`] does.
    pub fn new(w: W) -> Result<Self, mcap::McapError> {
        Self::with_compression(w, ChunkCompression::default())
    }

    /// A recording whose chunks are compressed with `compression`.
    pub fn with_compression(w: W, compression: ChunkCompression) -> Result<Self, mcap::McapError> {
        let mut mcap = mcap::WriteOptions::new()
            .profile(PROFILE)
            .library(format!("asbuilt {}", env!("CARGO_PKG_VERSION")))
            .compression(compression.mcap())
            // zstd at a fast level (LZ4 at its fast one): the byte planes leave little for a
            // slower level to find. On the writer's thread only, never the inspection's cores.
            .compression_level(if compression == ChunkCompression::Zstd {
                // The crate takes the level as a u32 and hands it to zstd `as i32`, so this
                // round trip is how a negative (fast) level reaches it.
                ZSTD_LEVEL as u32
            } else {
                0
            })
            .compression_threads(0)
            .chunk_size(Some(CHUNK_BYTES))
            .create(w)?;
        let mut channels = BTreeMap::new();
        for c in Channel::ALL {
            let schema =
                mcap.add_schema(c.schema_name(), SCHEMA_ENCODING, schema_text(c).as_bytes())?;
            let id = mcap.add_channel(schema, c.topic(), MESSAGE_ENCODING, &BTreeMap::new())?;
            channels.insert(c, id);
        }
        Ok(Self {
            mcap,
            channels,
            sequence: 0,
            foxglove: None,
        })
    }

    /// Also writes Foxglove's channels ([`crate::foxglove`]): each pose, deviation chunk,
    /// report and findings again in a schema Foxglove shows, deviations coloured by `colour`.
    pub fn with_foxglove(mut self, colour: Colour) -> Result<Self, mcap::McapError> {
        self.foxglove = Some(FoxgloveChannels::add(&mut self.mcap, colour)?);
        Ok(self)
    }

    /// With Foxglove's channels, one point in `every` of each deviation chunk goes into its
    /// cloud if it matched ([`crate::foxglove::cloud_points`]; the asbuilt channels keep every
    /// point: replay and report use those).
    pub fn foxglove_every(mut self, every: usize) -> Self {
        if let Some(f) = &mut self.foxglove {
            f.decimate(every);
        }
        self
    }

    /// With Foxglove's channels, scan chunks too, each in its station's frame.
    pub fn with_foxglove_scans(mut self) -> Result<Self, mcap::McapError> {
        if let Some(f) = &mut self.foxglove {
            f.add_scans(&mut self.mcap)?;
        }
        Ok(self)
    }

    /// A line profiler's clock offset (the robot's clock less the sensor's, ns), for the times
    /// of its profiles on Foxglove's channel; nothing without Foxglove's channels.
    pub fn foxglove_clock_offset(mut self, ns: i64) -> Self {
        if let Some(f) = &mut self.foxglove {
            f.set_clock_offset(ns);
        }
        self
    }

    /// The robot's base in the design frame (`T_design_base`) for Foxglove, which places a line
    /// profiler's mount poses by it; nothing without Foxglove's channels.
    pub fn foxglove_base(
        &mut self,
        time: u64,
        translation: [f64; 3],
        rotation_xyzw: [f64; 4],
    ) -> Result<(), mcap::McapError> {
        let Some(f) = &self.foxglove else {
            return Ok(());
        };
        let channel = f.base_channel();
        let bytes = crate::foxglove::base_transform(time, translation, rotation_xyzw);
        self.write_to(channel, time, time, &bytes)
    }

    /// The design for Foxglove (metres, design frame); nothing without Foxglove's channels.
    pub fn foxglove_design(
        &mut self,
        time: u64,
        vertices: impl IntoIterator<Item = [f64; 3]>,
        triangles: &[[u32; 3]],
    ) -> Result<(), mcap::McapError> {
        let Some(f) = &self.foxglove else {
            return Ok(());
        };
        let channel = f.design_channel();
        let bytes = crate::foxglove::design_scene(time, vertices, triangles);
        self.write_to(channel, time, time, &bytes)
    }

    fn write_to(
        &mut self,
        channel_id: u16,
        log_time: u64,
        publish_time: u64,
        bytes: &[u8],
    ) -> Result<(), mcap::McapError> {
        self.sequence = self.sequence.wrapping_add(1);
        self.mcap.write_to_known_channel(
            &mcap::records::MessageHeader {
                channel_id,
                sequence: self.sequence,
                log_time,
                publish_time,
            },
            bytes,
        )
    }

    /// Writes already-encoded message bytes.
    pub fn write_raw(
        &mut self,
        channel: Channel,
        log_time: u64,
        publish_time: u64,
        bytes: &[u8],
    ) -> Result<(), mcap::McapError> {
        self.write_to(self.channels[&channel], log_time, publish_time, bytes)
    }

    /// Writes a message, and its Foxglove twin when Foxglove's channels are on.
    pub fn write(&mut self, log_time: u64, message: &Recorded) -> Result<(), mcap::McapError> {
        if let Recorded::Chunk(h, points) = message {
            return self.write_scan_chunk(log_time, h, points);
        }
        self.write_raw(
            message.channel(),
            log_time,
            message.timestamp_ns(),
            &message.encode(),
        )?;
        self.write_foxglove(log_time, message)
    }

    /// Writes a scan chunk, and its Foxglove twin when scan chunks are shown, from its points
    /// where they lie: the agent's chunks are still in shared memory, with no message around
    /// them. [`RecordingWriter::write`] writes a [`Recorded::Chunk`] through here too.
    pub fn write_scan_chunk(
        &mut self,
        log_time: u64,
        header: &ChunkHeader,
        points: &[ScanPoint],
    ) -> Result<(), mcap::McapError> {
        let record = codec::encode_scan_chunk(header, points);
        self.write_raw(Channel::ScanChunks, log_time, header.timestamp_ns, &record)?;
        match self.foxglove.as_ref().and_then(|f| f.scan(header, points)) {
            Some((channel, bytes)) => self.write_to(channel, log_time, header.timestamp_ns, &bytes),
            None => Ok(()),
        }
    }

    /// Writes only the Foxglove twin of a message (a deviation chunk the asbuilt channel leaves
    /// out, say); nothing without Foxglove's channels.
    pub fn write_foxglove(
        &mut self,
        log_time: u64,
        message: &Recorded,
    ) -> Result<(), mcap::McapError> {
        match self.foxglove.as_ref().and_then(|f| f.message(message)) {
            Some((channel, bytes)) => {
                self.write_to(channel, log_time, message.timestamp_ns(), &bytes)
            }
            None => Ok(()),
        }
    }

    /// Writes the Foxglove cloud of a deviation chunk whose `points` were already selected by
    /// [`crate::foxglove::cloud_points`] (no further decimation); nothing without Foxglove's
    /// channels.
    pub fn write_foxglove_cloud(
        &mut self,
        log_time: u64,
        header: &DeviationHeader,
        points: &[PointDeviation],
    ) -> Result<(), mcap::McapError> {
        match &self.foxglove {
            Some(f) => {
                let (channel, bytes) = f.cloud(header, points.iter());
                self.write_to(channel, log_time, header.timestamp_ns, &bytes)
            }
            None => Ok(()),
        }
    }

    /// Writes the job's metadata record.
    pub fn metadata(&mut self, meta: &JobMetadata) -> Result<(), mcap::McapError> {
        self.mcap.write_metadata(&mcap::records::Metadata {
            name: METADATA_JOB.to_string(),
            metadata: meta.to_map(),
        })
    }

    /// Attaches the design file's bytes as `design/<name>`, so a recording can be reviewed
    /// without the design beside it.
    /// Attaches a scan layer's findings state (see [`ATTACHMENT_SCAN_LAYER_STATE`]).
    pub fn attach_scan_layer_state(
        &mut self,
        record: &ScanLayerStateRecord,
        time: u64,
    ) -> Result<(), mcap::McapError> {
        let data = postcard::to_allocvec(record).expect("a record of bytes always encodes");
        self.mcap.attach(&mcap::Attachment {
            log_time: time,
            create_time: time,
            name: ATTACHMENT_SCAN_LAYER_STATE.into(),
            media_type: "application/x-asbuilt-postcard".into(),
            data: std::borrow::Cow::Owned(data),
        })
    }

    /// Attaches the design file.
    pub fn attach_design(
        &mut self,
        name: &str,
        bytes: &[u8],
        time: u64,
    ) -> Result<(), mcap::McapError> {
        self.mcap.attach(&mcap::Attachment {
            log_time: time,
            create_time: time,
            name: format!("{ATTACHMENT_DESIGN}/{name}"),
            media_type: "application/octet-stream".into(),
            data: std::borrow::Cow::Borrowed(bytes),
        })
    }

    /// Ends the current chunk and flushes it to the file.
    pub fn flush(&mut self) -> Result<(), mcap::McapError> {
        self.mcap.flush()
    }

    /// Writes the summary and footer.
    pub fn finish(mut self) -> Result<W, mcap::McapError> {
        self.mcap.finish()?;
        Ok(self.mcap.into_inner())
    }
}

/// Why a recording cannot be read.
#[derive(Debug, thiserror::Error)]
pub enum ReadError {
    /// Not an MCAP file, or one the mcap crate cannot read.
    #[error("not a readable MCAP file: {0}")]
    Mcap(#[from] mcap::McapError),
    /// Records are cut short or overlap (a writer died, or the file was damaged).
    #[error("the file is damaged: {0}")]
    Damaged(#[from] Damaged),
    /// A record does not decode as its channel's message.
    #[error("message {index} on {topic}: {source}")]
    Decode {
        /// The message's index in the file, from 0.
        index: usize,
        /// The message's topic.
        topic: String,
        /// Why it does not decode.
        source: DecodeError,
    },
}

impl From<RecordError> for ReadError {
    fn from(e: RecordError) -> Self {
        match e {
            RecordError::Mcap(e) => ReadError::Mcap(e),
            RecordError::Damaged(e) => ReadError::Damaged(e),
        }
    }
}

/// The messages of a recording in file order, decoded one at a time (chunks are decompressed as
/// they are reached, so a large file is never held whole). Channels of other topics are skipped.
/// Reading stops at the first error.
pub fn messages(
    bytes: &[u8],
) -> Result<impl Iterator<Item = Result<(u64, Recorded), ReadError>> + '_, ReadError> {
    messages_on(bytes, &Channel::ALL)
}

/// [`messages`] of the `wanted` channels only: the others are not decoded (a reader after the
/// station events and reports skips the scan chunks' points).
pub fn messages_on<'a>(
    bytes: &'a [u8],
    wanted: &'a [Channel],
) -> Result<impl Iterator<Item = Result<(u64, Recorded), ReadError>> + 'a, ReadError> {
    if !bytes.starts_with(mcap::MAGIC) {
        return Err(ReadError::Mcap(mcap::McapError::BadMagic));
    }
    let mut channels: BTreeMap<u16, (Channel, String)> = BTreeMap::new();
    let mut index = 0usize;
    Ok(
        Records::new(bytes, Chunks::Open, true).filter_map(move |record| match record {
            Err(e) => Some(Err(e.into())),
            Ok(mcap::records::Record::Channel(c)) => {
                match Channel::from_topic(&c.topic) {
                    Some(ch) => channels.insert(c.id, (ch, c.topic)),
                    None => channels.remove(&c.id),
                };
                None
            }
            Ok(mcap::records::Record::Message { header, data }) => {
                index += 1;
                let (channel, topic) = channels.get(&header.channel_id)?;
                if !wanted.contains(channel) {
                    return None;
                }
                Some(
                    Recorded::decode(*channel, &data)
                        .map(|msg| (header.log_time, msg))
                        .map_err(|source| ReadError::Decode {
                            index: index - 1,
                            topic: topic.clone(),
                            source,
                        }),
                )
            }
            Ok(_) => None,
        }),
    )
}

/// The messages of a recording with its inputs (station events, poses, scan chunks) in the order the agent
/// processed them, for every reader that re-runs a job: `report`, `replay`, the Python reader.
///
/// An agent reads station events ahead of the chunks still queued, and records each message as
/// it reads it, so a recording can hold a station's End before chunks the End counts. The agent
/// still waits for those chunks; a reader that closed the station at its End would lose them.
/// Here an End is held back until its station's announced chunks have gone by, or the file
/// ends. An End that announces no count goes where it was recorded. Outputs (reports, findings,
/// deviations, status) stay where they are.
pub fn messages_in_agent_order(
    bytes: &[u8],
) -> Result<impl Iterator<Item = Result<(u64, Recorded), ReadError>> + '_, ReadError> {
    Ok(AgentOrder::new(messages(bytes)?))
}

/// See [`messages_in_agent_order`]; over any stream of recorded messages.
pub struct AgentOrder<I> {
    inner: I,
    /// Chunks seen per station.
    chunks: BTreeMap<(u64, u32), u64>,
    /// Ends waiting for their chunks, with the log time they were recorded at.
    held: BTreeMap<(u64, u32), (u64, StationEvent)>,
    /// Ends due now (their last chunk just went by, or the file ended).
    due: std::collections::VecDeque<(u64, Recorded)>,
    ended: bool,
}

impl<I> AgentOrder<I> {
    /// Reorders `inner`'s messages into the order the agent handled them.
    pub fn new(inner: I) -> Self {
        Self {
            inner,
            chunks: BTreeMap::new(),
            held: BTreeMap::new(),
            due: std::collections::VecDeque::new(),
            ended: false,
        }
    }
}

impl<I> AgentOrder<I> {
    /// A chunk (scan or profile) of `key` went by at `t`: its End is due after its last.
    fn chunk_of(&mut self, key: (u64, u32), t: u64) {
        let seen = self.chunks.entry(key).or_insert(0);
        *seen += 1;
        if let Some(&(_, e)) = self.held.get(&key)
            && *seen >= u64::from(e.expected_chunks)
        {
            let (te, e) = self.held.remove(&key).expect("just seen");
            self.due.push_back((te.max(t), Recorded::Event(e)));
        }
    }
}

impl<I: Iterator<Item = Result<(u64, Recorded), ReadError>>> Iterator for AgentOrder<I> {
    type Item = Result<(u64, Recorded), ReadError>;

    fn next(&mut self) -> Option<Self::Item> {
        loop {
            if let Some(m) = self.due.pop_front() {
                return Some(Ok(m));
            }
            if self.ended {
                return None;
            }
            let Some(item) = self.inner.next() else {
                self.ended = true;
                let held = std::mem::take(&mut self.held);
                self.due
                    .extend(held.into_values().map(|(t, e)| (t, Recorded::Event(e))));
                continue;
            };
            let (t, m) = match item {
                Ok(m) => m,
                Err(e) => return Some(Err(e)),
            };
            match m {
                Recorded::Event(e)
                    if e.kind() == Some(crate::StationEventKind::End)
                        && self.chunks.get(&(e.job, e.station)).copied().unwrap_or(0)
                            < u64::from(e.expected_chunks) =>
                {
                    self.held.insert((e.job, e.station), (t, e));
                }
                Recorded::Chunk(ref h, _) => {
                    self.chunk_of((h.job, h.station), t);
                    return Some(Ok((t, m)));
                }
                Recorded::Profiles(ref h, _) => {
                    self.chunk_of((h.job, h.pass), t);
                    return Some(Ok((t, m)));
                }
                m => return Some(Ok((t, m))),
            }
        }
    }
}

/// A design file attached to a recording: its name and bytes.
pub type DesignAttachment = (String, Vec<u8>);

/// The job metadata and the design attachments of a recording.
pub fn job(bytes: &[u8]) -> Result<(Option<JobMetadata>, Vec<DesignAttachment>), ReadError> {
    if !bytes.starts_with(mcap::MAGIC) {
        return Err(ReadError::Mcap(mcap::McapError::BadMagic));
    }
    let mut metadata = None;
    let mut attachments = Vec::new();
    for record in Records::new(bytes, Chunks::Skip, true) {
        match record? {
            mcap::records::Record::Metadata(m) if m.name == METADATA_JOB => {
                metadata = Some(JobMetadata::from_map(&m.metadata));
            }
            mcap::records::Record::Attachment { header, data, .. }
                if header.name != ATTACHMENT_SCAN_LAYER_STATE =>
            {
                attachments.push((header.name.clone(), data.into_owned()));
            }
            _ => {}
        }
    }
    Ok((metadata, attachments))
}

/// Every scan layer state attached to a recording, in file order, to `take`; records that do
/// not decode are skipped. Reading stops at a damaged record (a file whose writer died ends
/// so), which is returned after what came before it was taken. Returns the records skipped.
pub fn scan_layer_states(
    bytes: &[u8],
    mut take: impl FnMut(ScanLayerStateRecord),
) -> Result<usize, ReadError> {
    if !bytes.starts_with(mcap::MAGIC) {
        return Err(ReadError::Mcap(mcap::McapError::BadMagic));
    }
    let mut skipped = 0;
    for record in Records::new(bytes, Chunks::Skip, true) {
        if let mcap::records::Record::Attachment { header, data, .. } = record? {
            if header.name != ATTACHMENT_SCAN_LAYER_STATE {
                continue;
            }
            match postcard::from_bytes::<ScanLayerStateRecord>(&data) {
                Ok(r) if r.version == ScanLayerStateRecord::VERSION => take(r),
                _ => skipped += 1,
            }
        }
    }
    Ok(skipped)
}

/// Every complete record of a file whose writer died (no summary, no footer, a chunk cut off),
/// rewritten into a valid recording. Every channel is kept: asbuilt's own are written as the
/// recorder writes them, any other (Foxglove's, a channel a newer build added) with its schema
/// and messages as they are. Returns the messages, metadata and attachments saved.
pub fn recover<W: Write + Seek>(
    broken: &[u8],
    out: W,
) -> Result<(W, RecoverCounts), mcap::McapError> {
    let mut r = Recovery {
        w: RecordingWriter::new(out)?,
        counts: RecoverCounts::default(),
        ours: BTreeMap::new(),
        schemas: BTreeMap::new(),
        others: BTreeMap::new(),
    };
    // Chunks are opened one at a time and all or nothing: a chunk's checksum is checked before
    // any of its records is kept.
    for record in Records::new(broken, Chunks::Open, false) {
        match record {
            Ok(record) => r.take(record)?,
            Err(_) => {
                r.counts.truncated = true;
                break;
            }
        }
    }
    Ok((r.w.finish()?, r.counts))
}

/// A recovery under way: the file being written, and how the broken file's channels map to it.
struct Recovery<W: Write + Seek> {
    w: RecordingWriter<W>,
    counts: RecoverCounts,
    /// The broken file's ids of asbuilt's own channels.
    ours: BTreeMap<u16, Channel>,
    /// The broken file's schemas by id: name, encoding, data.
    schemas: BTreeMap<u16, (String, String, Vec<u8>)>,
    /// The broken file's other channels, by id, to their ids in the new file.
    others: BTreeMap<u16, u16>,
}

impl<W: Write + Seek> Recovery<W> {
    fn take(&mut self, record: mcap::records::Record<'_>) -> Result<(), mcap::McapError> {
        use mcap::records::Record;
        match record {
            Record::Schema { header, data } => {
                self.schemas
                    .insert(header.id, (header.name, header.encoding, data.into_owned()));
            }
            Record::Channel(c) => match Channel::from_topic(&c.topic) {
                Some(ch) => {
                    self.ours.insert(c.id, ch);
                }
                None => {
                    // Schema 0 is "no schema"; a schema record lost with its chunk leaves the
                    // channel without one rather than dropping its messages.
                    let schema = match self.schemas.get(&c.schema_id) {
                        Some((name, encoding, data)) => {
                            self.w.mcap.add_schema(name, encoding, data)?
                        }
                        None => 0,
                    };
                    let id = self.w.mcap.add_channel(
                        schema,
                        &c.topic,
                        &c.message_encoding,
                        &c.metadata,
                    )?;
                    self.others.insert(c.id, id);
                }
            },
            Record::Message { header, data } => {
                if let Some(&ch) = self.ours.get(&header.channel_id) {
                    self.w
                        .write_raw(ch, header.log_time, header.publish_time, &data)?;
                    self.counts.messages += 1;
                } else if let Some(&id) = self.others.get(&header.channel_id) {
                    let header = mcap::records::MessageHeader {
                        channel_id: id,
                        ..header
                    };
                    self.w.mcap.write_to_known_channel(&header, &data)?;
                    self.counts.messages += 1;
                } else {
                    self.counts.skipped += 1;
                }
            }
            Record::Metadata(m) => {
                self.w.mcap.write_metadata(&m)?;
                self.counts.metadata += 1;
            }
            Record::Attachment { header, data, .. } => {
                self.w.mcap.attach(&mcap::Attachment {
                    log_time: header.log_time,
                    create_time: header.create_time,
                    name: header.name.clone(),
                    media_type: header.media_type.clone(),
                    data,
                })?;
                self.counts.attachments += 1;
            }
            _ => {}
        }
        Ok(())
    }
}

/// What a recovery kept.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct RecoverCounts {
    /// Messages copied, in every channel.
    pub messages: u64,
    /// Metadata records copied.
    pub metadata: u64,
    /// Attachments copied.
    pub attachments: u64,
    /// Messages whose channel record was lost with the end of the file.
    pub skipped: u64,
    /// The file ended inside a record (its writer died); everything before was kept.
    pub truncated: bool,
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::{PoseMode, PoseSnapshot, StationEventKind};

    fn job_messages() -> Vec<Recorded> {
        let mut out = Vec::new();
        for station in 0..4u32 {
            out.push(Recorded::Event(StationEvent::new(
                StationEventKind::Begin,
                7,
                station,
            )));
            out.push(Recorded::Pose(PoseSnapshot::new(
                7,
                station,
                PoseMode::DesignScanner,
            )));
            for seq in 0..3u64 {
                let pts: Vec<ScanPoint> = (0..20_000)
                    .map(|i| ScanPoint::new(i as f32 * 1e-3, station as f32, seq as f32))
                    .collect();
                let mut h = ChunkHeader::new(7, station, seq, pts.len() as u32);
                h.last = u8::from(seq == 2);
                out.push(Recorded::Chunk(h, pts));
            }
            out.push(Recorded::Event(StationEvent::new(
                StationEventKind::End,
                7,
                station,
            )));
        }
        out
    }

    /// A station of three chunks whose End sits at `end_at` among them (0: before all).
    fn station_with_end_at(end_at: usize, announced: u32) -> Vec<Recorded> {
        let chunk = |seq| Recorded::Chunk(ChunkHeader::new(1, 5, seq, 0), Vec::new());
        let mut end = StationEvent::new(StationEventKind::End, 1, 5);
        end.expected_chunks = announced;
        let mut out = vec![
            Recorded::Event(StationEvent::new(StationEventKind::Begin, 1, 5)),
            Recorded::Pose(PoseSnapshot::new(1, 5, PoseMode::DesignScanner)),
        ];
        for seq in 0..3 {
            if seq == end_at as u64 {
                out.push(Recorded::Event(end));
            }
            out.push(chunk(seq));
        }
        if end_at >= 3 {
            out.push(Recorded::Event(end));
        }
        // An output the agent wrote after the End: it stays where it is.
        out.push(Recorded::Deviations(
            crate::DeviationHeader::new(1, 5, 0),
            Vec::new(),
        ));
        out
    }

    /// The messages in agent order, as their bytes (an unset printed height is NaN).
    fn in_agent_order(messages: Vec<Recorded>) -> Vec<Vec<u8>> {
        let numbered = messages.into_iter().enumerate();
        AgentOrder::new(numbered.map(|(i, m)| Ok((i as u64, m))))
            .map(|m| m.unwrap().1.encode())
            .collect()
    }

    fn encoded(messages: &[Recorded]) -> Vec<Vec<u8>> {
        messages.iter().map(Recorded::encode).collect()
    }

    #[test]
    fn an_end_recorded_before_its_chunks_comes_after_them() {
        let ordered = station_with_end_at(3, 3);
        assert_eq!(ordered.len(), 7);
        for end_at in 0..=3 {
            assert_eq!(
                in_agent_order(station_with_end_at(end_at, 3)),
                encoded(&ordered),
                "End recorded before chunk {end_at}"
            );
        }
        // Chunks the recording lost: the End still comes, when the file ends.
        let mut lost = station_with_end_at(1, 3);
        lost.retain(|m| !matches!(m, Recorded::Chunk(h, _) if h.sequence == 2));
        let got = in_agent_order(lost);
        assert_eq!(got.len(), 6);
        assert_eq!(got[5], ordered[5].encode());
        // An End that announces no count stays where it was.
        assert_eq!(
            in_agent_order(station_with_end_at(1, 0))[3],
            station_with_end_at(1, 0)[3].encode()
        );
    }

    fn write_job(flush_per_station: bool) -> (Vec<u8>, Vec<usize>) {
        write_job_with(flush_per_station, ChunkCompression::default())
    }

    fn write_job_with(
        flush_per_station: bool,
        compression: ChunkCompression,
    ) -> (Vec<u8>, Vec<usize>) {
        let mut w =
            RecordingWriter::with_compression(std::io::Cursor::new(Vec::new()), compression)
                .unwrap();
        w.metadata(&JobMetadata {
            writer: "test".into(),
            design_sha256: "abc".into(),
            ..Default::default()
        })
        .unwrap();
        w.attach_design("box.stl", b"solid box", 1).unwrap();
        // Bytes written after each station, to cut the file at.
        let mut marks = Vec::new();
        for (i, m) in job_messages().iter().enumerate() {
            w.write(i as u64, m).unwrap();
            if flush_per_station
                && matches!(m, Recorded::Event(e) if e.kind() == Some(StationEventKind::End))
            {
                w.flush().unwrap();
                marks.push(i + 1);
            }
        }
        (w.finish().unwrap().into_inner(), marks)
    }

    /// A scan chunk written from its points where they lie (as the agent writes a chunk still
    /// in shared memory) makes the file a copied chunk makes, byte for byte.
    #[test]
    fn scan_chunks_written_in_place_make_the_same_file() {
        let write = |in_place: bool| {
            let mut w = RecordingWriter::new(std::io::Cursor::new(Vec::new())).unwrap();
            for (i, m) in job_messages().iter().enumerate() {
                match m {
                    Recorded::Chunk(h, points) if in_place => {
                        w.write_scan_chunk(i as u64, h, points).unwrap()
                    }
                    _ => w.write(i as u64, m).unwrap(),
                }
            }
            w.finish().unwrap().into_inner()
        };
        assert!(
            job_messages()
                .iter()
                .any(|m| matches!(m, Recorded::Chunk(..)))
        );
        assert_eq!(write(true), write(false));
    }

    /// The zstd frames of a recording's chunks, as they are in the file.
    fn zstd_frames(bytes: &[u8]) -> Vec<Vec<u8>> {
        mcap::read::LinearReader::new(bytes)
            .unwrap()
            .filter_map(|r| match r.unwrap() {
                mcap::records::Record::Chunk { header, data } if header.compression == "zstd" => {
                    Some(data.into_owned())
                }
                _ => None,
            })
            .collect()
    }

    /// The mcap crate takes the zstd level as a u32 and casts it to zstd's i32: a crate that
    /// clamped it instead would turn [`ZSTD_LEVEL`] into zstd's slowest level. Each chunk's
    /// zstd frame says its window: 2^19 bytes at levels up to 2 (on input of unknown size),
    /// 2^21 and more at level 3 and above.
    #[test]
    fn chunks_are_compressed_at_a_fast_zstd_level() {
        let (bytes, _) = write_job_with(true, ChunkCompression::Zstd);
        let frames = zstd_frames(&bytes);
        assert!(!frames.is_empty());
        for f in frames {
            assert_eq!(f[..4], [0x28, 0xb5, 0x2f, 0xfd], "a zstd frame");
            let descriptor = f[4];
            assert_eq!(descriptor & 0x20, 0, "streamed: the frame gives its window");
            let window_log = 10 + (f[5] >> 3);
            assert!(window_log <= 19, "window 2^{window_log}: not a fast level");
        }
    }

    #[test]
    fn a_recording_reads_back_message_for_message() {
        for compression in [
            ChunkCompression::None,
            ChunkCompression::Lz4,
            ChunkCompression::Zstd,
        ] {
            let (bytes, _) = write_job_with(true, compression);
            let read: Vec<(u64, Recorded)> =
                messages(&bytes).unwrap().map(Result::unwrap).collect();
            let want = job_messages();
            assert_eq!(read.len(), want.len(), "{compression:?}");
            for (i, ((t, m), w)) in read.iter().zip(&want).enumerate() {
                assert_eq!(*t, i as u64);
                // Bytes, not values: a NaN printed height is not equal to itself.
                assert_eq!(m.encode(), w.encode());
            }
            // The checked reader (recover, resume) opens every chunk the same.
            let (_, counts) = recover(&bytes, std::io::Cursor::new(Vec::new())).unwrap();
            assert_eq!(counts.messages as usize, want.len(), "{compression:?}");
        }
        let (bytes, _) = write_job(true);
        let (meta, att) = job(&bytes).unwrap();
        assert_eq!(meta.unwrap().design_sha256, "abc");
        assert_eq!(
            att,
            vec![("design/box.stl".to_string(), b"solid box".to_vec())]
        );
    }

    /// zstd makes far more than lz4's 255 bytes of one from a chunk of zeros: the checked
    /// reader must still open it whole.
    #[test]
    fn a_zstd_chunk_of_zeros_reads_back() {
        let mut w = RecordingWriter::with_compression(
            std::io::Cursor::new(Vec::new()),
            ChunkCompression::Zstd,
        )
        .unwrap();
        let header = ChunkHeader::new(7, 0, 0, 200_000);
        let points = vec![crate::ScanPoint::default(); 200_000];
        w.write(1, &Recorded::Chunk(header, points.clone()))
            .unwrap();
        let bytes = w.finish().unwrap().into_inner();
        assert!(bytes.len() < 200_000 * 20 / 255, "{} bytes", bytes.len());
        let (_, counts) = recover(&bytes, std::io::Cursor::new(Vec::new())).unwrap();
        assert_eq!(counts.messages, 1);
        let read: Vec<_> = messages(&bytes).unwrap().map(Result::unwrap).collect();
        assert!(matches!(&read[0].1, Recorded::Chunk(_, p) if *p == points));
    }

    #[test]
    fn a_file_cut_at_60_percent_recovers_every_completed_station() {
        let (bytes, _) = write_job(true);
        let cut = &bytes[..bytes.len() * 6 / 10];
        // The summary is gone: an ordinary read fails.
        assert!(messages(cut).is_err() || messages(cut).unwrap().any(|m| m.is_err()));
        let (fixed, counts) = recover(cut, std::io::Cursor::new(Vec::new())).unwrap();
        assert!(counts.truncated);
        assert_eq!((counts.metadata, counts.attachments), (1, 1));
        let fixed = fixed.into_inner();
        let read: Vec<(u64, Recorded)> = messages(&fixed).unwrap().map(Result::unwrap).collect();
        // Whole stations only (each was flushed as one chunk), in order, and all of those
        // whose chunk ended before the cut.
        let per_station = job_messages().len() / 4;
        assert_eq!(read.len() % per_station, 0, "{}", read.len());
        assert!(read.len() >= per_station, "nothing recovered");
        assert_eq!(counts.messages as usize, read.len());
        let want = job_messages();
        for ((_, m), w) in read.iter().zip(&want) {
            assert_eq!(m.encode(), w.encode());
        }
    }

    /// Every message of every channel, by topic: what a reader that knows no asbuilt channel
    /// sees.
    fn topics(bytes: &[u8]) -> BTreeMap<String, usize> {
        let mut out = BTreeMap::new();
        for m in mcap::MessageStream::new(bytes).unwrap() {
            *out.entry(m.unwrap().channel.topic.clone()).or_insert(0) += 1;
        }
        out
    }

    #[test]
    fn recovery_keeps_foxglove_and_unknown_channels_as_they_are() {
        let mut w = RecordingWriter::new(std::io::Cursor::new(Vec::new()))
            .unwrap()
            .with_foxglove(Box::new(|_| [0, 0, 0]))
            .unwrap();
        let schema = w
            .mcap
            .add_schema("future.Thing", "jsonschema", b"{}")
            .unwrap();
        let future = w
            .mcap
            .add_channel(schema, "/future/thing", "json", &BTreeMap::new())
            .unwrap();
        for (i, m) in job_messages().iter().enumerate() {
            w.write(i as u64, m).unwrap();
            let header = mcap::records::MessageHeader {
                channel_id: future,
                sequence: i as u32,
                log_time: i as u64,
                publish_time: i as u64,
            };
            w.mcap
                .write_to_known_channel(&header, b"{\"n\":1}")
                .unwrap();
        }
        let bytes = w.finish().unwrap().into_inner();
        let want = topics(&bytes);
        assert!(want.keys().any(|t| t.starts_with("/foxglove")), "{want:?}");
        let (fixed, counts) = recover(&bytes, std::io::Cursor::new(Vec::new())).unwrap();
        let fixed = fixed.into_inner();
        assert_eq!(topics(&fixed), want);
        assert_eq!(counts.messages as usize, want.values().sum::<usize>());
        assert_eq!(counts.skipped, 0);
        // asbuilt's own channels still read back message for message.
        let read: Vec<(u64, Recorded)> = messages(&fixed).unwrap().map(Result::unwrap).collect();
        assert_eq!(read.len(), job_messages().len());
    }
}
