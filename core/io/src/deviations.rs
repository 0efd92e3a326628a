//! `deviations.ply`: design-frame points with their signed distance, as a binary PLY that
//! CloudCompare opens with `c2m` as a scalar field. Written as it goes, with bounded memory:
//! the body goes to a side file and the header, which needs the count, is written at the end.

use std::fs::File;
use std::io::{BufWriter, Write};
use std::path::Path;

use asbuilt_protocol::{DeviationFlags, PointDeviation};

use crate::IoError;
use crate::ply::{PlyWriter, Property, Scalar, point_columns};

/// The columns after the point's.
const DEVIATION: [Property; 5] = [
    Property::new("c2m", Scalar::F32),
    Property::new("triangle", Scalar::U32),
    Property::new("station", Scalar::U16),
    Property::new("feature", Scalar::U8),
    Property::new("flags", Scalar::U8),
];

/// The deviations of an inspection as `deviations.ply` (and `deviations.txt` when asked):
/// position, signed distance, triangle, station, feature and flags per point.
pub struct DeviationsPly {
    ply: PlyWriter,
    /// The same points as text with a header line, for tools that read ASCII.
    ascii: Option<(std::path::PathBuf, BufWriter<File>)>,
}

impl DeviationsPly {
    /// `ascii`: also write `deviations.txt` beside it, `//X Y Z C2M Triangle Station Feature
    /// Flags` then one point per line (CloudCompare reads the `//` line as column names).
    pub fn create(path: &Path, ascii: bool) -> Result<Self, IoError> {
        let ply = PlyWriter::create(
            path,
            "asbuilt deviations: design frame, metres; c2m is the signed distance (NaN: no \
             match within the maximum distance)",
            &point_columns(&DEVIATION),
            None,
        )?;
        let ascii = if ascii {
            let p = path.with_extension("txt");
            let file = File::create(&p).map_err(|source| IoError::Open {
                path: p.clone(),
                source,
            })?;
            let mut w = BufWriter::with_capacity(1 << 20, file);
            writeln!(w, "//X Y Z C2M Triangle Station Feature Flags").map_err(|e| write(&p, e))?;
            Some((p, w))
        } else {
            None
        };
        Ok(Self { ply, ascii })
    }

    /// Appends the points that reached the design frame; rejected points are only counted.
    pub fn write(&mut self, station: u16, devs: &[PointDeviation]) -> Result<(), IoError> {
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
            self.ply.record(&rec)?;
            if let Some((p, a)) = &mut self.ascii {
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
                )
                .map_err(|e| write(p, e))?;
            }
        }
        Ok(())
    }

    /// Completes both files; returns the points written.
    pub fn finish(self) -> Result<u64, IoError> {
        if let Some((p, mut a)) = self.ascii {
            a.flush().map_err(|e| write(&p, e))?;
        }
        self.ply.finish()
    }
}

fn write(path: &Path, source: std::io::Error) -> IoError {
    IoError::Write {
        path: path.to_path_buf(),
        source,
    }
}
