//! The planar faces of a design, each with axes in its plane: `u` along the layers
//! (horizontal on a wall), `v` across them.

use nalgebra::{Point3, Unit, Vector3};

use crate::Design;

/// One planar face: coplanar triangles facing the same way.
#[derive(Debug, Clone)]
pub struct Face {
    /// Outward normal.
    pub normal: Unit<Vector3<f64>>,
    /// A point of the plane: where `u` and `v` are measured from.
    pub origin: Point3<f64>,
    /// In the plane, along the layers (horizontal unless the face is a top or bottom).
    pub u: Unit<Vector3<f64>>,
    /// In the plane, across the layers.
    pub v: Unit<Vector3<f64>>,
    /// The face's extent in `u` and `v`, metres: `[u_min, u_max]`, `[v_min, v_max]`.
    pub extent: [[f64; 2]; 2],
    /// Its area, m².
    pub area: f64,
}

impl Face {
    /// `p` in the face's coordinates: along `u`, along `v`, and out along the normal.
    pub fn coordinates(&self, p: &Point3<f64>) -> [f64; 3] {
        let d = p - self.origin;
        [d.dot(&self.u), d.dot(&self.v), d.dot(&self.normal)]
    }

    /// The point at `u`, `v` on the face.
    pub fn point(&self, u: f64, v: f64) -> Point3<f64> {
        self.origin + self.u.into_inner() * u + self.v.into_inner() * v
    }

    /// Its size along `u` and along `v`, metres.
    pub fn size(&self) -> [f64; 2] {
        [
            self.extent[0][1] - self.extent[0][0],
            self.extent[1][1] - self.extent[1][0],
        ]
    }
}

/// The design's planar faces of at least `min_area` m², and the face of each triangle.
#[derive(Debug, Clone)]
pub struct PlanarFaces {
    /// The faces, largest first.
    pub faces: Vec<Face>,
    /// Per design triangle, its face's index, or `None` (curved, or part of a small face).
    pub of_triangle: Vec<Option<u32>>,
}

impl PlanarFaces {
    /// Groups `design`'s triangles by plane: normals within about 0.06° and plane offsets
    /// within 1 mm make one face, so two coplanar patches apart count as one. A curved
    /// surface's triangles each make a face of their own, below `min_area`. The face the part
    /// stands on (facing down at its lowest height) is left out: no scan sees it, and points
    /// at the foot of a wall would be read against it.
    pub fn of(design: &Design, min_area: f64) -> Self {
        use std::collections::HashMap;
        let lowest = design.bounds().0.z;
        let mut groups: HashMap<[i64; 4], (Vec<u32>, f64)> = HashMap::new();
        for (k, t) in design.triangles.iter().enumerate() {
            let [a, b, c] = t.map(|i| design.vertices[i as usize]);
            let cross = (b - a).cross(&(c - a));
            let area = 0.5 * cross.norm();
            if area <= 0.0 {
                continue;
            }
            let n = cross / (2.0 * area);
            let bed = n.z < -0.99 && [a, b, c].iter().all(|p| (p.z - lowest).abs() < 1e-3);
            if bed {
                continue;
            }
            let key = [
                (n.x * 1e3).round() as i64,
                (n.y * 1e3).round() as i64,
                (n.z * 1e3).round() as i64,
                (n.dot(&a.coords) * 1e3).round() as i64,
            ];
            let g = groups.entry(key).or_default();
            g.0.push(k as u32);
            g.1 += area;
        }
        let mut kept: Vec<(Vec<u32>, f64)> =
            groups.into_values().filter(|g| g.1 >= min_area).collect();
        kept.sort_by(|a, b| b.1.total_cmp(&a.1).then(a.0[0].cmp(&b.0[0])));
        let mut of_triangle = vec![None; design.triangles.len()];
        let faces = kept
            .iter()
            .enumerate()
            .map(|(f, (tris, area))| {
                for &t in tris {
                    of_triangle[t as usize] = Some(f as u32);
                }
                face_of(design, tris, *area)
            })
            .collect();
        Self { faces, of_triangle }
    }
}

fn face_of(design: &Design, tris: &[u32], area: f64) -> Face {
    let t0 = design.triangles[tris[0] as usize].map(|i| design.vertices[i as usize]);
    let normal = Unit::new_normalize((t0[1] - t0[0]).cross(&(t0[2] - t0[0])));
    // Along the layers: horizontal in the plane; a top or bottom takes x.
    let horizontal = Vector3::z().cross(&normal);
    let u = if horizontal.norm() > 0.1 {
        Unit::new_normalize(horizontal)
    } else {
        Unit::new_normalize(Vector3::x() - normal.into_inner() * normal.x)
    };
    let v = Unit::new_normalize(normal.cross(&u));
    let origin = t0[0];
    let mut extent = [[f64::INFINITY, f64::NEG_INFINITY]; 2];
    for &t in tris {
        for &i in &design.triangles[t as usize] {
            let d = design.vertices[i as usize] - origin;
            for (k, axis) in [u, v].iter().enumerate() {
                let x = d.dot(axis);
                extent[k][0] = extent[k][0].min(x);
                extent[k][1] = extent[k][1].max(x);
            }
        }
    }
    Face {
        normal,
        origin,
        u,
        v,
        extent,
        area,
    }
}
