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

/// A PLY mesh as ply-rs reads it: x, y, z of each vertex, each face's indices fanned.
fn ply_rs_mesh(path: &Path) -> (Vec<Point3<f64>>, Vec<[u32; 3]>) {
    use ply_rs_bw::ply::Property as P;
    let mut f = std::io::BufReader::new(std::fs::File::open(path).unwrap());
    let ply = ply_rs_bw::parser::Parser::<ply_rs_bw::ply::DefaultElement>::new()
        .read_ply(&mut f)
        .unwrap();
    let scalar = |p: &P| match *p {
        P::Float(v) => v as f64,
        P::Double(v) => v,
        P::Int(v) => v as f64,
        P::UChar(v) => v as f64,
        ref other => panic!("{other:?}"),
    };
    let vertices = ply.payload["vertex"]
        .iter()
        .map(|v| Point3::new(scalar(&v["x"]), scalar(&v["y"]), scalar(&v["z"])))
        .collect();
    let mut triangles = Vec::new();
    for f in &ply.payload["face"] {
        let list: Vec<u32> = match &f["vertex_indices"] {
            P::ListUInt(l) => l.clone(),
            P::ListInt(l) => l.iter().map(|&i| i as u32).collect(),
            other => panic!("{other:?}"),
        };
        for k in 1..list.len() - 1 {
            triangles.push([list[0], list[k], list[k + 1]]);
        }
    }
    (vertices, triangles)
}

/// A PLY mesh in `encoding` with what real files hold beside the mesh: an element before the
/// vertices and one after the faces, properties before and after x, y, z, mixed types,
/// coordinates a float cannot hold exactly, and polygons of three to five corners.
fn write_odd_ply(path: &Path, encoding: &str) {
    let vertices: Vec<[f64; 3]> = (0..40)
        .map(|i| {
            let t = i as f64 * 0.37;
            [t.cos() * 0.1, t.sin() * 0.1 + 0.3, 0.01 * i as f64 + 0.1]
        })
        .collect();
    let faces: Vec<Vec<u32>> = (0..30u32)
        .map(|i| (0..3 + i % 3).map(|k| (i + 2 * k) % 40).collect())
        .collect();
    let mut out: Vec<u8> = format!(
        "ply\nformat {encoding} 1.0\ncomment made by a test\nelement material 2\n\
         property uchar red\nproperty list uchar float weights\n\
         element vertex {}\nproperty float nx\nproperty float x\nproperty double y\n\
         property float z\nproperty uchar red\n\
         element face {}\nproperty uchar flags\nproperty list uchar uint vertex_indices\n\
         element edge 1\nproperty int vertex1\nproperty int vertex2\nend_header\n",
        vertices.len(),
        faces.len()
    )
    .into_bytes();
    let big = encoding == "binary_big_endian";
    macro_rules! put {
        ($v:expr) => {
            if encoding == "ascii" {
                out.extend(format!("{} ", $v).as_bytes());
            } else if big {
                out.extend($v.to_be_bytes());
            } else {
                out.extend($v.to_le_bytes());
            }
        };
    }
    let end = |out: &mut Vec<u8>| {
        if encoding == "ascii" {
            out.push(b'\n');
        }
    };
    for m in 0..2u8 {
        put!(m);
        put!(2u8);
        put!(0.5f32);
        put!(0.25f32);
        end(&mut out);
    }
    for v in &vertices {
        put!(1.0f32);
        put!(v[0] as f32);
        put!(v[1]);
        put!(v[2] as f32);
        put!(200u8);
        end(&mut out);
    }
    for f in &faces {
        put!(7u8);
        put!(f.len() as u8);
        for &i in f {
            put!(i);
        }
        end(&mut out);
    }
    put!(1i32);
    put!(2i32);
    end(&mut out);
    std::fs::write(path, out).unwrap();
}

#[test]
fn ply_designs_read_as_ply_rs_reads_them_in_every_encoding() {
    let dir = tempfile::tempdir().unwrap();
    for encoding in ["ascii", "binary_little_endian", "binary_big_endian"] {
        let path = dir.path().join(format!("{encoding}.ply"));
        write_odd_ply(&path, encoding);
        let (v, t) = ply_rs_mesh(&path);
        assert_eq!(t.len(), 60, "{encoding}: 30 polygons of 3 to 5 corners");
        let want = Design::from_indexed(v, t, 1.0).unwrap();
        let got = asbuilt_io::read_design(&path, Units::Metres).unwrap();
        assert_eq!(got.vertices, want.vertices, "{encoding}");
        assert_eq!(got.triangles, want.triangles, "{encoding}");
    }
}

#[test]
fn broken_ply_designs_are_clear_errors_and_claim_no_memory() {
    let dir = tempfile::tempdir().unwrap();
    let good = dir.path().join("good.ply");
    write_odd_ply(&good, "ascii");
    let text = std::fs::read_to_string(&good).unwrap();
    let cases = [
        (
            text.replace("element edge 1", "element edge 4000000000000"),
            "the file ends at edge 1 of 4000000000000",
        ),
        (
            text.replacen("200 \n", "two hundred\n", 1),
            "vertex 0 (line 22)",
        ),
        (
            text.replace("vertex_indices", "corners"),
            "no `vertex_indices` list",
        ),
        (text.replace("property double y\n", ""), "needs x, y and z"),
    ];
    for (i, (content, says)) in cases.iter().enumerate() {
        let path = dir.path().join(format!("broken{i}.ply"));
        std::fs::write(&path, content).unwrap();
        let e = asbuilt_io::read_design(&path, Units::Metres).unwrap_err();
        assert!(matches!(e, IoError::Malformed { .. }), "{e}");
        let msg = e.to_string();
        assert!(
            msg.contains(says) && msg.contains(&format!("broken{i}.ply")),
            "{msg}"
        );
    }
    // Cut short in binary, and a header that promises far more vertices than the file holds
    // (room is made as they come, not on the header's word): errors, not a mesh of what came.
    let bin = dir.path().join("cut.ply");
    write_odd_ply(&bin, "binary_little_endian");
    let bytes = std::fs::read(&bin).unwrap();
    std::fs::write(&bin, &bytes[..bytes.len() - 40]).unwrap();
    let e = asbuilt_io::read_design(&bin, Units::Metres).unwrap_err();
    assert!(e.to_string().contains("ends at face 28 of 30"), "{e}");
    let at = bytes
        .windows(17)
        .position(|w| w == b"element vertex 40")
        .unwrap();
    let mut huge = bytes[..at].to_vec();
    huge.extend(b"element vertex 4000000000000");
    huge.extend(&bytes[at + 17..]);
    std::fs::write(&bin, huge).unwrap();
    let e = asbuilt_io::read_design(&bin, Units::Metres).unwrap_err();
    assert!(
        e.to_string().contains("of 4000000000000 (truncated?)"),
        "{e}"
    );
}
