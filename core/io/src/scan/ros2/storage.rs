//! A rosbag2's files and their messages in the order recorded: MCAP (the default storage since
//! ROS 2 Jazzy; read with the checked reader the recorder's files are read with) or SQLite 3
//! (`.db3`, before). A bag is its folder (`metadata.yaml` and the files) or one of its files.

use std::path::{Path, PathBuf};

use asbuilt_protocol::mcap_records::{Chunks, Records};
use mcap::records::Record;

use crate::scan::error::ScanError;

/// The storage of a bag's files.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(super) enum Kind {
    Mcap,
    Sqlite,
}

/// A bag's files, in recording order.
#[derive(Debug)]
pub(super) struct Storage {
    pub(super) kind: Kind,
    pub(super) files: Vec<PathBuf>,
}

/// Where a message is, to find it again: its file, and its place there (SQLite: the row id;
/// MCAP: its ordinal among the file's messages).
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord)]
pub(super) struct Place {
    pub(super) file: usize,
    pub(super) key: u64,
}

/// One message as the storage holds it.
pub(super) struct BagMessage<'a> {
    pub(super) place: Place,
    pub(super) topic: &'a str,
    /// Its type, e.g. `sensor_msgs/msg/PointCloud2`.
    pub(super) kind: &'a str,
    /// Its CDR bytes.
    pub(super) data: &'a [u8],
}

fn content(what: String) -> ScanError {
    ScanError::Content(what)
}

/// The trailing number of a bag file's name (`bag_0.mcap` … `bag_10.mcap`), for their order.
fn split_index(path: &Path) -> (u64, String) {
    let stem = path
        .file_stem()
        .map(|s| s.to_string_lossy().into_owned())
        .unwrap_or_default();
    let digits: String = stem
        .chars()
        .rev()
        .take_while(|c| c.is_ascii_digit())
        .collect::<Vec<_>>()
        .into_iter()
        .rev()
        .collect();
    (digits.parse().unwrap_or(0), stem)
}

impl Storage {
    /// The bag at `path`: a rosbag2 folder or one `.mcap` / `.db3` file.
    pub(super) fn open(path: &Path) -> Result<Self, ScanError> {
        let kind_of = |p: &Path| match p.extension().and_then(|e| e.to_str()) {
            Some("mcap") => Some(Kind::Mcap),
            Some("db3") => Some(Kind::Sqlite),
            _ => None,
        };
        if path.is_dir() {
            let mut files: Vec<PathBuf> = std::fs::read_dir(path)
                .map_err(|e| content(format!("cannot list the bag folder: {e}")))?
                .filter_map(|e| e.ok().map(|e| e.path()))
                .filter(|p| kind_of(p).is_some())
                .collect();
            files.sort_by_key(|p| split_index(p));
            let Some(first) = files.first() else {
                return Err(content(
                    "the folder holds no .mcap or .db3 file: is it a rosbag2 (ros2 bag record) \
                     folder?"
                        .into(),
                ));
            };
            let kind = kind_of(first).expect("filtered");
            if files.iter().any(|f| kind_of(f) != Some(kind)) {
                return Err(content(
                    "the folder mixes .mcap and .db3 files; give one of them".into(),
                ));
            }
            return Ok(Self { kind, files });
        }
        match kind_of(path) {
            Some(kind) => Ok(Self {
                kind,
                files: vec![path.to_path_buf()],
            }),
            None => Err(content(
                "a ROS 2 bag is a folder recorded by `ros2 bag record`, or one of its .mcap or \
                 .db3 files"
                    .into(),
            )),
        }
    }

    /// Hands every message of `topics` (every topic when empty), in recording order, to `f`,
    /// which says whether to go on. Only the files `files` says yes to are read.
    pub(super) fn each(
        &self,
        topics: &[&str],
        files: &dyn Fn(usize) -> bool,
        f: &mut dyn FnMut(BagMessage<'_>) -> Result<bool, ScanError>,
    ) -> Result<(), ScanError> {
        for (i, path) in self.files.iter().enumerate() {
            if !files(i) {
                continue;
            }
            let named = |e: ScanError| match e {
                ScanError::Content(m) => content(format!("{}: {m}", path.display())),
                e => e,
            };
            let go_on = match self.kind {
                Kind::Mcap => each_mcap(i, path, topics, f),
                Kind::Sqlite => each_sqlite(i, path, topics, f),
            }
            .map_err(named)?;
            if !go_on {
                break;
            }
        }
        Ok(())
    }
}

fn each_mcap(
    file: usize,
    path: &Path,
    topics: &[&str],
    f: &mut dyn FnMut(BagMessage<'_>) -> Result<bool, ScanError>,
) -> Result<bool, ScanError> {
    let file_handle =
        std::fs::File::open(path).map_err(|e| content(format!("cannot open: {e}")))?;
    // SAFETY: only read; a bag being written underneath gives damaged records, which the
    // checked reader refuses, never a wrong read of memory.
    let map = unsafe { memmap2::Mmap::map(&file_handle) }
        .map_err(|e| content(format!("cannot read: {e}")))?;
    if !map.starts_with(mcap::MAGIC) {
        return Err(content("not an MCAP file".into()));
    }
    // Channels by id: topic, and its schema's name.
    let mut channels: std::collections::BTreeMap<u16, (String, u16)> = Default::default();
    let mut schemas: std::collections::BTreeMap<u16, String> = Default::default();
    let mut ordinal = 0u64;
    // A bag whose recorder was killed has no end: read up to where it stops.
    let ends = map.ends_with(mcap::MAGIC);
    for record in Records::new(&map, Chunks::Open, ends) {
        match record.map_err(|e| content(format!("damaged: {e}")))? {
            Record::Schema { header, .. } => {
                schemas.insert(header.id, header.name);
            }
            Record::Channel(c) => {
                channels.insert(c.id, (c.topic, c.schema_id));
            }
            Record::Message { header, data } => {
                ordinal += 1;
                let Some((topic, schema)) = channels.get(&header.channel_id) else {
                    continue;
                };
                if !topics.is_empty() && !topics.contains(&topic.as_str()) {
                    continue;
                }
                let kind = schemas.get(schema).map_or("", String::as_str);
                let m = BagMessage {
                    place: Place {
                        file,
                        key: ordinal - 1,
                    },
                    topic,
                    kind,
                    data: &data,
                };
                if !f(m)? {
                    return Ok(false);
                }
            }
            _ => {}
        }
    }
    Ok(true)
}

fn each_sqlite(
    file: usize,
    path: &Path,
    topics: &[&str],
    f: &mut dyn FnMut(BagMessage<'_>) -> Result<bool, ScanError>,
) -> Result<bool, ScanError> {
    use rusqlite::{Connection, OpenFlags};
    let sql = |e: rusqlite::Error| content(format!("not a readable rosbag2 SQLite file ({e})"));
    let db = Connection::open_with_flags(
        path,
        OpenFlags::SQLITE_OPEN_READ_ONLY | OpenFlags::SQLITE_OPEN_NO_MUTEX,
    )
    .map_err(sql)?;
    let mut kinds: std::collections::BTreeMap<i64, (String, String)> = Default::default();
    {
        let mut q = db
            .prepare("SELECT id, name, type FROM topics")
            .map_err(sql)?;
        let mut rows = q.query([]).map_err(sql)?;
        while let Some(r) = rows.next().map_err(sql)? {
            kinds.insert(
                r.get(0).map_err(sql)?,
                (r.get(1).map_err(sql)?, r.get(2).map_err(sql)?),
            );
        }
    }
    let mut q = db
        .prepare("SELECT id, topic_id, data FROM messages ORDER BY timestamp, id")
        .map_err(sql)?;
    let mut rows = q.query([]).map_err(sql)?;
    while let Some(r) = rows.next().map_err(sql)? {
        let topic_id: i64 = r.get(1).map_err(sql)?;
        let Some((topic, kind)) = kinds.get(&topic_id) else {
            continue;
        };
        if !topics.is_empty() && !topics.contains(&topic.as_str()) {
            continue;
        }
        let id: i64 = r.get(0).map_err(sql)?;
        let data = r
            .get_ref(2)
            .map_err(sql)?
            .as_blob()
            .map_err(|e| content(format!("message {id} of {topic} holds no bytes ({e})")))?;
        let m = BagMessage {
            place: Place {
                file,
                key: id as u64,
            },
            topic,
            kind,
            data,
        };
        if !f(m)? {
            return Ok(false);
        }
    }
    Ok(true)
}
