//! Mutation fuzzing on stable Rust: every input a user or a peer can hand asbuilt (scan files of
//! every format, design files, wire messages, recordings, agent.toml), mutated from valid files
//! that our own writers make and from `../shared/data`.
//!
//! An input passes when it gives a result or an error that names the file; it fails on a panic,
//! an abort, an allocation its size cannot justify, or a hang. The `fuzz` binary runs each
//! target in a worker process so that an abort or a hang is caught and its input kept.
//! Inputs are numbered: input `i` of a target under a run seed is always the same bytes, given
//! the same seed files.

mod mutate;
mod seeds;
mod targets;

use std::path::Path;

use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;

pub use mutate::mutate;
pub use seeds::write_seeds;
pub use targets::{TARGETS, Target, target};

/// What one input gave.
#[derive(Debug)]
pub enum Outcome {
    /// Read: what came out.
    Read(String),
    /// Refused with a clear error.
    Refused(String),
    /// An error that does not say which file or what is wrong.
    Unclear(String),
}

/// The seed files of `target`, sorted by name, from `dir/<target>/`.
pub fn load_seeds(dir: &Path, target: &Target) -> std::io::Result<Vec<(String, Vec<u8>)>> {
    let mut files: Vec<_> = std::fs::read_dir(dir.join(target.name))?
        .map(|e| e.map(|e| e.path()))
        .collect::<Result<_, _>>()?;
    files.sort();
    files
        .into_iter()
        .map(|p| {
            let name = p.file_name().unwrap().to_string_lossy().into_owned();
            std::fs::read(&p).map(|b| (name, b))
        })
        .collect()
}

/// Input `index` of `target` under `run_seed`: a seed file, mutated. Its extension is the seed's,
/// so file readers pick the same format.
pub fn input(
    target: &Target,
    seeds: &[(String, Vec<u8>)],
    run_seed: u64,
    index: u64,
) -> (String, Vec<u8>) {
    let mut rng = ChaCha8Rng::seed_from_u64(
        run_seed
            .wrapping_mul(0x9e37_79b9_7f4a_7c15)
            .wrapping_add(index)
            ^ fnv(target.name.as_bytes()),
    );
    let (name, bytes) = &seeds[rand::Rng::random_range(&mut rng, 0..seeds.len())];
    (name.clone(), mutate(bytes, &mut rng, target.text))
}

fn fnv(b: &[u8]) -> u64 {
    b.iter().fold(0xcbf2_9ce4_8422_2325, |h, &c| {
        (h ^ c as u64).wrapping_mul(0x100_0000_01b3)
    })
}
