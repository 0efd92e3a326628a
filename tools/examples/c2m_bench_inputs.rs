//! Writes the inputs of `tools/bench/c2m_vs_cloudcompare.sh`, the same files for asbuilt and
//! CloudCompare: `c2m_bench_inputs OUT_DIR`.
//!
//! - `bunny_scan.ply`, `bunny_shuffled.ply`: 2 M points on the Stanford bunny with Gaussian noise
//!   (σ 0.5 mm per axis), in scan-like order and shuffled;
//! - `column.stl`: a generated 1,004,000-triangle twisted elliptical column (free-form), metres;
//! - `column_scan.ply`: 1 M noisy points on it in scan-like order.

use std::io::Write;
use std::path::Path;

use asbuilt_core::Units;
use asbuilt_core::design::shapes::twisted_column;
use nalgebra::Point3;
use rand::SeedableRng;
use rand::seq::SliceRandom;

#[path = "../../core/benches/support/points.rs"]
mod points;

fn write_ply(path: &Path, pts: &[Point3<f64>]) -> std::io::Result<()> {
    let mut f = std::io::BufWriter::new(std::fs::File::create(path)?);
    write!(
        f,
        "ply\nformat binary_little_endian 1.0\nelement vertex {}\nproperty double x\n\
         property double y\nproperty double z\nend_header\n",
        pts.len()
    )?;
    for p in pts {
        for c in [p.x, p.y, p.z] {
            f.write_all(&c.to_le_bytes())?;
        }
    }
    f.flush()
}

fn main() -> anyhow::Result<()> {
    let out = std::path::PathBuf::from(std::env::args().nth(1).unwrap_or("out/c2m-bench".into()));
    std::fs::create_dir_all(&out)?;
    let bunny = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../../shared/data/stanford-bunny/bun_zipper.ply");
    let design = asbuilt_io::read_design(&bunny, Units::Metres)?;
    let mut pts = points::noisy_surface_points(&design, 2_000_000);
    write_ply(&out.join("bunny_scan.ply"), &pts)?;
    pts.shuffle(&mut rand_chacha::ChaCha8Rng::seed_from_u64(7));
    write_ply(&out.join("bunny_shuffled.ply"), &pts)?;
    let column = twisted_column(0.15, 0.1, 1.2, 90.0, 2000, 250);
    asbuilt_sim::write_stl(&out.join("column.stl"), &column)?;
    // Points from the design as the STL stores it (f32), as both tools read it.
    let column = asbuilt_io::read_design(&out.join("column.stl"), Units::Metres)?;
    write_ply(
        &out.join("column_scan.ply"),
        &points::noisy_surface_points(&column, 1_000_000),
    )?;
    eprintln!("inputs in {}", out.display());
    Ok(())
}
