//! C2M throughput: 2 M noisy points against the 69,451-triangle Stanford bunny, the job the
//! brief's peer figures were measured on (CloudCompare 0.57 M/s, Open3D 0.49 M/s, 2 cores).
//!
//! Points are taken on the surface and offset by Gaussian noise (σ 0.5 mm), in scan-like order:
//! consecutive points lie close together, as consecutive points of a scan line do; and the same
//! points shuffled (a merged or reference cloud). Beside it, parry's `TriMesh` (a BVH with
//! pseudo-normals) answers the same points on the same cores. Also: the index's build, and the
//! section that a new printed height needs, on the bunny and on a generated 1,004,000-triangle
//! free-form column; and coverage's line of sight, ours against parry's ray cast.
//!
//! Run: `cargo bench -p asbuilt-core --bench c2m`

use std::path::Path;
use std::time::Instant;

use asbuilt_core::design::shapes::twisted_column;
use asbuilt_core::station::{InspectParams, StationInspector};
use asbuilt_core::{C2mIndex, C2mParams, Closest, Design, Units};
use asbuilt_protocol::{PointDeviation, ScanPoint};
use criterion::{Criterion, Throughput, criterion_group, criterion_main};
use nalgebra::Isometry3;

const POINTS: usize = 2_000_000;

#[path = "support/points.rs"]
mod points;
use points::noisy_surface_points;

fn bench(c: &mut Criterion) {
    let mesh = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../../shared/data/stanford-bunny/bun_zipper.ply");
    let design =
        asbuilt_io::read_design(&mesh, Units::Metres).expect("bunny mesh in ../shared/data");
    let t0 = Instant::now();
    let index = C2mIndex::build(&design, C2mParams::within(0.005)).unwrap();
    let s = index.stats();
    eprintln!(
        "index: {} triangles, {} cells of {:.3} mm, {} candidates, {:.0} MB, built in {:.2} s",
        s.triangles,
        s.cells,
        s.cell_size * 1e3,
        s.candidates,
        s.bytes as f64 / 1e6,
        t0.elapsed().as_secs_f64()
    );
    let points = noisy_surface_points(&design, POINTS);
    let mut out: Vec<Option<Closest>> = vec![None; points.len()];

    let mut g = c.benchmark_group("c2m_bunny_2M");
    g.sample_size(10);
    g.throughput(Throughput::Elements(points.len() as u64));
    g.bench_function("query_batch", |b| {
        b.iter(|| index.query_batch(&points, &mut out))
    });
    let mut shuffled = points.clone();
    {
        use rand::SeedableRng;
        use rand::seq::SliceRandom;
        shuffled.shuffle(&mut rand_chacha::ChaCha8Rng::seed_from_u64(7));
    }
    g.bench_function("query_batch_shuffled", |b| {
        b.iter(|| index.query_batch(&shuffled, &mut out))
    });

    // parry's triangle mesh on the same points and cores, for the ratio: its BVH projection
    // with pseudo-normals (the sign) and the same maximum distance.
    let t0 = Instant::now();
    let trimesh = parry_bunny(&design);
    eprintln!(
        "parry TriMesh (BVH, pseudo-normals) built in {:.2} s",
        t0.elapsed().as_secs_f64()
    );
    let mut projected: Vec<Option<(f64, bool)>> = vec![None; points.len()];
    g.bench_function("parry_trimesh", |b| {
        b.iter(|| parry_project(&trimesh, &points, &mut projected))
    });

    // The full per-station path: validation, transform, C2M, deviations and statistics.
    let scan: Vec<ScanPoint> = points
        .iter()
        .map(|p| ScanPoint::new(p.x as f32, p.y as f32, p.z as f32))
        .collect();
    let mut devs = vec![PointDeviation::default(); 1 << 16];
    // The same points shuffled: the inspector queries a chunk in no spatial order along a
    // Morton curve.
    let scan_shuffled: Vec<ScanPoint> = shuffled
        .iter()
        .map(|p| ScanPoint::new(p.x as f32, p.y as f32, p.z as f32))
        .collect();
    for (name, scan) in [
        ("station_inspector", &scan),
        ("station_inspector_shuffled", &scan_shuffled),
    ] {
        g.bench_function(name, |b| {
            b.iter(|| {
                let mut st = StationInspector::new(
                    &index,
                    Isometry3::identity(),
                    InspectParams::with_tolerance(0.005),
                );
                for chunk in scan.chunks(1 << 16) {
                    st.process(chunk, &mut devs[..chunk.len()]);
                }
                st.tally().stats.count()
            })
        });
    }
    g.finish();

    line_of_sight(c, &design, &index, &trimesh, &points[..200_000]);
    design_index(c, &design, &index);

    // Brute force on a sample, for the ratio (every triangle per point).
    let sample = &points[..2_000];
    let t = Instant::now();
    for p in sample {
        std::hint::black_box(index.brute_force(p));
    }
    let bf = sample.len() as f64 / t.elapsed().as_secs_f64();
    eprintln!("brute force (1 core): {:.0} points/s", bf);
}

fn parry_bunny(design: &Design) -> parry3d_f64::shape::TriMesh {
    use parry3d_f64::math::Vector;
    use parry3d_f64::shape::{TriMesh, TriMeshFlags};
    let vertices = design
        .vertices
        .iter()
        .map(|v| Vector::new(v.x, v.y, v.z))
        .collect();
    TriMesh::with_flags(vertices, design.triangles.clone(), TriMeshFlags::ORIENTED)
        .expect("the bunny as a parry TriMesh")
}

/// Distance and inside/outside of each point within 5 mm, in parallel as `query_batch` is.
fn parry_project(
    mesh: &parry3d_f64::shape::TriMesh,
    points: &[nalgebra::Point3<f64>],
    out: &mut [Option<(f64, bool)>],
) {
    use parry3d_f64::math::Vector;
    use parry3d_f64::query::PointQuery;
    use rayon::prelude::*;
    points
        .par_chunks(4096)
        .zip(out.par_chunks_mut(4096))
        .for_each(|(ps, os)| {
            for (p, o) in ps.iter().zip(os) {
                let v = Vector::new(p.x, p.y, p.z);
                *o = mesh
                    .project_local_point_with_max_dist(v, false, 0.005)
                    .map(|proj| ((proj.point - v).length(), proj.is_inside));
            }
        });
}

/// Coverage's question, whether the design hides a point from a station, asked of our index
/// (`blocks_sight`, its BVH) and of parry's `TriMesh` ray cast, one core each: parry serves
/// where it is no slower. Four stations around the bunny, each looking at every target.
fn line_of_sight(
    c: &mut Criterion,
    design: &Design,
    index: &C2mIndex,
    trimesh: &parry3d_f64::shape::TriMesh,
    targets: &[nalgebra::Point3<f64>],
) {
    use nalgebra::{Point3, Vector3};
    use parry3d_f64::math::Vector;
    use parry3d_f64::query::{Ray, RayCast};
    // Surface within this of either end does not count: a point sees past its own face.
    const MARGIN: f64 = 0.002;
    let (lo, hi) = design.bounds();
    let centre = nalgebra::center(&lo, &hi);
    let r = (hi - lo).norm();
    let eyes: Vec<Point3<f64>> = (0..4)
        .map(|k| {
            let a = k as f64 * std::f64::consts::FRAC_PI_2;
            centre + Vector3::new(a.cos() * r, a.sin() * r, 0.3 * r)
        })
        .collect();
    let ours = |eye: &Point3<f64>, p: &Point3<f64>| index.blocks_sight(eye, p, MARGIN);
    let parry = |eye: &Point3<f64>, p: &Point3<f64>| {
        let d = p - eye;
        let len = d.norm();
        if len <= 2.0 * MARGIN {
            return false;
        }
        let dir = d / len;
        let o = eye + dir * MARGIN;
        let ray = Ray::new(Vector::new(o.x, o.y, o.z), Vector::new(dir.x, dir.y, dir.z));
        trimesh.intersects_local_ray(&ray, len - 2.0 * MARGIN)
    };
    let (mut blocked, mut differ) = (0usize, 0usize);
    for eye in &eyes {
        for p in targets {
            let a = ours(eye, p);
            blocked += usize::from(a);
            differ += usize::from(a != parry(eye, p));
        }
    }
    eprintln!(
        "line of sight: {blocked} of {} sights blocked; parry answers {differ} of them otherwise",
        eyes.len() * targets.len()
    );
    let mut g = c.benchmark_group("line_of_sight_bunny");
    g.sample_size(10);
    g.throughput(Throughput::Elements((eyes.len() * targets.len()) as u64));
    for (name, f) in [
        ("ours", &ours as &dyn Fn(_, _) -> bool),
        ("parry_trimesh", &parry),
    ] {
        g.bench_function(name, |b| {
            b.iter(|| {
                eyes.iter()
                    .map(|e| targets.iter().filter(|p| f(e, p)).count())
                    .sum::<usize>()
            })
        });
    }
    g.finish();
}

/// What the design costs: the index's build, and a new printed height's section, on the bunny
/// and on a generated 1,004,000-triangle column.
fn design_index(c: &mut Criterion, design: &Design, index: &C2mIndex) {
    let mut g = c.benchmark_group("design_index");
    g.sample_size(10);
    let params = C2mParams::within(0.005);
    g.bench_function("build_bunny", |b| {
        b.iter(|| C2mIndex::build(design, params).unwrap().stats().bytes)
    });
    let (lo, hi) = index.z_range();
    g.bench_function("section_bunny_mid_height", |b| {
        b.iter(|| index.section(0.5 * (lo + hi)).unwrap().triangles())
    });
    let column = twisted_column(0.15, 0.1, 1.2, 90.0, 2000, 250);
    let t0 = Instant::now();
    let big = C2mIndex::build(&column, params).unwrap();
    let s = big.stats();
    eprintln!(
        "column: {} triangles, {} cells of {:.3} mm, {} candidates, {} cells left to the BVH, \
         {:.0} MB ({:.0} B/triangle), built in {:.2} s",
        s.triangles,
        s.cells,
        s.cell_size * 1e3,
        s.candidates,
        s.bvh_cells,
        s.bytes as f64 / 1e6,
        s.bytes as f64 / s.triangles as f64,
        t0.elapsed().as_secs_f64()
    );
    g.bench_function("build_column_1M", |b| {
        b.iter(|| C2mIndex::build(&column, params).unwrap().stats().bytes)
    });
    g.bench_function("section_column_1M", |b| {
        b.iter(|| big.section(0.61).unwrap().triangles())
    });
    g.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
