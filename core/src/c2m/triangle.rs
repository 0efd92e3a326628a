//! Closest point on a triangle, with the Voronoi region it falls in (Ericson, *Real-Time
//! Collision Detection*, 5.1.5). The region names the feature whose pseudo-normal signs the
//! distance.

use nalgebra::{Point3, Vector3};

/// Where on a triangle `(v0, v1, v2)` the closest point lies.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Region {
    Face,
    /// Edge `i` runs from vertex `i` to vertex `(i + 1) % 3`.
    Edge(u8),
    Vertex(u8),
}

/// A triangle prepared for repeated closest-point queries.
#[derive(Debug, Clone, Copy)]
pub struct Triangle {
    pub a: Point3<f64>,
    pub ab: Vector3<f64>,
    pub ac: Vector3<f64>,
}

impl Triangle {
    pub fn new(a: Point3<f64>, b: Point3<f64>, c: Point3<f64>) -> Self {
        Self {
            a,
            ab: b - a,
            ac: c - a,
        }
    }

    pub fn b(&self) -> Point3<f64> {
        self.a + self.ab
    }

    pub fn c(&self) -> Point3<f64> {
        self.a + self.ac
    }

    /// Where the ray `o + t · dir` crosses the triangle, as `t` (Möller and Trumbore 1997);
    /// `None` when it misses or runs parallel to the plane.
    #[inline]
    pub fn ray_hit(&self, o: &Point3<f64>, dir: &Vector3<f64>) -> Option<f64> {
        let p = dir.cross(&self.ac);
        let det = self.ab.dot(&p);
        if det.abs() < 1e-300 {
            return None;
        }
        let inv = 1.0 / det;
        let s = o - self.a;
        let u = s.dot(&p) * inv;
        if !(0.0..=1.0).contains(&u) {
            return None;
        }
        let q = s.cross(&self.ab);
        let v = dir.dot(&q) * inv;
        if v < 0.0 || u + v > 1.0 {
            return None;
        }
        Some(self.ac.dot(&q) * inv)
    }

    /// The closest point of the triangle to `p` and the region it lies in.
    #[inline(always)]
    pub fn closest_point(&self, p: &Point3<f64>) -> (Point3<f64>, Region) {
        let (a, ab, ac) = (&self.a, &self.ab, &self.ac);
        let ap = p - a;
        let d1 = ab.dot(&ap);
        let d2 = ac.dot(&ap);
        if d1 <= 0.0 && d2 <= 0.0 {
            return (*a, Region::Vertex(0));
        }
        let bp = ap - ab;
        let d3 = ab.dot(&bp);
        let d4 = ac.dot(&bp);
        if d3 >= 0.0 && d4 <= d3 {
            return (a + ab, Region::Vertex(1));
        }
        let vc = d1 * d4 - d3 * d2;
        if vc <= 0.0 && d1 >= 0.0 && d3 <= 0.0 {
            let v = d1 / (d1 - d3);
            return (a + ab * v, Region::Edge(0));
        }
        let cp = ap - ac;
        let d5 = ab.dot(&cp);
        let d6 = ac.dot(&cp);
        if d6 >= 0.0 && d5 <= d6 {
            return (a + ac, Region::Vertex(2));
        }
        let vb = d5 * d2 - d1 * d6;
        if vb <= 0.0 && d2 >= 0.0 && d6 <= 0.0 {
            let w = d2 / (d2 - d6);
            return (a + ac * w, Region::Edge(2));
        }
        let va = d3 * d6 - d5 * d4;
        if va <= 0.0 && (d4 - d3) >= 0.0 && (d5 - d6) >= 0.0 {
            let w = (d4 - d3) / ((d4 - d3) + (d5 - d6));
            return (a + ab + (ac - ab) * w, Region::Edge(1));
        }
        let denom = 1.0 / (va + vb + vc);
        let v = vb * denom;
        let w = vc * denom;
        (a + ab * v + ac * w, Region::Face)
    }

    /// The triangle's axis-aligned bounding box.
    #[inline]
    pub fn aabb(&self) -> (Point3<f64>, Point3<f64>) {
        let b = self.b();
        let c = self.c();
        (self.a.inf(&b).inf(&c), self.a.sup(&b).sup(&c))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn tri() -> Triangle {
        Triangle::new(
            Point3::new(0.0, 0.0, 0.0),
            Point3::new(1.0, 0.0, 0.0),
            Point3::new(0.0, 1.0, 0.0),
        )
    }

    #[test]
    fn regions_of_a_right_triangle() {
        let t = tri();
        let cases = [
            ((0.2, 0.2, 1.0), (0.2, 0.2, 0.0), Region::Face),
            ((-1.0, -1.0, 0.5), (0.0, 0.0, 0.0), Region::Vertex(0)),
            ((2.0, -0.5, 0.0), (1.0, 0.0, 0.0), Region::Vertex(1)),
            ((-0.1, 3.0, 0.0), (0.0, 1.0, 0.0), Region::Vertex(2)),
            ((0.5, -2.0, 0.0), (0.5, 0.0, 0.0), Region::Edge(0)),
            ((1.0, 1.0, 0.0), (0.5, 0.5, 0.0), Region::Edge(1)),
            ((-3.0, 0.25, 1.0), (0.0, 0.25, 0.0), Region::Edge(2)),
        ];
        for ((x, y, z), (qx, qy, qz), region) in cases {
            let (q, r) = t.closest_point(&Point3::new(x, y, z));
            assert_eq!(r, region, "point ({x},{y},{z})");
            assert!((q - Point3::new(qx, qy, qz)).norm() < 1e-15, "{q:?}");
        }
    }
}
