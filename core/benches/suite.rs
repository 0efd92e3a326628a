//! Deviation-suite throughput on the source study's shotcrete wall (173.4 × 2000 × 980 mm): 2 M noisy
//! scan points (σ 0.5 mm, scan-like order) streamed in 64 k-point chunks, as the agent feeds
//! them, into
//! - streaming M3C2 with 100 k core points on the design (10 mm cylinders, 20 mm deep);
//! - reverse C2C and coverage state over the same 100 k samples, at 20 mm and 50 mm reach;
//! - C2C to the design samples with a local plane (k-d tree);
//! - the findings drawn from the M3C2 and coverage (20 mm reach) states that stream leaves:
//!   one pass over the 100 k samples (layer rows every 20 mm, the top, regions, missing areas).
//!
//! The goal for M3C2 is ≥ 5 M points/s on 2 cores (py4dgeo: 9.3 k core points/s on 1 M points).
//! Memory held by each method is printed before and after the stream: it must not grow.
//!
//! Run: `cargo bench -p asbuilt-core --bench suite`

use std::num::NonZeroUsize;

use asbuilt_core::Design;
use asbuilt_core::c2c::{self, C2cParams};
use asbuilt_core::cloud::CloudIndex;
use asbuilt_core::coverage::{Coverage, CoverageParams};
use asbuilt_core::design::shapes;
use asbuilt_core::findings::{FindingParams, find};
use asbuilt_core::m3c2::streaming::{StreamingM3c2, StreamingParams};
use asbuilt_core::sampling::DesignSamples;
use asbuilt_core::{C2mIndex, C2mParams};
use criterion::measurement::WallTime;
use criterion::{BenchmarkGroup, Criterion, Throughput, criterion_group, criterion_main};
use nalgebra::Point3;

#[path = "support/points.rs"]
mod points;
use points::noisy_surface_points;

const POINTS: usize = 2_000_000;
const CHUNK: usize = 65_536;
const CORE_POINTS: f64 = 100_000.0;

fn bench(c: &mut Criterion) {
    let wall = shapes::cuboid(Point3::origin(), Point3::new(2.0, 0.1734, 0.98));
    let spacing = (wall.surface_area() / CORE_POINTS).sqrt();
    let samples = DesignSamples::generate(&wall, spacing, 1).unwrap();
    // Points spread evenly over a finely remeshed wall, with noise, in scan-like order.
    let scan = noisy_surface_points(&remesh(&wall, 0.02), POINTS);
    eprintln!(
        "wall: {} core points at {:.2} mm spacing, {} scan points",
        samples.len(),
        spacing * 1e3,
        scan.len()
    );

    let mut g = c.benchmark_group("suite_wall_2M");
    g.sample_size(10);
    g.throughput(Throughput::Elements(scan.len() as u64));

    let mut m3c2 = StreamingM3c2::new(
        &samples,
        StreamingParams {
            projection_diameter: 0.01,
            max_depth: 0.02,
            min_points: 5,
        },
    )
    .unwrap();
    // The first chunk sizes the scratch; nothing grows after it.
    m3c2.ingest(&scan[..CHUNK]);
    let before = m3c2.bytes();
    g.bench_function("m3c2_100k_core_points", |b| {
        b.iter(|| {
            m3c2.begin_station();
            for chunk in scan.chunks(CHUNK) {
                m3c2.ingest(chunk);
            }
        })
    });
    let s = m3c2.end_station(0.001);
    eprintln!(
        "m3c2: {:.1} MB after one chunk, {:.1} MB after every run; {} of {} core points with points",
        before as f64 / 1e6,
        m3c2.bytes() as f64 / 1e6,
        s.with_points,
        s.core_points
    );

    for reach in [0.02, 0.05] {
        let mut cov =
            Coverage::new(&samples, CoverageParams::with_threshold(0.003, reach)).unwrap();
        cov.ingest(&scan[..CHUNK]);
        let before = cov.bytes();
        g.bench_function(format!("coverage_reach_{:.0}mm", reach * 1e3), |b| {
            b.iter(|| {
                cov.begin_station();
                for chunk in scan.chunks(CHUNK) {
                    cov.ingest(chunk);
                }
            })
        });
        eprintln!(
            "coverage (reach {:.0} mm): {:.1} MB after one chunk, {:.1} MB after every run",
            reach * 1e3,
            before as f64 / 1e6,
            cov.bytes() as f64 / 1e6
        );
    }

    bench_findings(&mut g, (&wall, &samples, spacing), &scan, &m3c2);
    g.throughput(Throughput::Elements(scan.len() as u64));

    let reference = CloudIndex::new(&samples.points).unwrap();
    let params = C2cParams {
        max_distance: 0.05,
        local_plane_k: NonZeroUsize::new(6),
    };
    let mut out = vec![None; CHUNK];
    g.bench_function("c2c_local_plane_to_samples", |b| {
        b.iter(|| {
            for chunk in scan.chunks(CHUNK) {
                c2c::distances(&reference, chunk, &params, &mut out[..chunk.len()]);
            }
        })
    });
    g.finish();
}

/// The findings over what one stream leaves: M3C2 as streamed, coverage at 20 mm reach; per
/// design sample.
fn bench_findings(
    g: &mut BenchmarkGroup<'_, WallTime>,
    (wall, samples, spacing): (&Design, &DesignSamples, f64),
    scan: &[Point3<f64>],
    m3c2: &StreamingM3c2,
) {
    let mut cov = Coverage::new(samples, CoverageParams::with_threshold(0.003, 0.02)).unwrap();
    for chunk in scan.chunks(CHUNK) {
        cov.ingest(chunk);
    }
    let index = C2mIndex::build(wall, C2mParams::within(0.05)).unwrap();
    let (results, outcomes) = (m3c2.results(0.001), cov.outcomes(&index));
    let sharp = wall.sharp_edges(30.0);
    let area_per_sample = wall.surface_area() / samples.len() as f64;
    let params = FindingParams {
        tolerance: 0.005,
        layer_height: Some(0.02),
        printed_height: 0.98,
        spacing,
        radius: 0.005,
        min_region_samples: 5,
        coverage_threshold: 0.003,
        min_missing_area_m2: 0.001,
    };
    g.throughput(Throughput::Elements(samples.len() as u64));
    g.bench_function("findings_100k_samples", |b| {
        b.iter(|| {
            find(&results, &outcomes, &sharp, area_per_sample, &params, 0.001)
                .layers
                .len()
        })
    });
}

/// The wall with its faces split into triangles of about `edge` metres, so that points spread
/// over triangles lie evenly over the area.
fn remesh(d: &asbuilt_core::Design, edge: f64) -> asbuilt_core::Design {
    let mut v = Vec::new();
    let mut t = Vec::new();
    for tri in &d.triangles {
        let [a, b, c] = tri.map(|i| d.vertices[i as usize]);
        let n = (((b - a).norm().max((c - a).norm()).max((c - b).norm())) / edge).ceil() as u32;
        // Rows j = 0..=n, each with n - j + 1 points.
        let mut index = vec![vec![0u32; (n + 1) as usize]; (n + 1) as usize];
        for j in 0..=n {
            for i in 0..=(n - j) {
                index[j as usize][i as usize] = v.len() as u32;
                let (u, w) = (i as f64 / n as f64, j as f64 / n as f64);
                v.push(a + (b - a) * u + (c - a) * w);
            }
        }
        for j in 0..n {
            for i in 0..(n - j) {
                let p = index[j as usize][i as usize];
                let q = index[j as usize][i as usize + 1];
                let r = index[j as usize + 1][i as usize];
                t.push([p, q, r]);
                if i + 1 < n - j {
                    let s = index[j as usize + 1][i as usize + 1];
                    t.push([q, s, r]);
                }
            }
        }
    }
    asbuilt_core::Design::from_indexed(v, t, 1.0).unwrap()
}

criterion_group!(benches, bench);
criterion_main!(benches);
