//! `deviations.ply`: design-frame points with their signed distance, as a binary PLY that
//! CloudCompare opens with `c2m` as a scalar field. Written as it goes, with bounded memory:
//! the body goes to a side file and the header, which needs the count, is written at the end.

use std::fs::File;
use std::io::{BufWriter, Write};
use std::path::{Path, PathBuf};

use anyhow::{Context, Result};
use asbuilt_protocol::{DeviationFlags, PointDeviation};

pub struct DeviationsPly {
    path: PathBuf,
    body_path: PathBuf,
    body: BufWriter<File>,
    count: u64,
    /// The same points as text with a header line, for tools that read ASCII.
    ascii: Option<BufWriter<File>>,
}

impl DeviationsPly {
    /// `ascii`: also write `deviations.txt` beside it, `//X Y Z C2M Triangle Station Feature
    /// Flags` then one point per line (CloudCompare reads the `//` line as column names).
    pub fn create(path: &Path, ascii: bool) -> Result<Self> {
        let body_path = path.with_extension("ply.body");
        let body = File::create(&body_path)
            .with_context(|| format!("cannot write {}", body_path.display()))?;
        let ascii = if ascii {
            let p = path.with_extension("txt");
            let mut w = BufWriter::with_capacity(
                1 << 20,
                File::create(&p).with_context(|| format!("cannot write {}", p.display()))?,
            );
            writeln!(w, "//X Y Z C2M Triangle Station Feature Flags")?;
            Some(w)
        } else {
            None
        };
        Ok(Self {
            path: path.to_path_buf(),
            body_path,
            body: BufWriter::with_capacity(1 << 20, body),
            count: 0,
            ascii,
        })
    }

    /// Appends the points that reached the design frame; rejected points are only counted.
    pub fn write(&mut self, station: u16, devs: &[PointDeviation]) -> Result<()> {
        for d in devs {
            if d.flags.contains(DeviationFlags::REJECTED) {
                continue;
            }
            let mut rec = [0u8; 8 * 3 + 4 + 4 + 2 + 1 + 1];
            for k in 0..3 {
                rec[8 * k..8 * k + 8].copy_from_slice(&d.position[k].to_le_bytes());
            }
            rec[24..28].copy_from_slice(&(d.distance as f32).to_le_bytes());
            rec[28..32].copy_from_slice(&d.triangle.to_le_bytes());
            rec[32..34].copy_from_slice(&station.to_le_bytes());
            rec[34] = d.feature;
            rec[35] = d.flags.0;
            self.body.write_all(&rec)?;
            if let Some(a) = &mut self.ascii {
                writeln!(
                    a,
                    "{:.6} {:.6} {:.6} {:.7} {} {station} {} {}",
                    d.position[0],
                    d.position[1],
                    d.position[2],
                    d.distance,
                    d.triangle,
                    d.feature,
                    d.flags.0
                )?;
            }
            self.count += 1;
        }
        Ok(())
    }

    pub fn finish(mut self) -> Result<u64> {
        if let Some(a) = &mut self.ascii {
            a.flush()?;
        }
        self.body.flush()?;
        drop(self.body);
        let mut out = BufWriter::new(
            File::create(&self.path)
                .with_context(|| format!("cannot write {}", self.path.display()))?,
        );
        write!(
            out,
            "ply\nformat binary_little_endian 1.0\n\
             comment asbuilt deviations: design frame, metres; c2m is the signed distance \
             (NaN: no match within the maximum distance)\n\
             element vertex {}\nproperty double x\nproperty double y\nproperty double z\n\
             property float c2m\nproperty uint triangle\nproperty ushort station\n\
             property uchar feature\nproperty uchar flags\nend_header\n",
            self.count
        )?;
        let mut body = File::open(&self.body_path)?;
        std::io::copy(&mut body, &mut out)?;
        out.flush()?;
        std::fs::remove_file(&self.body_path).ok();
        Ok(self.count)
    }
}
