//! ASTM E57 through the `e57` crate: several scans per file, each with an optional pose,
//! Cartesian or spherical coordinates, invalid-state flags and intensity.

use std::path::Path;

use super::error::{Context, Result, ScanError, bail};
use asbuilt_protocol::{ScanPoint, ScanPointFlags};
use e57::{CartesianCoordinate, E57Reader};
use nalgebra::{Isometry3, Quaternion, Translation3, UnitQuaternion, Vector3};

use super::{Batcher, PoseSource, ReadNotes, ScanInfo, Sink};

fn open(path: &Path) -> Result<E57Reader<std::io::BufReader<std::fs::File>>> {
    E57Reader::from_file(path).map_err(|e| {
        ScanError::Content(format!(
            "cannot read {} as E57: {e}. The file may be damaged (a CRC error means corrupt \
             pages) or not an E57 file",
            path.display()
        ))
    })
}

pub fn scans(path: &Path) -> Result<Vec<ScanInfo>> {
    let reader = open(path)?;
    let clouds = reader.pointclouds();
    if clouds.is_empty() {
        bail!(
            "{} is a valid E57 file with no point cloud in it",
            path.display()
        );
    }
    Ok(clouds
        .iter()
        .enumerate()
        .map(|(index, pc)| {
            // No pose element means the points are already in the file's frame.
            let pose = match &pc.transform {
                Some(t) => {
                    let q = UnitQuaternion::from_quaternion(Quaternion::new(
                        t.rotation.w,
                        t.rotation.x,
                        t.rotation.y,
                        t.rotation.z,
                    ));
                    let v = Vector3::new(t.translation.x, t.translation.y, t.translation.z);
                    (
                        Isometry3::from_parts(Translation3::from(v), q),
                        PoseSource::E57,
                    )
                }
                None => (Isometry3::identity(), PoseSource::FileFrame),
            };
            ScanInfo {
                index,
                name: pc
                    .name
                    .clone()
                    .filter(|n| !n.trim().is_empty())
                    .or_else(|| pc.guid.clone())
                    .unwrap_or_else(|| format!("scan {index}")),
                points: Some(pc.records),
                pose: Some(pose),
                offset: 0,
                first_line: 0,
            }
        })
        .collect())
}

pub fn stream(path: &Path, info: &ScanInfo, chunk: usize, sink: &mut Sink) -> Result<ReadNotes> {
    let mut reader = open(path)?;
    let pc = reader
        .pointclouds()
        .into_iter()
        .nth(info.index)
        .with_context(|| format!("{}: scan {} is gone", path.display(), info.index))?;
    let mut points = reader.pointcloud_simple(&pc).with_context(|| {
        format!(
            "cannot read the points of {} scan {}",
            path.display(),
            info.name
        )
    })?;
    // Local coordinates: the pose is applied by the caller, as a station pose.
    points.apply_pose(false);
    points.spherical_to_cartesian(true);
    let mut notes = ReadNotes::default();
    let mut out = Batcher::new(chunk, sink);
    for (n, p) in points.enumerate() {
        let p = p.with_context(|| {
            format!(
                "{} scan {:?}: point {n} cannot be read (the file is damaged or truncated)",
                path.display(),
                info.name
            )
        })?;
        let mut sp = match p.cartesian {
            // A return at the scanner's own centre is no measurement (as PTX writes misses).
            CartesianCoordinate::Valid { x, y, z } if !(x == 0.0 && y == 0.0 && z == 0.0) => {
                ScanPoint::new(x as f32, y as f32, z as f32)
            }
            _ => {
                notes.invalid += 1;
                let mut sp = ScanPoint::new(0.0, 0.0, 0.0);
                sp.flags = ScanPointFlags(ScanPointFlags::INVALID);
                sp
            }
        };
        // Intensity limits with min = max normalise to NaN.
        if let Some(i) = p.intensity.filter(|i| i.is_finite()) {
            sp.intensity = i;
        }
        out.push(sp)?;
    }
    out.finish()?;
    if info.points.is_some_and(|n| n > 0) && notes.invalid == info.points.unwrap_or(0) {
        bail!(
            "{} scan {:?}: none of its {} points is a measurement (every one is flagged invalid \
             or sits at the scanner's centre): the point data is damaged or was never filled",
            path.display(),
            info.name,
            notes.invalid
        );
    }
    Ok(notes)
}
