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

/// Where a message is, to read it again without reading what comes before: its file, and its
/// place there (SQLite: the row id; MCAP: the offset of its chunk, or of itself when it is in
/// none, and its ordinal among that record's messages), with its log time to check it by.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord)]
pub(super) struct Place {
    pub(super) file: usize,
    pub(super) offset: u64,
    pub(super) index: u32,
    pub(super) log_time: u64,
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

    /// Hands every message, in recording order, to `f`.
    pub(super) fn each(
        &self,
        f: &mut dyn FnMut(BagMessage<'_>) -> Result<(), ScanError>,
    ) -> Result<(), ScanError> {
        for (i, path) in self.files.iter().enumerate() {
            match self.kind {
                Kind::Mcap => each_mcap(i, path, f),
                Kind::Sqlite => each_sqlite(i, path, f),
            }
            .map_err(|e| self.naming(i, e))?;
        }
        Ok(())
    }

    /// The bytes of the message at `place`.
    pub(super) fn read_at(&self, place: Place) -> Result<Vec<u8>, ScanError> {
        let path = &self.files[place.file];
        match self.kind {
            Kind::Mcap => mcap_at(path, place),
            Kind::Sqlite => sqlite_at(path, place),
        }
        .map_err(|e| self.naming(place.file, e))
    }

    /// An error of file `i`, naming it when the bag has several.
    fn naming(&self, i: usize, e: ScanError) -> ScanError {
        match e {
            ScanError::Content(m) if self.files.len() > 1 => {
                content(format!("{}: {m}", self.files[i].display()))
            }
            e => e,
        }
    }
}

fn each_mcap(
    file: usize,
    path: &Path,
    f: &mut dyn FnMut(BagMessage<'_>) -> Result<(), ScanError>,
) -> Result<(), ScanError> {
    let opened = std::fs::File::open(path).map_err(|e| content(format!("cannot open: {e}")))?;
    let mut magic = [0u8; 8];
    if std::io::Read::read_exact(&mut &opened, &mut magic).is_err() || magic != *mcap::MAGIC {
        return Err(content("not an MCAP file".into()));
    }
    // Read as it comes, a chunk at a time; a bag whose recorder was killed has no end and is
    // read up to where it stops.
    let mut records = Records::from_file(opened, Chunks::Open, 0)
        .map_err(|e| content(format!("cannot read: {e}")))?;
    // Channels by id: topic, and its schema's name.
    let mut channels: std::collections::BTreeMap<u16, (String, u16)> = Default::default();
    let mut schemas: std::collections::BTreeMap<u16, String> = Default::default();
    let (mut top, mut index) = (u64::MAX, 0u32);
    while let Some(record) = records.next() {
        match record.map_err(|e| content(format!("damaged: {e}")))? {
            Record::Schema { header, .. } => {
                schemas.insert(header.id, header.name);
            }
            Record::Channel(c) => {
                channels.insert(c.id, (c.topic, c.schema_id));
            }
            Record::Message { header, data } => {
                if records.record_offset() != top {
                    (top, index) = (records.record_offset(), 0);
                }
                index += 1;
                let Some((topic, schema)) = channels.get(&header.channel_id) else {
                    continue;
                };
                f(BagMessage {
                    place: Place {
                        file,
                        offset: top,
                        index: index - 1,
                        log_time: header.log_time,
                    },
                    topic,
                    kind: schemas.get(schema).map_or("", String::as_str),
                    data: &data,
                })?;
            }
            _ => {}
        }
    }
    Ok(())
}

/// The message at `place` of an MCAP file: its chunk opened, the message counted to.
fn mcap_at(path: &Path, place: Place) -> Result<Vec<u8>, ScanError> {
    let opened = std::fs::File::open(path).map_err(|e| content(format!("cannot open: {e}")))?;
    let records = Records::from_file(opened, Chunks::Open, place.offset)
        .map_err(|e| content(format!("cannot read: {e}")))?;
    let mut index = 0;
    for record in records {
        if let Record::Message { header, data } =
            record.map_err(|e| content(format!("damaged: {e}")))?
        {
            if index == place.index {
                if header.log_time != place.log_time {
                    break;
                }
                return Ok(data.into_owned());
            }
            index += 1;
        }
    }
    Err(content(format!(
        "the message logged at {} ns is no longer where the bag had it: was the bag changed \
         while it was read?",
        place.log_time
    )))
}

fn sqlite_at(path: &Path, place: Place) -> Result<Vec<u8>, ScanError> {
    let db = open_sqlite(path)?;
    db.query_row(
        "SELECT data FROM messages WHERE id = ?1",
        [place.offset as i64],
        |r| r.get::<_, Vec<u8>>(0),
    )
    .map_err(|e| {
        content(format!(
            "message {} cannot be read again ({e})",
            place.offset
        ))
    })
}

fn open_sqlite(path: &Path) -> Result<rusqlite::Connection, ScanError> {
    use rusqlite::{Connection, OpenFlags};
    Connection::open_with_flags(
        path,
        OpenFlags::SQLITE_OPEN_READ_ONLY | OpenFlags::SQLITE_OPEN_NO_MUTEX,
    )
    .map_err(|e| content(format!("not a readable rosbag2 SQLite file ({e})")))
}

fn each_sqlite(
    file: usize,
    path: &Path,
    f: &mut dyn FnMut(BagMessage<'_>) -> Result<(), ScanError>,
) -> Result<(), ScanError> {
    let sql = |e: rusqlite::Error| content(format!("not a readable rosbag2 SQLite file ({e})"));
    let db = open_sqlite(path)?;
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
        .prepare("SELECT id, topic_id, timestamp, data FROM messages ORDER BY timestamp, id")
        .map_err(sql)?;
    let mut rows = q.query([]).map_err(sql)?;
    while let Some(r) = rows.next().map_err(sql)? {
        let topic_id: i64 = r.get(1).map_err(sql)?;
        let Some((topic, kind)) = kinds.get(&topic_id) else {
            continue;
        };
        let id: i64 = r.get(0).map_err(sql)?;
        let stamp: i64 = r.get(2).map_err(sql)?;
        let data = r
            .get_ref(3)
            .map_err(sql)?
            .as_blob()
            .map_err(|e| content(format!("message {id} of {topic} holds no bytes ({e})")))?;
        f(BagMessage {
            place: Place {
                file,
                offset: id as u64,
                index: 0,
                log_time: stamp as u64,
            },
            topic,
            kind,
            data,
        })?;
    }
    Ok(())
}
