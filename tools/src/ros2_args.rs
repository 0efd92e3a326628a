//! `--ros2 BAG`: a ROS 2 bag as the scans of `inspect`, `pack` and `publish`, the same options
//! for each.

use std::path::{Path, PathBuf};

use anyhow::Result;
use asbuilt_io::scan::ScanFile;
use asbuilt_io::scan::ros2::{Ros2Options, load_windows};
use asbuilt_io::stations::{self, Station};
use clap::Args;

/// The options of a ROS 2 bag input.
#[derive(Args, Debug, Clone)]
pub struct Ros2Args {
    /// A ROS 2 bag as the scans: the folder `ros2 bag record` wrote, or one of its .mcap or .db3
    /// files. Each PointCloud2 of the cloud topic is a station (--stations groups them), placed
    /// by the bag's /tf_static and /tf at the cloud's stamp.
    #[arg(long, value_name = "BAG")]
    pub ros2: Option<PathBuf>,
    /// With --ros2: the PointCloud2 topic (default: the bag's only one).
    #[arg(long, value_name = "TOPIC", requires = "ros2")]
    pub cloud_topic: Option<String>,
    /// With --ros2: the design's frame in the bag's transform tree.
    #[arg(long, value_name = "FRAME", default_value = "world")]
    pub frame: String,
}

impl Default for Ros2Args {
    fn default() -> Self {
        Self {
            ros2: None,
            cloud_topic: None,
            frame: "world".into(),
        }
    }
}

impl Ros2Args {
    /// The bag's stations (`None` without --ros2): a cloud each, or the clouds of each window
    /// of `windows` (a TOML of `[[station]]` with `id`, `from` and `to`, seconds of the bag's
    /// clock).
    pub fn stations(&self, windows: Option<&Path>) -> Result<Option<Vec<Station>>> {
        let Some(bag) = &self.ros2 else {
            return Ok(None);
        };
        let stations = stations::of_ros2(bag, &self.options(windows)?)?;
        if stations.is_empty() {
            anyhow::bail!("{}: no station to inspect", bag.display());
        }
        Ok(Some(stations))
    }

    /// The bag as one scan file whose scans are its stations (`None` without --ros2).
    pub fn scan_file(&self, windows: Option<&Path>) -> Result<Option<ScanFile>> {
        let Some(path) = &self.ros2 else {
            return Ok(None);
        };
        Ok(Some(ScanFile::open_ros2(path, &self.options(windows)?)?))
    }

    fn options(&self, windows: Option<&Path>) -> Result<Ros2Options> {
        Ok(Ros2Options {
            cloud_topic: self.cloud_topic.clone(),
            frame: self.frame.clone(),
            stations: windows.map(load_windows).transpose()?,
        })
    }
}
