//! Builds the C2M index of a design and prints its cost and query rates:
//! `index_probe [MESH m|mm | wall] [--cut]` (without a mesh: a generated 1,000,000-triangle
//! twisted column; `wall`: the study's wall, twelve triangles that every cut crosses).
use std::time::Instant;

use asbuilt_core::design::shapes::{study_wall, twisted_column};
use asbuilt_core::{C2mIndex, C2mParams, Closest};
use nalgebra::Point3;
use rand::{SeedableRng, seq::SliceRandom};
use rand_chacha::ChaCha8Rng;

#[path = "../benches/support/points.rs"]
mod points;

fn main() {
    let a: Vec<String> = std::env::args().collect();
    let design = if a.get(1).is_some_and(|m| m == "wall") {
        study_wall()
    } else if a.len() >= 3 && a[2] != "--cut" {
        asbuilt_io::read_design(a[1].as_ref(), a[2].parse().expect("m or mm")).expect("design")
    } else {
        twisted_column(0.15, 0.1, 1.2, 90.0, 2000, 250)
    };
    eprintln!("peak RSS after loading: {}", peak_rss());
    let t = Instant::now();
    let index = C2mIndex::build(&design, C2mParams::within(0.005)).unwrap();
    let build = t.elapsed().as_secs_f64();
    eprintln!("peak RSS after indexing: {}", peak_rss());
    let s = index.stats();
    println!(
        "{} triangles: built in {:.3} s, {:.1} MB ({:.0} B/triangle), {} cells of {:.3} mm, {} candidates ({:.1}/cell), {} BVH cells",
        s.triangles,
        build,
        s.bytes as f64 / 1e6,
        s.bytes as f64 / s.triangles as f64,
        s.cells,
        s.cell_size * 1e3,
        s.candidates,
        s.candidates as f64 / s.cells as f64,
        s.bvh_cells
    );
    let mut rng = ChaCha8Rng::seed_from_u64(42);
    let pts = points::noisy_surface_points(&design, 2_000_000);
    let mut out: Vec<Option<Closest>> = vec![None; pts.len()];
    for (name, shuffle) in [("scan order", false), ("shuffled", true)] {
        let mut p: Vec<Point3<f64>> = pts.clone();
        if shuffle {
            p.shuffle(&mut rng);
        }
        let mut rates = Vec::new();
        for _ in 0..5 {
            let t = Instant::now();
            index.query_batch(&p, &mut out);
            rates.push(p.len() as f64 / t.elapsed().as_secs_f64() / 1e6);
        }
        rates.sort_by(f64::total_cmp);
        println!("{name}: median {:.2} M points/s ({:?})", rates[2], rates);
    }
    if a.iter().any(|x| x == "--cut") {
        let (lo, hi) = index.z_range();
        for f in [0.3, 0.5, 0.77] {
            let h = lo + (hi - lo) * f;
            let t = Instant::now();
            let sec = index.section(h).unwrap();
            println!(
                "section at {h:.3}: {} triangles, {:.1} ms, {} B",
                sec.triangles(),
                t.elapsed().as_secs_f64() * 1e3,
                sec.bytes()
            );
            let t = Instant::now();
            let mut c = asbuilt_core::Cursor::default();
            let mut m = 0;
            for q in &pts {
                if index.query_cut(q, &mut c, &sec).is_some() {
                    m += 1;
                }
            }
            println!(
                "  cut queries (1 thread): {:.2} M/s, {m} matched",
                pts.len() as f64 / t.elapsed().as_secs_f64() / 1e6
            );
        }
    }
}

/// The process's peak resident memory so far (Linux), for the record.
fn peak_rss() -> String {
    std::fs::read_to_string("/proc/self/status")
        .ok()
        .and_then(|s| {
            s.lines()
                .find(|l| l.starts_with("VmHWM"))
                .map(|l| l[6..].trim().to_string())
        })
        .unwrap_or_else(|| "unknown".into())
}
