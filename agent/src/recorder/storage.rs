//! Where the recording's bytes go. A flush is a promise: once it returns, what was written
//! survives the agent being killed and the cell losing power, because the cell is told of a
//! result only after its record is flushed. The disk keeps that promise with `sync_data`;
//! tests put a storage in its place that keeps only what was synced when the power is "cut".

use std::fs::File;
use std::io::{BufWriter, Seek, SeekFrom, Write};
use std::path::Path;

/// Creates the recording's files.
pub trait Storage: Send + Sync {
    /// A new file at `path`; fails with `AlreadyExists` if there is one.
    fn create_new(&self, path: &Path) -> std::io::Result<Box<dyn StoredFile>>;
}

/// A recording file being written. `flush` returns once everything written is durable.
pub trait StoredFile: Write + Seek + Send {}

impl<T: Write + Seek + Send> StoredFile for T {}

/// The file system: buffered writes, and a flush that syncs the file's data to the disk.
pub struct Disk;

impl Storage for Disk {
    fn create_new(&self, path: &Path) -> std::io::Result<Box<dyn StoredFile>> {
        let file = File::create_new(path)?;
        // The new name is the folder's data: synced too, or a power cut could keep the file's
        // bytes and lose the file.
        if let Some(dir) = path.parent() {
            File::open(if dir.as_os_str().is_empty() {
                Path::new(".")
            } else {
                dir
            })?
            .sync_all()?;
        }
        Ok(Box::new(Synced(BufWriter::with_capacity(1 << 20, file))))
    }
}

/// A buffered file whose flush hands the buffer to the kernel and then waits for the disk.
struct Synced(BufWriter<File>);

impl Write for Synced {
    fn write(&mut self, buf: &[u8]) -> std::io::Result<usize> {
        self.0.write(buf)
    }

    fn flush(&mut self) -> std::io::Result<()> {
        self.0.flush()?;
        // The data, not the metadata: a file's size is data for `fdatasync`, so a reader
        // after a power cut finds every synced byte.
        self.0.get_ref().sync_data()
    }
}

impl Seek for Synced {
    fn seek(&mut self, pos: SeekFrom) -> std::io::Result<u64> {
        self.0.seek(pos)
    }
}
