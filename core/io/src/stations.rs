//! `stations.toml`: which scan was taken where, `p_design = R(rotation_xyzw) · p_scan +
//! translation`; and Stanford's Scanalyze `.conf` turned into one.

use std::path::{Component, Path, PathBuf};

use nalgebra::{Isometry3, UnitQuaternion};
use serde::{Deserialize, Serialize};

use crate::IoError;
use crate::scan::ScanFile;

/// Why stations could not be read: the file itself, or what its entries say.
#[derive(Debug, thiserror::Error)]
pub enum StationsError {
    /// The stations file (or the `.conf`) cannot be read, or is not what its format says.
    #[error(transparent)]
    File(#[from] IoError),
    /// Entries with problems, every one listed, each saying what to change.
    #[error("{origin}:\n  - {}", problems.join("\n  - "))]
    Entries {
        /// The stations file, or the flags the stations came from.
        origin: String,
        /// One line per problem.
        problems: Vec<String>,
    },
}

/// A stations file as written: its `[[station]]` tables.
#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct StationsFile {
    /// One entry per scan position.
    pub station: Vec<StationEntry>,
}

/// One `[[station]]` table.
#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct StationEntry {
    /// The station's name in reports.
    pub id: String,
    /// A scan file (E57, LAS/LAZ, PTX, PLY, XYZ); relative paths are relative to the stations
    /// file.
    pub scan: PathBuf,
    /// Which scan of a file that holds several (E57, PTX), from 0. Without it every scan of
    /// the file becomes a station, named `id/scan name`.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub scan_index: Option<usize>,
    /// Metres. With `rotation_xyzw`, the pose; without both, the pose the file holds.
    pub translation: Option<[f64; 3]>,
    /// Unit quaternion, scalar last.
    pub rotation_xyzw: Option<[f64; 4]>,
    /// One-sigma position uncertainty of the station, metres.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub position_sigma: Option<f64>,
}

impl StationEntry {
    /// A station of every scan in `scan`, named after the file, with the poses the file holds.
    pub fn of_file(scan: &Path) -> Self {
        Self {
            id: scan
                .file_stem()
                .map(|s| s.to_string_lossy().into_owned())
                .unwrap_or_else(|| "scan".into()),
            scan: scan.to_path_buf(),
            scan_index: None,
            translation: None,
            rotation_xyzw: None,
            position_sigma: None,
        }
    }
}

/// A station ready to inspect.
#[derive(Debug, Clone)]
pub struct Station {
    /// Its name in reports: the entry's id, with the scan's name for a file of several scans.
    pub id: String,
    /// The scan file, resolved against the stations file's folder.
    pub scan: PathBuf,
    /// Which scan of the file.
    pub scan_index: usize,
    /// Where the pose came from, for the log.
    pub pose_source: String,
    /// The scanner's pose in the design frame.
    pub t_design_scanner: Isometry3<f64>,
    /// The pose as written, so a publisher sends exactly the numbers `inspect` used.
    pub translation: [f64; 3],
    /// The rotation as written, scalar last.
    pub rotation_xyzw: [f64; 4],
    /// One-sigma position uncertainty, metres.
    pub position_sigma: f64,
    /// The ROS 2 bag `scan` names, when it is one ([`of_ros2`]).
    pub bag: Option<std::sync::Arc<crate::scan::ros2::Ros2Bag>>,
}

impl Station {
    /// A warning when this station's scan (its corners `lo`, `hi`) and a design `design_size`
    /// across differ in size by more than 30×: the units are almost certainly wrong.
    pub fn size_mismatch(
        &self,
        design_size: f64,
        (lo, hi): (nalgebra::Point3<f64>, nalgebra::Point3<f64>),
    ) -> Option<String> {
        let scan_size = (hi - lo).norm();
        if !(scan_size.is_finite() && design_size > 0.0 && scan_size > 0.0) {
            return None;
        }
        let ratio = design_size / scan_size;
        (!(1.0 / 30.0..=30.0).contains(&ratio)).then(|| {
            format!(
                "station {}: the design spans {design_size:.3} m but the scan spans \
                 {scan_size:.3} m ({}× apart): check --units (a millimetre design declared as \
                 m is 1000× too big)",
                self.id,
                ratio.max(1.0 / ratio).round()
            )
        })
    }

    /// Opens the station's scan: its file, or the bag it comes from.
    pub fn open_scan(&self) -> Result<crate::scan::ScanFile, IoError> {
        match &self.bag {
            Some(bag) => Ok(crate::scan::ScanFile::of_ros2(&self.scan, bag.clone())),
            None => crate::scan::ScanFile::open(&self.scan),
        }
    }
}

/// A station's position uncertainty when its entry gives none: the robot's pose accuracy.
pub const DEFAULT_POSITION_SIGMA: f64 = 1e-3;

/// Reads and checks a stations file, listing every problem at once.
pub fn load(path: &Path) -> Result<Vec<Station>, StationsError> {
    let text = read_text(path, "stations")?;
    let file: StationsFile = toml::from_str(&text).map_err(|e| IoError::Malformed {
        path: path.to_path_buf(),
        format: "a stations file",
        what: format!(
            "{e}\nexpected [[station]] tables with id, scan, translation = [x, y, z] and \
             rotation_xyzw = [x, y, z, w]"
        ),
    })?;
    let base = path.parent().unwrap_or(Path::new("."));
    resolve(file, base, &path.display().to_string())
}

/// A `[[station]]` entry checked: its scan file opened, its pose (if given) valid, and the
/// scans of the file it names. `None` when a problem was recorded.
struct Entry {
    scan: PathBuf,
    sigma: f64,
    given: Option<([f64; 3], [f64; 4])>,
    file: ScanFile,
    indices: Vec<usize>,
}

fn check_entry(s: &StationEntry, base: &Path, problems: &mut Vec<String>) -> Option<Entry> {
    let scan = if s.scan.is_absolute() {
        s.scan.clone()
    } else {
        base.join(&s.scan)
    };
    let sigma = s.position_sigma.unwrap_or(DEFAULT_POSITION_SIGMA);
    if !(sigma >= 0.0 && sigma.is_finite()) {
        problems.push(format!(
            "station {:?}: position_sigma must be >= 0 metres",
            s.id
        ));
    }
    let given = match (s.translation, s.rotation_xyzw) {
        (Some(t), Some(r)) => Some((t, r)),
        (None, None) => None,
        _ => {
            problems.push(format!(
                "station {:?}: give both translation = [x, y, z] (metres) and \
             rotation_xyzw = [x, y, z, w], or neither to use the file's pose",
                s.id
            ));
            return None;
        }
    };
    if let Some((t, r)) = given
        && let Err(e) = asbuilt_core::frames::isometry(t, r)
    {
        problems.push(format!("station {:?}: {e}", s.id));
    }
    let file = match ScanFile::open(&scan) {
        Ok(f) => f,
        Err(e) => {
            problems.push(format!("station {:?}: {e}", s.id));
            return None;
        }
    };
    let indices: Vec<usize> = match s.scan_index {
        Some(i) if i < file.scans.len() => vec![i],
        Some(i) => {
            problems.push(format!(
                "station {:?}: scan_index {i}, but {} holds {} scan(s) (0 to {})",
                s.id,
                scan.display(),
                file.scans.len(),
                file.scans.len() - 1
            ));
            return None;
        }
        None => (0..file.scans.len()).collect(),
    };
    if given.is_some() && indices.len() > 1 {
        problems.push(format!(
            "station {:?}: {} holds {} scans and one pose is given: add scan_index to say \
         which scan the pose is for",
            s.id,
            scan.display(),
            indices.len()
        ));
        return None;
    }
    Some(Entry {
        scan,
        sigma,
        given,
        file,
        indices,
    })
}

/// The stations of `file`, scan paths resolved against `base`; `origin` names where they came
/// from in an error, which lists every problem at once.
pub fn resolve(
    file: StationsFile,
    base: &Path,
    origin: &str,
) -> Result<Vec<Station>, StationsError> {
    let mut problems = Vec::new();
    let mut out = Vec::new();
    let mut seen = std::collections::HashSet::new();
    if file.station.is_empty() {
        problems.push("no [[station]] entries".to_string());
    }
    for s in file.station {
        if !seen.insert(s.id.clone()) {
            problems.push(format!("station {:?} is listed twice", s.id));
        }
        let Some(Entry {
            scan,
            sigma,
            given,
            file,
            indices,
        }) = check_entry(&s, base, &mut problems)
        else {
            continue;
        };
        for i in indices {
            let info = &file.scans[i];
            let id = if file.scans.len() > 1 && s.scan_index.is_none() {
                format!("{}/{}", s.id, info.name)
            } else {
                s.id.clone()
            };
            let (t, r, source) = match (given, info.pose) {
                (Some((t, r)), _) => (t, r, origin.to_string()),
                (None, Some((pose, src))) => {
                    let v = pose.translation.vector;
                    let q = pose.rotation.quaternion().coords;
                    (
                        [v.x, v.y, v.z],
                        [q.x, q.y, q.z, q.w],
                        format!("{} in {}", src.describe(), scan.display()),
                    )
                }
                (None, None) => {
                    problems.push(format!(
                        "station {:?} has no pose: give translation = [x, y, z] (metres) and \
                         rotation_xyzw = [x, y, z, w], or use a file that holds its pose (E57, \
                         PTX, LAS)",
                        s.id
                    ));
                    continue;
                }
            };
            let pose = match asbuilt_core::frames::isometry(t, r) {
                Ok(p) => p,
                Err(e) => {
                    problems.push(format!("station {id:?}: {e}"));
                    continue;
                }
            };
            out.push(Station {
                id,
                scan: scan.clone(),
                scan_index: i,
                pose_source: source,
                t_design_scanner: pose,
                translation: t,
                rotation_xyzw: r,
                position_sigma: sigma,
                bag: None,
            });
        }
    }
    if !problems.is_empty() {
        return Err(StationsError::Entries {
            origin: origin.to_string(),
            problems,
        });
    }
    Ok(out)
}

/// Stations from scan files that hold their poses: every scan of every file, in order.
pub fn from_files(files: &[PathBuf]) -> Result<Vec<Station>, StationsError> {
    let file = StationsFile {
        station: files.iter().map(|f| StationEntry::of_file(f)).collect(),
    };
    resolve(file, Path::new("."), "scan files")
}

/// The stations of one scan file given on the command line (`--scan`): every scan in it at
/// `pose` (translation, rotation x,y,z,w) when one is given, else at the poses the file holds;
/// the robot's pose accuracy as their uncertainty.
pub fn of_scan(
    scan: &Path,
    pose: Option<([f64; 3], [f64; 4])>,
) -> Result<Vec<Station>, StationsError> {
    let file = StationsFile {
        station: vec![StationEntry {
            translation: pose.map(|p| p.0),
            rotation_xyzw: pose.map(|p| p.1),
            position_sigma: Some(DEFAULT_POSITION_SIGMA),
            ..StationEntry::of_file(scan)
        }],
    };
    resolve(file, Path::new("."), "--scan")
}

/// The stations of a ROS 2 bag (`--ros2`): each at the pose its bag's transform tree gives its
/// first cloud, the robot's pose accuracy as their uncertainty. A station the tree cannot place
/// keeps its place in the list, at no pose, and fails with the tree's reason when its scan is
/// read, so that the other stations go on.
pub fn of_ros2(
    path: &Path,
    options: &crate::scan::ros2::Ros2Options,
) -> Result<Vec<Station>, IoError> {
    let file = crate::scan::ScanFile::open_ros2(path, options)?;
    let bag = file.bag.clone().expect("a bag's scan file");
    let scans = file.scans;
    Ok(scans
        .into_iter()
        .map(|info| {
            let (pose, source) = match info.pose {
                Some((p, src)) => (p, src.describe().to_string()),
                None => (
                    nalgebra::Isometry3::identity(),
                    format!(
                        "nowhere ({})",
                        bag.pose_error(info.index).unwrap_or_default()
                    ),
                ),
            };
            let v = pose.translation.vector;
            let q = pose.rotation.quaternion().coords;
            let (translation, rotation) = ([v.x, v.y, v.z], [q.x, q.y, q.z, q.w]);
            Station {
                id: info.name,
                scan: path.to_path_buf(),
                scan_index: info.index,
                pose_source: source,
                // The pose as its numbers make it, as `publish` and `pack` send it: a bag
                // inspected gives the bits of the bag packed and reported.
                t_design_scanner: asbuilt_core::frames::isometry(translation, rotation)
                    .unwrap_or(pose),
                translation,
                rotation_xyzw: rotation,
                position_sigma: DEFAULT_POSITION_SIGMA,
                bag: Some(bag.clone()),
            }
        })
        .collect())
}

/// Converts a Stanford/Scanalyze `.conf` (`bmesh FILE tx ty tz qx qy qz qw`, where
/// `p_mesh = R(q)ᵀ · p_scan + t`) into stations. Scan paths are written relative to `out_dir`.
pub fn from_conf(conf: &Path, out_dir: &Path) -> Result<StationsFile, IoError> {
    let text = read_text(conf, "Scanalyze .conf")?;
    let malformed = |what: String| IoError::Malformed {
        path: conf.to_path_buf(),
        format: "a Scanalyze .conf",
        what,
    };
    let dir = conf.parent().unwrap_or(Path::new("."));
    let mut station = Vec::new();
    for (n, line) in text.lines().enumerate() {
        let f: Vec<&str> = line.split_whitespace().collect();
        if f.first() != Some(&"bmesh") {
            continue; // `camera` lines are a viewpoint, not a station
        }
        if f.len() != 9 {
            return Err(malformed(format!(
                "line {}: expected `bmesh FILE tx ty tz qx qy qz qw`",
                n + 1
            )));
        }
        let nums: Vec<f64> = f[2..]
            .iter()
            .map(|s| s.parse::<f64>())
            .collect::<Result<_, _>>()
            .map_err(|e| malformed(format!("line {}: {e}", n + 1)))?;
        // The file's rotation maps mesh to scan; the station needs scan to mesh: its conjugate.
        let q = UnitQuaternion::from_quaternion(nalgebra::Quaternion::new(
            nums[6], nums[3], nums[4], nums[5],
        ))
        .conjugate();
        let c = q.quaternion().coords; // (x, y, z, w)
        let scan = dir.join(f[1]);
        station.push(StationEntry {
            scan_index: None,
            id: Path::new(f[1])
                .file_stem()
                .map(|s| s.to_string_lossy().into_owned())
                .unwrap_or_else(|| f[1].to_string()),
            scan: relative_to(&scan, out_dir),
            translation: Some([nums[0], nums[1], nums[2]]),
            rotation_xyzw: Some([c.x, c.y, c.z, c.w]),
            position_sigma: None,
        });
    }
    if station.is_empty() {
        return Err(malformed("no `bmesh` lines".into()));
    }
    Ok(StationsFile { station })
}

/// A text file read whole; `kind` names it when it is not there.
fn read_text(path: &Path, kind: &'static str) -> Result<String, IoError> {
    IoError::require_file(path, kind)?;
    std::fs::read_to_string(path).map_err(|source| IoError::Open {
        path: path.to_path_buf(),
        source,
    })
}

/// `target` as seen from `dir`, when both can be resolved; otherwise `target` unchanged.
fn relative_to(target: &Path, dir: &Path) -> PathBuf {
    let (Ok(t), Ok(d)) = (std::fs::canonicalize(target), std::fs::canonicalize(dir)) else {
        return target.to_path_buf();
    };
    let tc: Vec<Component> = t.components().collect();
    let dc: Vec<Component> = d.components().collect();
    let common = tc.iter().zip(&dc).take_while(|(a, b)| a == b).count();
    let mut out = PathBuf::new();
    for _ in common..dc.len() {
        out.push("..");
    }
    for c in &tc[common..] {
        out.push(c);
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_problem_of_a_stations_file_is_listed_at_once() {
        let dir = tempfile::tempdir().unwrap();
        std::fs::write(dir.path().join("a.xyz"), "0 0 0\n1 0 0\n").unwrap();
        let path = dir.path().join("stations.toml");
        std::fs::write(
            &path,
            "[[station]]\nid = \"a\"\nscan = \"a.xyz\"\ntranslation = [0, 0, 0]\n\
             [[station]]\nid = \"a\"\nscan = \"a.xyz\"\nposition_sigma = -1\n\
             [[station]]\nid = \"b\"\nscan = \"gone.xyz\"\n",
        )
        .unwrap();
        let Err(StationsError::Entries { origin, problems }) = load(&path) else {
            panic!("a stations file with five problems was accepted");
        };
        assert_eq!(origin, path.display().to_string());
        let expected = [
            "station \"a\": give both translation",
            "station \"a\" is listed twice",
            "station \"a\": position_sigma must be >= 0",
            "station \"a\" has no pose",
            "station \"b\": cannot open scan file",
        ];
        assert_eq!(problems.len(), expected.len(), "{problems:#?}");
        for (problem, start) in problems.iter().zip(expected) {
            assert!(problem.starts_with(start), "{problem}");
        }
        let e = load(&dir.path().join("nowhere.toml"))
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("stations file") && e.contains("does not exist"),
            "{e}"
        );
    }

    #[test]
    fn a_conf_becomes_stations_with_the_inverse_rotation_and_relative_scans() {
        let dir = tempfile::tempdir().unwrap();
        let conf = dir.path().join("scans").join("bun.conf");
        std::fs::create_dir(conf.parent().unwrap()).unwrap();
        // A quarter turn about z that takes mesh to scan; a station takes scan to mesh.
        let h = std::f64::consts::FRAC_1_SQRT_2;
        std::fs::write(
            &conf,
            format!("camera 0 0 1 0 0 0 1\nbmesh bun000.ply 0.1 0.2 0.3 0 0 {h} {h}\n"),
        )
        .unwrap();
        std::fs::write(dir.path().join("scans/bun000.ply"), "").unwrap();
        let file = from_conf(&conf, dir.path()).unwrap();
        assert_eq!(file.station.len(), 1);
        let s = &file.station[0];
        assert_eq!(s.id, "bun000");
        assert_eq!(s.scan, Path::new("scans/bun000.ply"));
        assert_eq!(s.translation, Some([0.1, 0.2, 0.3]));
        let [x, y, z, w] = s.rotation_xyzw.unwrap();
        assert_eq!([x, y], [0.0, 0.0]);
        assert!((z + h).abs() < 1e-15 && (w - h).abs() < 1e-15, "{z} {w}");

        std::fs::write(&conf, "bmesh bun000.ply 0.1 0.2 0.3\n").unwrap();
        let e = from_conf(&conf, dir.path()).unwrap_err().to_string();
        assert!(
            e.contains("bun.conf") && e.contains("line 1: expected `bmesh"),
            "{e}"
        );
    }
}
