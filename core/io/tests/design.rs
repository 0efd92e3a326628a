//! Loading designs: every format gives the same mesh; units scale; defects are counted.

use std::io::Write;
use std::path::Path;

use asbuilt_core::design::shapes::cuboid;
use asbuilt_core::{Design, Units};
use asbuilt_io::IoError;
use nalgebra::Point3;

fn cube() -> Design {
    cuboid(
        Point3::new(-500.0, -250.0, 0.0),
        Point3::new(500.0, 250.0, 100.0),
    )
}

fn soup(d: &Design) -> Vec<[[f32; 3]; 3]> {
    d.triangles
        .iter()
        .map(|t| {
            t.map(|i| {
                let v = d.vertices[i as usize];
                [v.x as f32, v.y as f32, v.z as f32]
            })
        })
        .collect()
}

fn write_ascii_stl(path: &Path, d: &Design) {
    let mut s = String::from("solid cube\n");
    for t in soup(d) {
        s += "facet normal 0 0 0\nouter loop\n";
        for v in t {
            s += &format!("vertex {} {} {}\n", v[0], v[1], v[2]);
        }
        s += "endloop\nendfacet\n";
    }
    s += "endsolid cube\n";
    std::fs::write(path, s).unwrap();
}

fn write_binary_stl(path: &Path, d: &Design) {
    let tris = soup(d);
    let mut f = std::fs::File::create(path).unwrap();
    f.write_all(&[0u8; 80]).unwrap();
    f.write_all(&(tris.len() as u32).to_le_bytes()).unwrap();
    for t in tris {
        f.write_all(&[0u8; 12]).unwrap();
        for v in t {
            for c in v {
                f.write_all(&c.to_le_bytes()).unwrap();
            }
        }
        f.write_all(&[0u8; 2]).unwrap();
    }
}

fn write_obj(path: &Path, d: &Design) {
    let mut s = String::new();
    for v in &d.vertices {
        s += &format!("v {} {} {}\n", v.x, v.y, v.z);
    }
    for t in &d.triangles {
        s += &format!("f {} {} {}\n", t[0] + 1, t[1] + 1, t[2] + 1);
    }
    std::fs::write(path, s).unwrap();
}

fn write_ply(path: &Path, d: &Design) {
    let mut s = format!(
        "ply\nformat ascii 1.0\nelement vertex {}\nproperty float x\nproperty float y\nproperty float z\nelement face {}\nproperty list uchar int vertex_indices\nend_header\n",
        d.vertices.len(),
        d.triangles.len()
    );
    for v in &d.vertices {
        s += &format!("{} {} {}\n", v.x, v.y, v.z);
    }
    for t in &d.triangles {
        s += &format!("3 {} {} {}\n", t[0], t[1], t[2]);
    }
    std::fs::write(path, s).unwrap();
}

#[test]
fn every_format_loads_the_same_closed_mesh_in_metres() {
    let dir = tempfile::tempdir().unwrap();
    let reference = cube();
    let files = [
        ("ascii.stl", write_ascii_stl as fn(&Path, &Design)),
        ("binary.stl", write_binary_stl),
        ("cube.obj", write_obj),
        ("cube.ply", write_ply),
    ];
    for (name, write) in files {
        let path = dir.path().join(name);
        write(&path, &reference);
        let d = asbuilt_io::read_design(&path, Units::Millimetres)
            .unwrap_or_else(|e| panic!("{name}: {e}"));
        assert_eq!(d.vertices.len(), 8, "{name}: duplicate vertices merged");
        assert_eq!(d.triangles.len(), 12, "{name}");
        assert!(
            d.report.topology.is_closed_and_oriented(),
            "{name}: {:?}",
            d.report
        );
        assert!(d.report.warnings().is_empty(), "{name}");
        let (lo, hi) = d.bounds();
        assert!(
            (lo - Point3::new(-0.5, -0.25, 0.0)).norm() < 1e-12,
            "{name}: {lo}"
        );
        assert!(
            (hi - Point3::new(0.5, 0.25, 0.1)).norm() < 1e-12,
            "{name}: {hi}"
        );
        let m = asbuilt_io::read_design(&path, Units::Metres).unwrap();
        assert!(
            (m.bounds().1.x - 500.0).abs() < 1e-9,
            "{name}: metres are not scaled"
        );
        // The same file from memory, as a recording's attachment is read.
        let bytes = std::fs::read(&path).unwrap();
        let b = asbuilt_io::read_design_bytes(&bytes, name, Units::Millimetres)
            .unwrap_or_else(|e| panic!("{name} from bytes: {e}"));
        assert_eq!(
            (b.vertices, b.triangles),
            (d.vertices, d.triangles),
            "{name}"
        );
    }
}

#[test]
fn a_design_in_memory_is_named_in_its_errors() {
    let e = asbuilt_io::read_design_bytes(b"solid x\nfacet oops", "part.stl", Units::Metres)
        .unwrap_err();
    assert!(matches!(e, IoError::Malformed { .. }), "{e}");
    assert!(e.to_string().contains("part.stl"), "{e}");
    let e = asbuilt_io::read_design_bytes(b"", "part.step", Units::Metres).unwrap_err();
    assert!(matches!(e, IoError::UnknownFormat { .. }), "{e}");
    assert!(e.to_string().contains(".obj"), "{e}");
}

#[test]
fn defects_are_counted_as_warnings() {
    let c = cube();
    // Drop one triangle (a hole: 3 boundary edges), flip another (3 inconsistent edges), add a
    // degenerate one and a fin that makes an edge non-manifold.
    let mut t = c.triangles.clone();
    t.remove(0);
    t[0] = [t[0][0], t[0][2], t[0][1]];
    t.push([0, 0, 1]);
    let mut v = c.vertices.clone();
    v.push(Point3::new(0.0, 0.0, 1000.0));
    let e = t[3];
    t.push([e[0], e[1], 8]);
    let d = Design::from_indexed(v, t, 1e-3).unwrap();
    assert_eq!(d.report.degenerate_triangles, 1);
    let topo = d.report.topology;
    assert!(topo.boundary_edges >= 3, "{topo:?}");
    assert!(topo.inconsistent_edges >= 1, "{topo:?}");
    assert_eq!(topo.non_manifold_edges, 1, "{topo:?}");
    let w = d.report.warnings().join("\n");
    for word in [
        "degenerate",
        "open boundary",
        "non-manifold",
        "opposite orientation",
    ] {
        assert!(w.contains(word), "{word} missing from:\n{w}");
    }
}

#[test]
fn unreadable_empty_and_unknown_files_are_clear_errors() {
    let dir = tempfile::tempdir().unwrap();
    let missing = dir.path().join("nope.stl");
    let e = asbuilt_io::read_design(&missing, Units::Metres).unwrap_err();
    assert!(matches!(e, IoError::NotFound { .. }), "{e}");
    assert!(e.to_string().contains("nope.stl"), "{e}");

    let empty = dir.path().join("empty.ply");
    std::fs::write(
        &empty,
        "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\nelement face 0\nproperty list uchar int vertex_indices\nend_header\n0 0 0\n1 0 0\n0 1 0\n",
    )
    .unwrap();
    let e = asbuilt_io::read_design(&empty, Units::Metres).unwrap_err();
    assert!(matches!(e, IoError::EmptyDesign { .. }), "{e}");
    assert!(e.to_string().contains("no usable triangles"), "{e}");

    let garbage = dir.path().join("garbage.stl");
    std::fs::write(&garbage, b"\x00\x01 not an stl").unwrap();
    assert!(asbuilt_io::read_design(&garbage, Units::Metres).is_err());

    let step = dir.path().join("part.step");
    std::fs::write(&step, "ISO-10303-21;").unwrap();
    let e = asbuilt_io::read_design(&step, Units::Metres).unwrap_err();
    assert!(e.to_string().contains(".stl"), "{e}");

    let bad_index = dir.path().join("bad.obj");
    std::fs::write(&bad_index, "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\nf 1 2 9\n").unwrap();
    match asbuilt_io::read_design(&bad_index, Units::Metres) {
        Ok(d) => assert_eq!(d.triangles.len(), 1),
        Err(e) => assert!(e.to_string().contains("bad.obj"), "{e}"),
    }
}
