//! Reading a 20 M-point scan file must not hold it in memory. Generates a LAS file and a PTX
//! file of 20 M points each (written by our own streaming writers), then streams each back in
//! 64 k-point chunks and reports the peak resident memory of the read alone (the peak is reset
//! before reading through /proc/self/clear_refs) and the read rate.
//!
//! Run: `cargo bench -p asbuilt-tools --bench read_memory` (needs about 1.3 GB of free disk
//! in the temp folder; set POINTS to change the size).

use std::time::Instant;

use asbuilt_io::scan::write::{self, OutScan};
use asbuilt_io::scan::{DEFAULT_CHUNK, ScanFile};
use asbuilt_protocol::ScanPoint;
use nalgebra::Isometry3;

fn status_kib(field: &str) -> u64 {
    std::fs::read_to_string("/proc/self/status")
        .unwrap_or_default()
        .lines()
        .find(|l| l.starts_with(field))
        .and_then(|l| l.split_whitespace().nth(1))
        .and_then(|v| v.parse().ok())
        .unwrap_or(0)
}

fn main() {
    let n: u64 = std::env::var("POINTS")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(20_000_000);
    let dir = tempfile::tempdir().expect("temp dir");
    for ext in ["las", "ptx"] {
        let path = dir.path().join(format!("big.{ext}"));
        let t0 = Instant::now();
        let mut w = write::create(&path, n).expect("writer");
        let scan = OutScan {
            name: "big".into(),
            pose: Isometry3::translation(100.0, 200.0, 10.0),
            points: n,
        };
        w.write_scan(&scan, &mut |emit| {
            let mut chunk = Vec::with_capacity(DEFAULT_CHUNK);
            let mut i = 0u64;
            while i < n {
                chunk.clear();
                while chunk.len() < DEFAULT_CHUNK && i < n {
                    let a = i as f32 * 1e-5;
                    chunk.push(ScanPoint::new(
                        a.sin() * 20.0,
                        a.cos() * 20.0,
                        (i % 1000) as f32 * 0.003,
                    ));
                    i += 1;
                }
                emit(&chunk)?;
            }
            Ok(())
        })
        .expect("write");
        w.finish().expect("finish");
        let size = std::fs::metadata(&path).map(|m| m.len()).unwrap_or(0);
        eprintln!(
            "{ext}: wrote {n} points ({:.0} MB) in {:.1} s",
            size as f64 / 1e6,
            t0.elapsed().as_secs_f64()
        );

        let before = status_kib("VmRSS:");
        // Reset the peak so it measures the read alone.
        let _ = std::fs::write("/proc/self/clear_refs", "5");
        let t0 = Instant::now();
        let file = ScanFile::open(&path).expect("open");
        let mut count = 0u64;
        let mut checksum = 0f64;
        file.stream(0, DEFAULT_CHUNK, &mut |c| {
            count += c.len() as u64;
            checksum += c[0].xyz[2] as f64;
            Ok(())
        })
        .expect("read");
        let secs = t0.elapsed().as_secs_f64();
        let peak = status_kib("VmHWM:");
        assert_eq!(count, n);
        println!(
            "{ext}: read {count} points in {secs:.1} s ({:.2} M points/s); RSS before {} MiB, \
             peak during the read {} MiB (the file is {:.0} MB) [checksum {checksum:.1}]",
            count as f64 / secs / 1e6,
            before / 1024,
            peak / 1024,
            size as f64 / 1e6
        );
        std::fs::remove_file(&path).ok();
    }
}
