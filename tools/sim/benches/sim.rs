//! The simulated scanner's output rate: one station of the demo's job (the study wall after 24
//! of its 49 layers, a Z+F at 0.036°, 1.2 m out and 0.5 m above the top) from the as-built mesh
//! to noisy points in scan-line order. `asbuilt sim --rate max` and the agent benchmarks can
//! only be fed as fast as this; the goal is ≥ 5 M points/s on 2 cores.
//!
//! Run: `cargo bench -p asbuilt-sim --bench sim`

use asbuilt_sim::{Defect, Part, ScannerModel, as_built, scan, stations_around};
use criterion::{Criterion, Throughput, criterion_group, criterion_main};

fn bench(c: &mut Criterion) {
    let part = Part::wall();
    let defects = [
        Defect::Extrusion {
            first: 2,
            last: 4,
            width: 0.012,
        },
        Defect::Bulge {
            centre: [-0.5, -0.0867, 0.25],
            radius: 0.1,
            height: 0.015,
        },
    ];
    let m = as_built(&part, &defects, 24).unwrap();
    let (lo, hi) = part.design.bounds();
    let station = stations_around(lo, hi, m.top, 4, 1.2, 0.5)[0];
    let model = ScannerModel::default();
    let n = scan(&m, &station, &model, 1).points.len() as u64;
    eprintln!(
        "as-built: {} triangles; one station: {n} points",
        m.triangles.len()
    );
    let mut g = c.benchmark_group("sim");
    g.sample_size(20);
    g.throughput(Throughput::Elements(n));
    g.bench_function("scan_one_station", |b| {
        b.iter(|| scan(&m, &station, &model, 1).points.len())
    });
    g.throughput(Throughput::Elements(1));
    g.bench_function("as_built_24_layers", |b| {
        b.iter(|| as_built(&part, &defects, 24).unwrap().triangles.len())
    });
    g.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
