//! How fast the simulated line profiler makes profiles: one pass over layer 30 of the column
//! (about 7,900 profiles of up to 2,048 points), on one thread and on all (rayon), median of
//! five runs. The simulated cell must outpace the agent (4.1 M points/s at 2,048 × 2 kHz).
//! Then how fast `core::profiler::Sweep` marks what the pass's profiles swept over the column's
//! design samples (10 mm apart): the agent must keep up with 2,000 profiles a second.
//!
//! `cargo bench -p asbuilt-sim --bench profiler`

use std::time::Instant;

use asbuilt_core::profiler::{Sweep, SweepParams};
use asbuilt_core::sampling::DesignSamples;
use asbuilt_core::{C2mIndex, C2mParams};
use asbuilt_sim::profiler::{ProfilePass, ProfilerModel};
use asbuilt_sim::{Part, as_built};
use rayon::prelude::*;

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

fn main() {
    let part = Part::column();
    let built = as_built(&part, &[], 31).expect("the column prints");
    let pass = ProfilePass::new(&part, &built, 30, ProfilerModel::default(), 1, 0)
        .expect("the column has a section at every layer");
    let n = pass.profiles();
    for (name, parallel) in [("one thread", false), ("all threads", true)] {
        let mut rates = Vec::new();
        let mut points = 0;
        for _ in 0..5 {
            let t = Instant::now();
            points = if parallel {
                (0..n)
                    .into_par_iter()
                    .map(|k| pass.profile(k).map_or(0, |p| p.points.len()))
                    .sum::<usize>()
            } else {
                (0..n)
                    .map(|k| pass.profile(k).map_or(0, |p| p.points.len()))
                    .sum::<usize>()
            };
            rates.push(n as f64 / t.elapsed().as_secs_f64());
        }
        let per_s = median(rates);
        println!(
            "{name}: {n} profiles, {points} points: {per_s:.0} profiles/s, {:.1} M points/s \
             (median of 5)",
            per_s * points as f64 / n as f64 * 1e-6
        );
    }
    sweep(&pass, &part);
}

fn sweep(pass: &ProfilePass, part: &Part) {
    let model = ProfilerModel::default();
    let samples = DesignSamples::generate(&part.design, 0.01, 1).expect("the column samples");
    let index = C2mIndex::from_design(part.design.clone(), C2mParams::within(0.05))
        .expect("the column indexes");
    let n = pass.profiles();
    let sensors: Vec<_> = (0..n)
        .filter_map(|k| Some(pass.mount_at(pass.profile_time_ns(k)?)? * model.mount_sensor()))
        .collect();
    let mut rates = Vec::new();
    let mut swept = 0;
    for _ in 0..5 {
        let mut sweep = Sweep::new(&samples.points, &samples.normals, SweepParams::default());
        let t = Instant::now();
        for s in &sensors {
            sweep.profile(s, &index);
        }
        rates.push(sensors.len() as f64 / t.elapsed().as_secs_f64());
        swept = sweep.count();
    }
    println!(
        "sweep: {} profiles over {} design samples, {swept} swept: {:.0} profiles/s (median of 5)",
        sensors.len(),
        samples.len(),
        median(rates)
    );
}
