//! `asbuilt calibrate`: sphere targets with known centres, scanned from one or more stations,
//! give the transform the agent needs (`t_design_base` or `t_flange_scanner`).

use std::path::PathBuf;
use std::process::ExitCode;

use anyhow::{Context, Result, bail};
use asbuilt_core::calibration::rigid::{self, RigidFit};
use asbuilt_core::calibration::{matching, sphere};
use clap::{Args, ValueEnum};
use nalgebra::{Point3, UnitQuaternion};

use asbuilt_io::stations::{self, Station};
use asbuilt_io::targets::{self, Target};

#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum Solve {
    /// The robot base in the design frame. Targets in the design frame; station poses are the
    /// scanner in the robot base frame (or identity for a scanner on a tripod).
    DesignBase,
    /// The scanner on the flange. Targets in the robot base frame; station poses are the
    /// flange in the robot base frame.
    FlangeScanner,
}

impl Solve {
    fn key(self) -> &'static str {
        match self {
            Solve::DesignBase => "t_design_base",
            Solve::FlangeScanner => "t_flange_scanner",
        }
    }
}

#[derive(Args)]
pub struct CalibrateArgs {
    /// Targets file: [[target]] with id and position = [x, y, z] (metres; design frame for
    /// design-base, robot base frame for flange-scanner).
    #[arg(long)]
    targets: PathBuf,
    /// The spheres' radius, metres (a 145 mm sphere: 0.0725).
    #[arg(long)]
    radius: f64,
    /// Stations file with the scans of the targets and each station's pose.
    #[arg(long, conflicts_with = "files", required_unless_present = "files")]
    stations: Option<PathBuf>,
    /// Scan files that hold their poses (E57, PTX), instead of a stations file.
    files: Vec<PathBuf>,
    /// Which transform to estimate.
    #[arg(long, value_enum, default_value = "design-base")]
    solve: Solve,
    /// Solve the translation only, with the rotation given by --rotation-xyzw (default none):
    /// the fixed-orientation mode of a robot that keeps the scanner's orientation.
    #[arg(long)]
    fixed_orientation: bool,
    /// With --fixed-orientation: the known rotation as x,y,z,w.
    #[arg(
        long,
        value_delimiter = ',',
        allow_negative_numbers = true,
        requires = "fixed_orientation"
    )]
    rotation_xyzw: Option<Vec<f64>>,
    /// Distances between spheres must match those between their targets within this, metres.
    #[arg(long, default_value_t = 0.01)]
    match_tolerance: f64,
    /// A point within this of a sphere's surface belongs to it, metres (default 3 % of the
    /// radius, 1 to 5 mm).
    #[arg(long)]
    shell: Option<f64>,
    /// Leave a target out (repeatable), e.g. one the warnings named.
    #[arg(long)]
    exclude: Vec<String>,
    /// Where to write the calibration, a [calibration] table for agent.toml.
    #[arg(long, short, default_value = "calibration.toml")]
    out: PathBuf,
}

/// One sphere seen from one station and matched to a target.
struct Pair {
    target: usize,
    station: String,
    /// Where the sphere is, in the frame the unknown transform maps from.
    measured: Point3<f64>,
    /// Where the target is, in the frame it maps to.
    known: Point3<f64>,
    sigma_mm: f64,
    inliers: usize,
}

/// The spheres found in one station's scan and matched to targets, each paired with where the
/// target is, in the frame being solved for.
fn station_pairs(
    st: &Station,
    args: &CalibrateArgs,
    params: &sphere::DetectParams,
    known: &[Point3<f64>],
) -> Result<Vec<Pair>> {
    let mut pairs = Vec::new();
    let (pts, _) = st.open_scan()?.valid_points(st.scan_index)?;
    let found = sphere::detect(&pts, params);
    // Targets and spheres compare in one frame: the scanner's for the sphere centres, and
    // the targets as they are (distances do not depend on the frame).
    let centres: Vec<Point3<f64>> = found.iter().map(|f| f.centre).collect();
    let labels = matching::by_distances(&centres, known, args.match_tolerance);
    let matched = labels.iter().flatten().count();
    eprintln!(
        "station {}: {} points, {} sphere(s) of radius {} m found, {} matched to targets \
         (pose from {})",
        st.id,
        pts.len(),
        found.len(),
        args.radius,
        matched,
        st.pose_source
    );
    for (f, label) in found.iter().zip(&labels) {
        let Some(k) = *label else {
            eprintln!(
                "  sphere at {:.4}, {:.4}, {:.4} (scanner frame) matches no target",
                f.centre.x, f.centre.y, f.centre.z
            );
            continue;
        };
        let pose = st.t_design_scanner;
        let (measured, known_k) = match args.solve {
            Solve::DesignBase => (pose * f.centre, known[k]),
            Solve::FlangeScanner => (f.centre, pose.inverse() * known[k]),
        };
        pairs.push(Pair {
            target: k,
            station: st.id.clone(),
            measured,
            known: known_k,
            sigma_mm: f.centre_sigma.norm() * 1e3,
            inliers: f.inliers,
        });
    }
    Ok(pairs)
}

/// Prints the residuals and the fit, and returns the `[calibration]` line to write.
fn report_fit(args: &CalibrateArgs, targets: &[Target], pairs: &[Pair], fit: &RigidFit) -> String {
    println!(
        "{:<10} {:<14} {:>8} {:>12} {:>14}",
        "target", "station", "points", "centre σ mm", "residual mm"
    );
    for (p, r) in pairs.iter().zip(&fit.residuals) {
        println!(
            "{:<10} {:<14} {:>8} {:>12.3} {:>14.3}",
            targets[p.target].id,
            p.station,
            p.inliers,
            p.sigma_mm,
            r * 1e3
        );
    }
    let t = fit.transform.translation.vector;
    let q = fit.transform.rotation.quaternion().coords;
    let s = fit.translation_sigma * 1e3;
    println!(
        "{}: translation {:.5}, {:.5}, {:.5} m (σ {:.2}, {:.2}, {:.2} mm), rotation {:.3}°; RMS \
         {:.3} mm over {} spheres",
        args.solve.key(),
        t.x,
        t.y,
        t.z,
        s.x,
        s.y,
        s.z,
        fit.transform.rotation.angle().to_degrees(),
        fit.rms * 1e3,
        pairs.len()
    );
    format!(
        "# Written by asbuilt calibrate from {} spheres of radius {} m ({}).\n\
         # RMS residual {:.3} mm; translation σ {:.2}, {:.2}, {:.2} mm at the targets' centroid.\n\
         # Copy the line below into the [calibration] table of agent.toml.\n\
         [calibration]\n{} = {{ translation = [{}, {}, {}], rotation_xyzw = [{}, {}, {}, {}] }}\n",
        pairs.len(),
        args.radius,
        if args.fixed_orientation {
            "translation only"
        } else {
            "6 degrees of freedom"
        },
        fit.rms * 1e3,
        s.x,
        s.y,
        s.z,
        args.solve.key(),
        t.x,
        t.y,
        t.z,
        q.x,
        q.y,
        q.z,
        q.w
    )
}

/// Warns of every target that does not fit the others; true when there is one.
fn warn_misfits(targets: &[Target], pairs: &[Pair], fit: &RigidFit) -> bool {
    for &(k, r) in &fit.misfits {
        let seen_from: Vec<&str> = pairs
            .iter()
            .filter(|p| p.target == k)
            .map(|p| p.station.as_str())
            .collect();
        eprintln!(
            "warning: target {} (stations {}) does not fit: {:.1} mm off the fit made without \
             it. Check its coordinates and that the right sphere was scanned; leave it out \
             with --exclude {}",
            targets[k].id,
            seen_from.join(", "),
            r * 1e3,
            targets[k].id
        );
    }
    !fit.misfits.is_empty()
}

pub fn run(args: CalibrateArgs) -> Result<ExitCode> {
    if !(args.radius > 0.0 && args.radius.is_finite()) {
        bail!(
            "--radius must be a positive number of metres, got {}",
            args.radius
        );
    }
    let rotation = match &args.rotation_xyzw {
        None => UnitQuaternion::identity(),
        Some(r) if r.len() == 4 => {
            asbuilt_core::frames::isometry([0.0; 3], [r[0], r[1], r[2], r[3]])
                .context("--rotation-xyzw")?
                .rotation
        }
        Some(r) => bail!(
            "--rotation-xyzw takes four numbers x,y,z,w, got {}",
            r.len()
        ),
    };
    let targets = targets::load(&args.targets, &args.exclude)?;
    let stations: Vec<Station> = match &args.stations {
        Some(p) => stations::load(p)?,
        None => stations::from_files(&args.files)?,
    };
    let mut params = sphere::DetectParams::new(args.radius);
    if let Some(s) = args.shell {
        params.shell = s;
    }
    let known: Vec<Point3<f64>> = targets.iter().map(|t| Point3::from(t.position)).collect();

    let mut pairs: Vec<Pair> = Vec::new();
    for st in &stations {
        pairs.extend(station_pairs(st, &args, &params, &known)?);
    }
    let seen: std::collections::BTreeSet<usize> = pairs.iter().map(|p| p.target).collect();
    let missing: Vec<&str> = (0..targets.len())
        .filter(|k| !seen.contains(k))
        .map(|k| targets[k].id.as_str())
        .collect();
    if !missing.is_empty() {
        eprintln!(
            "warning: target(s) not found in any scan: {}",
            missing.join(", ")
        );
    }
    let from: Vec<Point3<f64>> = pairs.iter().map(|p| p.measured).collect();
    let to: Vec<Point3<f64>> = pairs.iter().map(|p| p.known).collect();
    let groups: Vec<usize> = pairs.iter().map(|p| p.target).collect();
    let fit: RigidFit = if args.fixed_orientation {
        rigid::fit_translation_grouped(&from, &to, &groups, rotation)
    } else {
        rigid::fit_grouped(&from, &to, &groups)
    }
    .map_err(|e| {
        let ids: Vec<&str> = seen.iter().map(|&k| targets[k].id.as_str()).collect();
        anyhow::anyhow!("cannot calibrate from targets {}: {e}", ids.join(", "))
    })?;

    let text = report_fit(&args, &targets, &pairs, &fit);
    std::fs::write(&args.out, text)
        .with_context(|| format!("cannot write {}", args.out.display()))?;
    eprintln!("wrote {}", args.out.display());
    if warn_misfits(&targets, &pairs, &fit) {
        return Ok(ExitCode::from(1));
    }
    Ok(ExitCode::SUCCESS)
}
