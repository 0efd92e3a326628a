//! Analytic shapes as closed, outward-oriented meshes: ground truth for tests, and design objects
//! for the simulator.

use std::collections::HashMap;

use nalgebra::{Point3, Vector3};

use super::Design;

/// An axis-aligned box from `min` to `max`, 12 triangles.
pub fn cuboid(min: Point3<f64>, max: Point3<f64>) -> Design {
    let v: Vec<Point3<f64>> = (0..8)
        .map(|i| {
            Point3::new(
                if i & 1 == 0 { min.x } else { max.x },
                if i & 2 == 0 { min.y } else { max.y },
                if i & 4 == 0 { min.z } else { max.z },
            )
        })
        .collect();
    // Each face as a quad, counter-clockwise seen from outside.
    let quads = [
        [0, 2, 3, 1], // z = min
        [4, 5, 7, 6], // z = max
        [0, 1, 5, 4], // y = min
        [2, 6, 7, 3], // y = max
        [0, 4, 6, 2], // x = min
        [1, 3, 7, 5], // x = max
    ];
    let triangles = quads
        .iter()
        .flat_map(|q| [[q[0], q[1], q[2]], [q[0], q[2], q[3]]])
        .collect();
    Design::from_indexed(v, triangles, 1.0).expect("a box has area")
}

/// A flat square sheet in the plane z = `z`, `n × n` quads, normal +z. Open: it has a boundary.
pub fn sheet(half_size: f64, z: f64, n: u32) -> Design {
    let mut v = Vec::new();
    for j in 0..=n {
        for i in 0..=n {
            let s = |k: u32| -half_size + 2.0 * half_size * k as f64 / n as f64;
            v.push(Point3::new(s(i), s(j), z));
        }
    }
    let id = |i: u32, j: u32| j * (n + 1) + i;
    let mut t = Vec::new();
    for j in 0..n {
        for i in 0..n {
            t.push([id(i, j), id(i + 1, j), id(i + 1, j + 1)]);
            t.push([id(i, j), id(i + 1, j + 1), id(i, j + 1)]);
        }
    }
    Design::from_indexed(v, t, 1.0).expect("a sheet has area")
}

/// A geodesic sphere: an icosahedron subdivided `subdivisions` times, every vertex at `radius`
/// from `center`. 20 · 4^subdivisions triangles.
pub fn icosphere(center: Point3<f64>, radius: f64, subdivisions: u32) -> Design {
    let p = (1.0 + 5f64.sqrt()) / 2.0;
    let mut v: Vec<Vector3<f64>> = [
        [-1.0, p, 0.0],
        [1.0, p, 0.0],
        [-1.0, -p, 0.0],
        [1.0, -p, 0.0],
        [0.0, -1.0, p],
        [0.0, 1.0, p],
        [0.0, -1.0, -p],
        [0.0, 1.0, -p],
        [p, 0.0, -1.0],
        [p, 0.0, 1.0],
        [-p, 0.0, -1.0],
        [-p, 0.0, 1.0],
    ]
    .iter()
    .map(|c| Vector3::from(*c).normalize())
    .collect();
    let mut t: Vec<[u32; 3]> = vec![
        [0, 11, 5],
        [0, 5, 1],
        [0, 1, 7],
        [0, 7, 10],
        [0, 10, 11],
        [1, 5, 9],
        [5, 11, 4],
        [11, 10, 2],
        [10, 7, 6],
        [7, 1, 8],
        [3, 9, 4],
        [3, 4, 2],
        [3, 2, 6],
        [3, 6, 8],
        [3, 8, 9],
        [4, 9, 5],
        [2, 4, 11],
        [6, 2, 10],
        [8, 6, 7],
        [9, 8, 1],
    ];
    for _ in 0..subdivisions {
        let mut mid: HashMap<(u32, u32), u32> = HashMap::new();
        let mut midpoint = |a: u32, b: u32, v: &mut Vec<Vector3<f64>>| {
            *mid.entry((a.min(b), a.max(b))).or_insert_with(|| {
                v.push((v[a as usize] + v[b as usize]).normalize());
                (v.len() - 1) as u32
            })
        };
        let mut next = Vec::with_capacity(t.len() * 4);
        for [a, b, c] in t {
            let ab = midpoint(a, b, &mut v);
            let bc = midpoint(b, c, &mut v);
            let ca = midpoint(c, a, &mut v);
            next.extend([[a, ab, ca], [b, bc, ab], [c, ca, bc], [ab, bc, ca]]);
        }
        t = next;
    }
    let v = v.iter().map(|d| center + d * radius).collect();
    Design::from_indexed(v, t, 1.0).expect("a sphere has area")
}

/// A truncated cone standing on the plane z = `base.z`: radius `r_base` at the bottom, `r_top`
/// at `height` above, `segments` facets around, closed by a top disc. With `bottom` false it is
/// open underneath, to stand on another part's face without an internal face.
pub fn frustum(
    base: Point3<f64>,
    r_base: f64,
    r_top: f64,
    height: f64,
    segments: u32,
    bottom: bool,
) -> Design {
    let n = segments.max(3);
    let mut v = Vec::with_capacity(2 * n as usize + 2);
    for (r, z) in [(r_base, base.z), (r_top, base.z + height)] {
        for i in 0..n {
            let a = std::f64::consts::TAU * i as f64 / n as f64;
            v.push(Point3::new(base.x + r * a.cos(), base.y + r * a.sin(), z));
        }
    }
    v.push(Point3::new(base.x, base.y, base.z + height));
    v.push(base);
    let (top, bot) = (2 * n, 2 * n + 1);
    let mut t = Vec::new();
    for i in 0..n {
        let j = (i + 1) % n;
        t.push([i, j, n + j]);
        t.push([i, n + j, n + i]);
        t.push([top, n + i, n + j]);
        if bottom {
            t.push([bot, j, i]);
        }
    }
    Design::from_indexed(v, t, 1.0).expect("a frustum has area")
}

/// Several designs as one mesh (no boolean union: faces inside another part stay).
pub fn merge(parts: &[Design]) -> Design {
    let mut v = Vec::new();
    let mut t = Vec::new();
    for p in parts {
        let off = v.len() as u32;
        v.extend(&p.vertices);
        t.extend(p.triangles.iter().map(|tri| tri.map(|i| i + off)));
    }
    Design::from_indexed(v, t, 1.0).expect("parts have area")
}

/// The source study's printed wall: 173.4 mm thick, 2000 mm long, 980 mm high, standing on the
/// plane z = 0 with its long side along x, centred on the origin in x and y. Metres.
pub fn study_wall() -> Design {
    let (l, t, h) = (2.0, 0.1734, 0.98);
    cuboid(
        Point3::new(-l / 2.0, -t / 2.0, 0.0),
        Point3::new(l / 2.0, t / 2.0, h),
    )
}

/// A column of elliptical section (semi-axes `a` along x and `b` along y) standing on z = 0,
/// `height` tall, its section turning by `twist_deg` from bottom to top: a free-form part whose
/// faces are nowhere parallel to an axis. `segments` around, `rings` up; closed by flat caps.
pub fn twisted_column(
    a: f64,
    b: f64,
    height: f64,
    twist_deg: f64,
    segments: u32,
    rings: u32,
) -> Design {
    let (n, m) = (segments.max(3), rings.max(1));
    let mut v = Vec::with_capacity(((m + 1) * n + 2) as usize);
    for k in 0..=m {
        let z = height * k as f64 / m as f64;
        let turn = twist_deg.to_radians() * k as f64 / m as f64;
        for i in 0..n {
            let phi = std::f64::consts::TAU * i as f64 / n as f64;
            let (x, y) = (a * phi.cos(), b * phi.sin());
            let (s, c) = turn.sin_cos();
            v.push(Point3::new(x * c - y * s, x * s + y * c, z));
        }
    }
    let bottom = v.len() as u32;
    v.push(Point3::new(0.0, 0.0, 0.0));
    let top = v.len() as u32;
    v.push(Point3::new(0.0, 0.0, height));
    let id = |k: u32, i: u32| k * n + i % n;
    let mut t = Vec::new();
    for k in 0..m {
        for i in 0..n {
            t.push([id(k, i), id(k, i + 1), id(k + 1, i + 1)]);
            t.push([id(k, i), id(k + 1, i + 1), id(k + 1, i)]);
        }
    }
    for i in 0..n {
        t.push([bottom, id(0, i + 1), id(0, i)]);
        t.push([top, id(m, i), id(m, i + 1)]);
    }
    Design::from_indexed(v, t, 1.0).expect("a column has area")
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::design::topology::Topology;

    #[test]
    fn the_study_wall_has_the_study_dimensions() {
        let w = study_wall();
        let (lo, hi) = w.bounds();
        let size = hi - lo;
        assert!((size.x - 2.0).abs() < 1e-12 && (size.y - 0.1734).abs() < 1e-12);
        assert!((size.z - 0.98).abs() < 1e-12 && lo.z == 0.0);
    }

    #[test]
    fn a_twisted_column_is_closed_outward_and_has_the_expected_area() {
        let c = twisted_column(0.15, 0.1, 1.2, 90.0, 128, 60);
        assert!(Topology::of(&c.triangles).is_closed_and_oriented());
        let (lo, hi) = c.bounds();
        assert!((hi.z - 1.2).abs() < 1e-12 && lo.z == 0.0);
        // Outward: every side face's normal points away from the axis.
        for tri in &c.triangles {
            let [p, q, r] = tri.map(|i| c.vertices[i as usize]);
            let n = (q - p).cross(&(r - p));
            let centre = (p.coords + q.coords + r.coords) / 3.0;
            if n.z.abs() < 0.5 * n.norm() {
                assert!(n.x * centre.x + n.y * centre.y > 0.0);
            }
        }
        // Untwisted, the side is an elliptic cylinder: perimeter (Ramanujan) × height.
        let s = twisted_column(0.15, 0.1, 1.2, 0.0, 512, 1);
        let (a, b) = (0.15f64, 0.1f64);
        let h3 = 3.0 * (a - b).powi(2) / (a + b).powi(2);
        let perimeter = std::f64::consts::PI * (a + b) * (1.0 + h3 / (10.0 + (4.0 - h3).sqrt()));
        let caps = 2.0 * std::f64::consts::PI * a * b;
        let area = perimeter * 1.2 + caps;
        assert!(
            (s.surface_area() - area).abs() < 1e-3 * area,
            "{}",
            s.surface_area()
        );
    }
}
