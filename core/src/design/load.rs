use std::fs::File;
use std::io::BufReader;
use std::path::{Path, PathBuf};

use nalgebra::Point3;
use ply_rs_bw::parser::Parser;
use ply_rs_bw::ply::{DefaultElement, Property};

/// Mesh file formats a design can come in.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum MeshFormat {
    Stl,
    Obj,
    Ply,
}

impl MeshFormat {
    pub fn from_path(path: &Path) -> Option<Self> {
        let ext = path.extension()?.to_str()?.to_ascii_lowercase();
        match ext.as_str() {
            "stl" => Some(Self::Stl),
            "obj" => Some(Self::Obj),
            "ply" => Some(Self::Ply),
            _ => None,
        }
    }
}

#[derive(Debug, thiserror::Error)]
pub enum DesignError {
    #[error("cannot open design file {path}: {source}")]
    Open {
        path: PathBuf,
        source: std::io::Error,
    },
    #[error(
        "design file {path} has an unknown extension: use a .stl (binary or ASCII), .obj or .ply \
         triangle mesh"
    )]
    UnknownFormat { path: PathBuf },
    #[error("cannot read design file {path} as {format:?}: {reason}")]
    Parse {
        path: PathBuf,
        format: MeshFormat,
        reason: String,
    },
    #[error(
        "design file {path} has no usable triangles (empty, or every triangle degenerate): \
         export the surface as a triangle mesh"
    )]
    Empty { path: PathBuf },
}

type Mesh = (Vec<Point3<f64>>, Vec<[u32; 3]>);

pub(super) fn read_mesh(path: &Path) -> Result<Mesh, DesignError> {
    let format = MeshFormat::from_path(path).ok_or_else(|| DesignError::UnknownFormat {
        path: path.to_path_buf(),
    })?;
    let parse = |reason: String| DesignError::Parse {
        path: path.to_path_buf(),
        format,
        reason,
    };
    let open = || {
        File::open(path).map_err(|source| DesignError::Open {
            path: path.to_path_buf(),
            source,
        })
    };
    match format {
        MeshFormat::Stl => {
            let mut reader = BufReader::new(open()?);
            let mesh = stl_io::read_stl(&mut reader).map_err(|e| parse(e.to_string()))?;
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
            open()?;
            let options = tobj::LoadOptions {
                triangulate: true,
                single_index: false,
                ignore_points: true,
                ignore_lines: true,
            };
            let (models, _) = tobj::load_obj(path, &options).map_err(|e| parse(e.to_string()))?;
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
        MeshFormat::Ply => {
            let mut reader = BufReader::new(open()?);
            let ply = Parser::<DefaultElement>::new()
                .read_ply(&mut reader)
                .map_err(|e| parse(e.to_string()))?;
            let vertex_el = ply
                .payload
                .get("vertex")
                .ok_or_else(|| parse("no `vertex` element".into()))?;
            let mut vertices = Vec::with_capacity(vertex_el.len());
            for (i, v) in vertex_el.iter().enumerate() {
                let coord = |k: &str| {
                    v.get(k)
                        .and_then(ply_scalar)
                        .ok_or_else(|| parse(format!("vertex {i} has no numeric `{k}`")))
                };
                vertices.push(Point3::new(coord("x")?, coord("y")?, coord("z")?));
            }
            let mut triangles = Vec::new();
            if let Some(faces) = ply.payload.get("face") {
                for (i, f) in faces.iter().enumerate() {
                    let list = f
                        .get("vertex_indices")
                        .or_else(|| f.get("vertex_index"))
                        .and_then(index_list)
                        .ok_or_else(|| parse(format!("face {i} has no `vertex_indices` list")))?;
                    // Fan-triangulate polygons; a negative index is caught as invalid later.
                    for k in 1..list.len().saturating_sub(1) {
                        triangles.push([list[0], list[k], list[k + 1]]);
                    }
                }
            }
            Ok((vertices, triangles))
        }
    }
}

/// A numeric PLY property as f64 (exact for every PLY scalar type); `None` for a list.
pub fn ply_scalar(p: &Property) -> Option<f64> {
    Some(match *p {
        Property::Float(v) => v as f64,
        Property::Double(v) => v,
        Property::Char(v) => v as f64,
        Property::UChar(v) => v as f64,
        Property::Short(v) => v as f64,
        Property::UShort(v) => v as f64,
        Property::Int(v) => v as f64,
        Property::UInt(v) => v as f64,
        _ => return None,
    })
}

fn index_list(p: &Property) -> Option<Vec<u32>> {
    let to_u32 = |v: i64| u32::try_from(v).unwrap_or(u32::MAX);
    Some(match p {
        Property::ListInt(v) => v.iter().map(|&i| to_u32(i as i64)).collect(),
        Property::ListUInt(v) => v.clone(),
        Property::ListUChar(v) => v.iter().map(|&i| i as u32).collect(),
        Property::ListChar(v) => v.iter().map(|&i| to_u32(i as i64)).collect(),
        Property::ListShort(v) => v.iter().map(|&i| to_u32(i as i64)).collect(),
        Property::ListUShort(v) => v.iter().map(|&i| i as u32).collect(),
        _ => return None,
    })
}
