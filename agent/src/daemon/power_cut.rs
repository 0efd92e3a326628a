//! The power cut at any write of the recording. The recorder writes through a storage that
//! keeps, when the power goes, only what was synced; an agent started on what survives must
//! have every report the cell was told, and so tell the cell the truth about every attempt.

use std::path::PathBuf;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Mutex};

use asbuilt_protocol::StationReport;
use asbuilt_protocol::recording::JobMetadata;

use super::tests::{begin, bench, chunk, end, lifecycle, reports};
use super::*;
use crate::config::RecorderConfig;
use crate::recorder::{Storage, StoredFile};

/// The machine's power: on until the write numbered `cut_at`, off from it on.
struct Power {
    writes: AtomicU64,
    cut_at: u64,
    files: Mutex<Vec<(PathBuf, Arc<Mutex<Image>>)>>,
}

impl Power {
    fn new(cut_at: u64) -> Arc<Self> {
        Arc::new(Self {
            writes: AtomicU64::new(0),
            cut_at,
            files: Mutex::new(Vec::new()),
        })
    }

    fn is_off(&self) -> bool {
        self.writes.load(Ordering::SeqCst) >= self.cut_at
    }

    /// One more write, if the power is still on.
    fn write(&self) -> std::io::Result<()> {
        if self.writes.fetch_add(1, Ordering::SeqCst) >= self.cut_at {
            return Err(std::io::Error::other("the power is off"));
        }
        Ok(())
    }

    /// What the disk holds after the cut: each file's synced bytes, written out for real.
    fn leave_on_disk(&self) {
        for (path, image) in self.files.lock().unwrap().iter() {
            std::fs::write(path, &image.lock().unwrap().synced).unwrap();
        }
    }
}

/// A file as written (`data`) and as the disk has it (`synced`).
#[derive(Default)]
struct Image {
    data: Vec<u8>,
    pos: usize,
    synced: Vec<u8>,
}

struct CutStorage(Arc<Power>);

struct CutFile(Arc<Mutex<Image>>, Arc<Power>);

impl Storage for CutStorage {
    fn create_new(&self, path: &std::path::Path) -> std::io::Result<Box<dyn StoredFile>> {
        self.0.write()?;
        let image = Arc::new(Mutex::new(Image::default()));
        let mut files = self.0.files.lock().unwrap();
        files.push((path.to_path_buf(), image.clone()));
        Ok(Box::new(CutFile(image, self.0.clone())))
    }
}

impl std::io::Write for CutFile {
    fn write(&mut self, buf: &[u8]) -> std::io::Result<usize> {
        self.1.write()?;
        let mut f = self.0.lock().unwrap();
        let end = f.pos + buf.len();
        if f.data.len() < end {
            f.data.resize(end, 0);
        }
        let at = f.pos;
        f.data[at..end].copy_from_slice(buf);
        f.pos = end;
        Ok(buf.len())
    }

    fn flush(&mut self) -> std::io::Result<()> {
        self.1.write()?;
        let mut f = self.0.lock().unwrap();
        f.synced = f.data.clone();
        Ok(())
    }
}

impl std::io::Seek for CutFile {
    fn seek(&mut self, pos: std::io::SeekFrom) -> std::io::Result<u64> {
        let mut f = self.0.lock().unwrap();
        let to = match pos {
            std::io::SeekFrom::Start(n) => n as i64,
            std::io::SeekFrom::End(n) => f.data.len() as i64 + n,
            std::io::SeekFrom::Current(n) => f.pos as i64 + n,
        };
        f.pos = usize::try_from(to).map_err(|_| std::io::Error::other("seek before start"))?;
        Ok(f.pos as u64)
    }
}

const STATIONS: u32 = 4;
const CHUNKS: u32 = 3;

/// The job of [`STATIONS`] stations sent to an agent recording through `power`, until the job
/// is over or the power goes; the reports the cell was told, and the recording's folder.
fn run_until_cut(power: &Arc<Power>, n: u64) -> (Vec<StationReport>, tempfile::TempDir) {
    let mut b = bench(&format!("power-cut-{n}"), Duration::from_secs(600));
    let dir = tempfile::tempdir().unwrap();
    let config = RecorderConfig {
        dir: Some(dir.path().to_path_buf()),
        ..Default::default()
    };
    let recorder = Recorder::start_on(
        Arc::new(CutStorage(power.clone())),
        &config,
        JobMetadata::default(),
        (std::path::Path::new("design.stl"), Vec::new()),
        Arc::new(asbuilt_core::design::shapes::cuboid(
            nalgebra::Point3::origin(),
            nalgebra::Point3::new(1.0, 1.0, 1.0),
        )),
        0.005,
    )
    .unwrap();
    let mut out = Fanout::new(&b.ports, (Some(recorder), None), &b.frames, 16, false);
    let mut held = HeldControl::default();
    let mut told = Vec::new();
    for station in 0..STATIONS {
        begin(&b.cell, station, CHUNKS);
        for seq in 0..CHUNKS {
            chunk(&b.cell, station, u64::from(seq), seq + 1 == CHUNKS);
        }
        end(&b.cell, station, CHUNKS);
        held.drain(&mut b.lifecycle, &mut out);
        // The results go out as the disk takes them; once the power is off, nothing more.
        let start = Instant::now();
        loop {
            out.publish_durable(false);
            told.extend(reports(&b.cell));
            if out.unpublished.is_empty() || power.is_off() {
                break;
            }
            assert!(start.elapsed() < Duration::from_secs(10), "cut {n}: stuck");
            std::thread::sleep(Duration::from_micros(200));
        }
        if power.is_off() {
            break;
        }
    }
    // The machine is dead: whatever the writer still had is gone with it.
    drop(out);
    (told, dir)
}

/// Every report the cell was told is in what survives the cut, so an agent started on it
/// calls none of those attempts interrupted and reports none of them again differently.
#[test]
fn a_power_cut_at_any_write_keeps_every_report_the_cell_was_told() {
    // The job without a cut: how many writes it takes, and what the cell is told.
    let whole = Power::new(u64::MAX);
    let (told, _) = run_until_cut(&whole, u64::MAX);
    assert_eq!(told.len(), STATIONS as usize);
    let writes = whole.writes.load(Ordering::SeqCst);
    // Cut points spread over the whole job, up to 300 of them (each write of it when fewer).
    let step = writes.div_ceil(300).max(1);
    eprintln!("{writes} writes in the job, cut every {step}");
    let mut told_some = 0;
    for n in (0..writes).step_by(step as usize) {
        let power = Power::new(n);
        let (told, dir) = run_until_cut(&power, n);
        power.leave_on_disk();
        told_some += usize::from(!told.is_empty());
        let folder = crate::resume::scan_folder(dir.path());
        let mut after = lifecycle(Duration::from_secs(600));
        let resumed = crate::resume::replay_job(&folder.files, &mut after);
        let recorded = resumed.as_ref().map_or(&[][..], |r| &r.recorded[..]);
        for r in &told {
            assert!(
                recorded
                    .iter()
                    .any(|x| asbuilt_protocol::codec::encode(x)
                        == asbuilt_protocol::codec::encode(r)),
                "cut at write {n} of {writes}: station {} attempt {} was told to the cell and \
                 is not on disk",
                r.station,
                r.attempt
            );
        }
        if let Some(resumed) = &resumed {
            for b in &resumed.open {
                assert!(
                    !told
                        .iter()
                        .any(|r| (r.station, r.attempt.max(1)) == (b.station, b.attempt.max(1))),
                    "cut at write {n}: station {} attempt {} would be called interrupted after \
                     the cell was told its report",
                    b.station,
                    b.attempt
                );
            }
        }
    }
    // The cuts fell both before and after reports went out.
    assert!(told_some > 0 && told_some < (writes / step) as usize);
}
