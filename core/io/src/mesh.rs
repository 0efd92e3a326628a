//! Design meshes: STL (binary or ASCII), OBJ and PLY, from a file or from bytes, in the units
//! the caller declares.

use std::fs::File;
use std::io::{BufRead, BufReader, Cursor};
use std::path::{Path, PathBuf};

use asbuilt_core::{Design, DesignError, Units};
use nalgebra::Point3;

use crate::IoError;
use crate::ply::read::{Property, Record, Records, Value, header, place, whole};
use crate::scan::error::{Context, ScanError, bail};

/// Mesh file formats a design can come in.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum MeshFormat {
    /// Binary or ASCII STL.
    Stl,
    /// Wavefront OBJ (faces with more than three vertices are fanned into triangles).
    Obj,
    /// PLY, binary or ASCII, with a `face` element.
    Ply,
}

const EXPECTED: &str = ".stl (binary or ASCII), .obj or .ply (a triangle mesh)";

impl MeshFormat {
    /// The format a file name's extension says, if it names one.
    pub fn from_path(path: &Path) -> Option<Self> {
        let ext = path.extension()?.to_str()?.to_ascii_lowercase();
        match ext.as_str() {
            "stl" => Some(Self::Stl),
            "obj" => Some(Self::Obj),
            "ply" => Some(Self::Ply),
            _ => None,
        }
    }

    fn name(self) -> &'static str {
        match self {
            MeshFormat::Stl => "STL",
            MeshFormat::Obj => "OBJ",
            MeshFormat::Ply => "PLY",
        }
    }
}

/// Reads a design file whose coordinates are in `units`: vertices at one position are merged
/// and degenerate triangles dropped (the design's report counts both).
pub fn read_design(path: &Path, units: Units) -> Result<Design, IoError> {
    let format = format_of(path)?;
    IoError::require_file(path, "design")?;
    let file = File::open(path).map_err(|source| IoError::Open {
        path: path.to_path_buf(),
        source,
    })?;
    let mesh = parse(BufReader::new(file), format, path)?;
    design(mesh, units, path)
}

/// The design file's bytes, checked as [`read_design`] checks the file (a known format, a file
/// that is there), for a caller that keeps them: to hash, attach, or key a cache by. They read
/// with [`read_design_bytes`] under the path's name.
pub fn read_design_file(path: &Path) -> Result<Vec<u8>, IoError> {
    format_of(path)?;
    IoError::require_file(path, "design")?;
    std::fs::read(path).map_err(|source| IoError::Open {
        path: path.to_path_buf(),
        source,
    })
}

/// [`read_design`] for a design held in memory (one attached to a recording): `name` is the
/// file name it had, which gives its format and names it in errors.
pub fn read_design_bytes(bytes: &[u8], name: &str, units: Units) -> Result<Design, IoError> {
    let path = PathBuf::from(name);
    let format = format_of(&path)?;
    let mesh = parse(Cursor::new(bytes), format, &path)?;
    design(mesh, units, &path)
}

fn format_of(path: &Path) -> Result<MeshFormat, IoError> {
    MeshFormat::from_path(path).ok_or_else(|| IoError::UnknownFormat {
        path: path.to_path_buf(),
        kind: "design",
        extension: path
            .extension()
            .map(|e| e.to_string_lossy().into_owned())
            .unwrap_or_default(),
        expected: EXPECTED,
    })
}

fn design(mesh: Mesh, units: Units, path: &Path) -> Result<Design, IoError> {
    let (vertices, triangles) = mesh;
    Design::from_indexed(vertices, triangles, units.scale()).map_err(|e| match e {
        DesignError::Empty => IoError::EmptyDesign {
            path: path.to_path_buf(),
        },
    })
}

type Mesh = (Vec<Point3<f64>>, Vec<[u32; 3]>);

fn parse<R: BufRead + std::io::Seek>(
    mut reader: R,
    format: MeshFormat,
    path: &Path,
) -> Result<Mesh, IoError> {
    let malformed = |what: String| IoError::Malformed {
        path: path.to_path_buf(),
        format: format.name(),
        what,
    };
    match format {
        MeshFormat::Stl => {
            let mesh = stl_io::read_stl(&mut reader).map_err(|e| malformed(e.to_string()))?;
            let vertices = mesh
                .vertices
                .iter()
                .map(|v| Point3::new(v[0] as f64, v[1] as f64, v[2] as f64))
                .collect();
            let triangles = mesh
                .faces
                .iter()
                .map(|f| f.vertices.map(|i| i as u32))
                .collect();
            Ok((vertices, triangles))
        }
        MeshFormat::Obj => {
            let options = tobj::LoadOptions {
                triangulate: true,
                single_index: false,
                ignore_points: true,
                ignore_lines: true,
            };
            // Materials do not shape a design: a missing .mtl is not an error.
            let (models, _) = tobj::load_obj_buf(&mut reader, &options, |_| {
                Err(tobj::LoadError::OpenFileFailed)
            })
            .map_err(|e| malformed(e.to_string()))?;
            let mut vertices = Vec::new();
            let mut triangles = Vec::new();
            for m in models {
                let base = vertices.len() as u32;
                let pos = &m.mesh.positions;
                vertices.extend(
                    pos.chunks_exact(3)
                        .map(|c| Point3::new(c[0] as f64, c[1] as f64, c[2] as f64)),
                );
                triangles.extend(
                    m.mesh
                        .indices
                        .chunks_exact(3)
                        .map(|t| [t[0] + base, t[1] + base, t[2] + base]),
                );
            }
            Ok((vertices, triangles))
        }
        MeshFormat::Ply => ply_mesh(reader, path).map_err(|e| malformed(e.to_string())),
    }
}

/// A PLY mesh: the `vertex` element's x, y, z and each `face`'s `vertex_indices` (or
/// `vertex_index`), polygons fanned into triangles; other elements are passed over.
fn ply_mesh(mut reader: impl BufRead, path: &Path) -> Result<Mesh, ScanError> {
    let h = header(&mut reader, path)?;
    let vi = h.vertex_element(path)?;
    let vertex = &h.elements[vi];
    let xyz = ["x", "y", "z"].map(|k| vertex.scalar(&[k]));
    if xyz.contains(&None) {
        bail!("the vertex element needs x, y and z");
    }
    let face = h.element("face");
    let indices = face
        .map(|f| {
            h.elements[f]
                .properties
                .iter()
                .position(|p| {
                    matches!(p, Property::List { name, .. }
                        if name == "vertex_indices" || name == "vertex_index")
                })
                .with_context(|| "the face element has no `vertex_indices` list")
        })
        .transpose()?;
    let mut records = Records::new(reader, h.encoding);
    // Counts are the header's word: room is made as records come, never on its say alone.
    let room = |n: u64| n.min(1 << 20) as usize;
    let mut vertices = Vec::with_capacity(room(vertex.count));
    let mut triangles = Vec::new();
    let mut list: Vec<u32> = Vec::new();
    let mut line = h.lines;
    for (ei, e) in h.elements.iter().enumerate() {
        if Some(ei) == face {
            triangles.reserve(room(e.count));
        }
        for r in 0..e.count {
            line += 1;
            let mut p = [f64::NAN; 3];
            list.clear();
            let read = records.next(e, &mut |v| match v {
                Value::Scalar(k, x) if ei == vi => place(&mut p, xyz, k, x),
                // A negative or fractional index is caught as invalid with the others.
                Value::Item(k, x) if Some(k) == indices && Some(ei) == face => {
                    list.push(whole(x).unwrap_or(u32::MAX))
                }
                _ => {}
            })?;
            match read {
                Record::Read => {}
                Record::Malformed => bail!(
                    "{} {r} (line {line}) is not the numbers the header declares",
                    e.name
                ),
                Record::End => bail!(
                    "the file ends at {} {r} of {} (truncated?)",
                    e.name,
                    e.count
                ),
            }
            if ei == vi {
                vertices.push(Point3::from(p));
            } else if Some(ei) == face {
                for k in 1..list.len().saturating_sub(1) {
                    triangles.push([list[0], list[k], list[k + 1]]);
                }
            }
        }
    }
    Ok((vertices, triangles))
}
