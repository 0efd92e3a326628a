//! The design, read and indexed once at start, or taken up from the index cache the run before
//! wrote beside the recording (`[recorder] index_cache`, [`asbuilt_io::index_cache`]): a
//! million-triangle design takes seconds to index, which a restart after a crash cannot spare.

use std::sync::Arc;
use std::thread::JoinHandle;
use std::time::Instant;

use asbuilt_core::printed::PrintedDesigns;
use asbuilt_core::{C2mIndex, C2mParams, Design};
use asbuilt_io::index_cache::{CacheMiss, IndexCache};
use nalgebra::Point3;

use crate::config::AgentConfig;
use crate::error::AgentError;
use crate::{info, warn};

/// The design's mesh, for a view.
pub type DesignView = (Vec<Point3<f64>>, Vec<[u32; 3]>);

/// The design as the agent serves it.
pub struct LoadedDesign {
    /// The design and its index, for every printed height.
    pub designs: PrintedDesigns,
    /// The mesh for the view, when there is a view.
    pub view: Option<DesignView>,
    /// The thread writing the index cache, after a start that had to index the design.
    pub caching: Option<JoinHandle<()>>,
    /// The design file as read, for the recorder to hash and attach without reading it again.
    pub file: Vec<u8>,
}

/// The cache file in the recording folder, when the configuration keeps one.
pub fn cache_path(config: &AgentConfig) -> Option<std::path::PathBuf> {
    let r = &config.recorder;
    r.dir
        .as_ref()
        .filter(|_| r.index_cache)
        .map(|d| d.join("design.index"))
}

/// Reads the design and indexes it, or takes both from the cache when it is this design's,
/// for these `[inspect]` parameters and this build. After indexing, the cache is written on a
/// thread of its own while the agent serves.
pub fn load(config: &AgentConfig, started: Instant) -> Result<LoadedDesign, AgentError> {
    let path = &config.design.path;
    let units = config.design.units();
    let params = C2mParams {
        max_distance: config.inspect.max_distance(),
        cell_size: config.inspect.cell_size,
    };
    let bytes = asbuilt_io::read_design_file(path)?;
    let cache = cache_path(config).map(|p| IndexCache::new(p, &bytes, units, &params));
    let cached = cache.as_ref().and_then(|c| match c.load() {
        Ok(cached) => Some(cached),
        Err(miss @ CacheMiss::Damaged { .. }) => {
            warn!("design: {miss}");
            None
        }
        Err(miss) => {
            info!("design: {miss}; indexing the design");
            None
        }
    });
    let from_cache = cached.is_some();
    let (design, index) = match cached {
        Some(cached) => cached,
        None => {
            let design = asbuilt_io::read_design_bytes(&bytes, &path.to_string_lossy(), units)?;
            let index = C2mIndex::build(&design, params)?;
            (design, index)
        }
    };
    for w in design.report.warnings() {
        warn!("design: {w}");
    }
    // The view needs the mesh once; the index has everything else.
    let view = (config.viewer.rrd.is_some() || config.viewer.url.is_some())
        .then(|| (design.vertices.clone(), design.triangles.clone()));
    let designs = PrintedDesigns::with_index(design, index);
    let ix = designs.full().index.stats();
    info!(
        "design {} ({}): {} triangles, index {} cells of {:.2} mm, {:.0} MB, {} in {:.1} s",
        path.display(),
        config.design.units,
        ix.triangles,
        ix.cells,
        ix.cell_size * 1e3,
        ix.bytes as f64 / 1e6,
        if from_cache {
            "taken from the index cache"
        } else {
            "ready"
        },
        started.elapsed().as_secs_f64()
    );
    let caching = cache.filter(|_| !from_cache).and_then(|cache| {
        let design = designs.whole_design().clone();
        let index = designs.full().index.clone();
        std::thread::Builder::new()
            .name("index-cache".into())
            .spawn(move || store(&cache, &design, &index))
            .map_err(|e| warn!("design: cannot start writing the index cache: {e}"))
            .ok()
    });
    Ok(LoadedDesign {
        designs,
        view,
        caching,
        file: bytes,
    })
}

fn store(cache: &IndexCache, design: &Arc<Design>, index: &Arc<C2mIndex>) {
    let started = Instant::now();
    let written = cache
        .path()
        .parent()
        .map_or(Ok(()), std::fs::create_dir_all)
        .and_then(|()| cache.store(design, index));
    match written {
        Ok(bytes) => info!(
            "design: index cached in {} ({:.0} MB, {:.1} s), for the next start",
            cache.path().display(),
            bytes as f64 / 1e6,
            started.elapsed().as_secs_f64()
        ),
        Err(e) => warn!(
            "design: cannot write the index cache {}: {e}; the next start indexes the design \
             again",
            cache.path().display()
        ),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A closed tetrahedron in ASCII STL, millimetres.
    const TETRAHEDRON: &str = "solid t
facet normal 0 0 -1
outer loop
vertex 0 0 0
vertex 0 100 0
vertex 100 0 0
endloop
endfacet
facet normal 0 -1 0
outer loop
vertex 0 0 0
vertex 100 0 0
vertex 0 0 100
endloop
endfacet
facet normal -1 0 0
outer loop
vertex 0 0 0
vertex 0 0 100
vertex 0 100 0
endloop
endfacet
facet normal 1 1 1
outer loop
vertex 100 0 0
vertex 0 100 0
vertex 0 0 100
endloop
endfacet
endsolid t
";

    fn config(dir: &std::path::Path, tolerance: f64) -> AgentConfig {
        let text = format!(
            "[design]\npath = \"t.stl\"\nunits = \"mm\"\n[inspect]\ntolerance = {tolerance}\n\
             [recorder]\ndir = \"rec\"\n"
        );
        AgentConfig::parse(&text, dir, &dir.join("agent.toml")).unwrap()
    }

    #[test]
    fn a_restart_takes_the_design_from_the_cache_until_it_changes() {
        let dir = tempfile::tempdir().unwrap();
        std::fs::write(dir.path().join("t.stl"), TETRAHEDRON).unwrap();
        let c = config(dir.path(), 0.005);
        let first = load(&c, Instant::now()).unwrap();
        first
            .caching
            .expect("the first start caches")
            .join()
            .unwrap();
        assert!(cache_path(&c).unwrap().is_file());
        let again = load(&c, Instant::now()).unwrap();
        assert!(again.caching.is_none(), "the restart indexed again");
        let (a, b) = (first.designs.full(), again.designs.full());
        assert_eq!(a.design().vertices, b.design().vertices);
        assert_eq!(a.design().triangles, b.design().triangles);
        // Memory aside: a loaded index holds no spare capacity.
        let (x, y) = (a.index.stats(), b.index.stats());
        assert_eq!(
            (x.cells, x.candidates, x.bvh_cells),
            (y.cells, y.candidates, y.bvh_cells)
        );
        assert!(y.bytes <= x.bytes);
        // Another tolerance is another index: built and cached again.
        let other = load(&config(dir.path(), 0.05), Instant::now()).unwrap();
        other
            .caching
            .expect("a stale cache is replaced")
            .join()
            .unwrap();
        // A damaged cache costs an indexing, never the start.
        std::fs::write(cache_path(&c).unwrap(), b"torn").unwrap();
        let after = load(&c, Instant::now()).unwrap();
        assert!(after.caching.is_some());
    }
}
