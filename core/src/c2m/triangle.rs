//! Closest point on a triangle, with the Voronoi region it falls in (Ericson, *Real-Time
//! Collision Detection*, 5.1.5). The region names the feature whose pseudo-normal signs the
//! distance.

use nalgebra::{Point3, Vector3};

use crate::simd::has_avx2;

/// Where on a triangle `(v0, v1, v2)` the closest point lies.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Region {
    /// Inside the triangle.
    Face,
    /// Edge `i` runs from vertex `i` to vertex `(i + 1) % 3`.
    Edge(u8),
    /// Vertex `i`.
    Vertex(u8),
}

/// A triangle prepared for repeated closest-point queries.
#[derive(Debug, Clone, Copy)]
pub struct Triangle {
    /// Vertex 0.
    pub a: Point3<f64>,
    /// Vertex 1 minus vertex 0.
    pub ab: Vector3<f64>,
    /// Vertex 2 minus vertex 0.
    pub ac: Vector3<f64>,
}

impl Triangle {
    /// The triangle `(a, b, c)`.
    pub fn new(a: Point3<f64>, b: Point3<f64>, c: Point3<f64>) -> Self {
        Self {
            a,
            ab: b - a,
            ac: c - a,
        }
    }

    /// Vertex 1.
    pub fn b(&self) -> Point3<f64> {
        self.a + self.ab
    }

    /// Vertex 2.
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

    /// Squared distance from `p` to the triangle, as every search compares triangles (the
    /// grid's lists, the BVH, brute force): [`Lanes::dist2`] for one lane, so the bits are the
    /// same whichever path measured it.
    #[inline(always)]
    pub fn dist2(&self, p: &Point3<f64>) -> f64 {
        let mut one = Lanes::<1>::default();
        one.set(0, self);
        one.dist2(p)[0]
    }

    /// The triangle's axis-aligned bounding box.
    #[inline]
    pub fn aabb(&self) -> (Point3<f64>, Point3<f64>) {
        let b = self.b();
        let c = self.c();
        (self.a.inf(&b).inf(&c), self.a.sup(&b).sup(&c))
    }
}

/// `N` triangles side by side, coordinate by coordinate, so that their distances to a point are
/// measured together (the compiler turns the lanes into vector instructions).
#[derive(Debug, Clone, Copy)]
pub struct Lanes<const N: usize> {
    a: [[f64; N]; 3],
    ab: [[f64; N]; 3],
    ac: [[f64; N]; 3],
}

impl<const N: usize> Default for Lanes<N> {
    fn default() -> Self {
        Self {
            a: [[0.0; N]; 3],
            ab: [[0.0; N]; 3],
            ac: [[0.0; N]; 3],
        }
    }
}

impl<const N: usize> Lanes<N> {
    /// Puts `t` into lane `lane`.
    #[inline(always)]
    pub fn set(&mut self, lane: usize, t: &Triangle) {
        for k in 0..3 {
            self.a[k][lane] = t.a[k];
            self.ab[k][lane] = t.ab[k];
            self.ac[k][lane] = t.ac[k];
        }
    }

    /// Puts the triangle `face` of `vertices` into lane `lane`, as [`Lanes::set`] puts
    /// [`Triangle::new`] of its corners.
    #[inline(always)]
    pub fn set_face(&mut self, lane: usize, vertices: &[Point3<f64>], face: &[u32; 3]) {
        let [a, b, c] = face.map(|i| vertices[i as usize]);
        for k in 0..3 {
            self.a[k][lane] = a[k];
            self.ab[k][lane] = b[k] - a[k];
            self.ac[k][lane] = c[k] - a[k];
        }
    }

    /// Squared distance from `p` to each lane's triangle. The closest point is
    /// `a + s·ab + t·ac`, with `(s, t)` of the Voronoi region [`Triangle::closest_point`]
    /// picks, by the same tests in the same order; every region's `(s, t)` is computed and the
    /// first region that holds is kept, without branches.
    #[inline(always)]
    pub fn dist2(&self, p: &Point3<f64>) -> [f64; N] {
        let mut out = [0.0; N];
        for (l, o) in out.iter_mut().enumerate() {
            let [bx, by, bz] = [self.ab[0][l], self.ab[1][l], self.ab[2][l]];
            let [cx, cy, cz] = [self.ac[0][l], self.ac[1][l], self.ac[2][l]];
            // p − a, p − b and p − c.
            let [px, py, pz] = [p.x - self.a[0][l], p.y - self.a[1][l], p.z - self.a[2][l]];
            let [qx, qy, qz] = [px - bx, py - by, pz - bz];
            let [rx, ry, rz] = [px - cx, py - cy, pz - cz];
            let d1 = bx * px + by * py + bz * pz;
            let d2 = cx * px + cy * py + cz * pz;
            let d3 = bx * qx + by * qy + bz * qz;
            let d4 = cx * qx + cy * qy + cz * qz;
            let d5 = bx * rx + by * ry + bz * rz;
            let d6 = cx * rx + cy * ry + cz * rz;
            let vc = d1 * d4 - d3 * d2;
            let vb = d5 * d2 - d1 * d6;
            let va = d3 * d6 - d5 * d4;
            // From the last region tested to the first, so that the first that holds wins.
            let denom = 1.0 / (va + vb + vc);
            let (mut s, mut t) = (vb * denom, vc * denom);
            let w = (d4 - d3) / ((d4 - d3) + (d5 - d6));
            if va <= 0.0 && (d4 - d3) >= 0.0 && (d5 - d6) >= 0.0 {
                (s, t) = (1.0 - w, w);
            }
            let w = d2 / (d2 - d6);
            if vb <= 0.0 && d2 >= 0.0 && d6 <= 0.0 {
                (s, t) = (0.0, w);
            }
            if d6 >= 0.0 && d5 <= d6 {
                (s, t) = (0.0, 1.0);
            }
            let v = d1 / (d1 - d3);
            if vc <= 0.0 && d1 >= 0.0 && d3 <= 0.0 {
                (s, t) = (v, 0.0);
            }
            if d3 >= 0.0 && d4 <= d3 {
                (s, t) = (1.0, 0.0);
            }
            if d1 <= 0.0 && d2 <= 0.0 {
                (s, t) = (0.0, 0.0);
            }
            let [dx, dy, dz] = [
                px - s * bx - t * cx,
                py - s * by - t * cy,
                pz - s * bz - t * cz,
            ];
            *o = dx * dx + dy * dy + dz * dz;
        }
        out
    }
}

impl Lanes<4> {
    /// Four triangles of `vertices` into the lanes, as [`Lanes::set_face`] puts each: with
    /// AVX2, each corner is loaded whole and the four are transposed into lanes, and the edges
    /// are subtracted four at a time (the same subtractions, so the same bits).
    #[inline(always)]
    pub fn set_faces(&mut self, vertices: &[Point3<f64>], faces: [&[u32; 3]; 4]) {
        #[cfg(target_arch = "x86_64")]
        if has_avx2() {
            // SAFETY: the CPU has AVX2.
            return unsafe { self.set_faces_avx2(vertices, faces) };
        }
        for (l, f) in faces.iter().enumerate() {
            self.set_face(l, vertices, f);
        }
    }

    /// [`Lanes::set_faces`] with AVX2 instructions, compiled into its caller (which runs with
    /// AVX2: a function of its own would be left out of line).
    ///
    /// # Safety
    /// The CPU must have AVX2.
    #[cfg(target_arch = "x86_64")]
    #[inline(always)]
    unsafe fn set_faces_avx2(&mut self, vertices: &[Point3<f64>], faces: [&[u32; 3]; 4]) {
        use std::arch::x86_64::*;
        // SAFETY: this function's caller guarantees AVX2, which is all `corner_avx2` needs (it
        // indexes `vertices` with bounds checks and masks the load past each point).
        let (a, b, c) = unsafe {
            (
                corner_avx2(vertices, faces, 0),
                corner_avx2(vertices, faces, 1),
                corner_avx2(vertices, faces, 2),
            )
        };
        for k in 0..3 {
            // SAFETY: the CPU has AVX2, and each row is four f64.
            unsafe {
                _mm256_storeu_pd(self.a[k].as_mut_ptr(), a[k]);
                _mm256_storeu_pd(self.ab[k].as_mut_ptr(), _mm256_sub_pd(b[k], a[k]));
                _mm256_storeu_pd(self.ac[k].as_mut_ptr(), _mm256_sub_pd(c[k], a[k]));
            }
        }
    }
}

/// Corner `k` of four triangles as columns x, y, z: each point loaded whole as a row
/// (x, y, z, 0), the four rows transposed.
///
/// # Safety
/// The CPU must have AVX2.
#[cfg(target_arch = "x86_64")]
#[inline(always)]
unsafe fn corner_avx2(
    vertices: &[Point3<f64>],
    faces: [&[u32; 3]; 4],
    k: usize,
) -> [std::arch::x86_64::__m256d; 3] {
    use std::arch::x86_64::*;
    // SAFETY: the CPU has AVX2; a point is three f64 in a row, and the fourth lane is masked
    // off, so nothing past it is read.
    unsafe {
        let mask = _mm256_setr_epi64x(-1, -1, -1, 0);
        // Loaded one by one, not in a closure: a closure is compiled without AVX2 unless it
        // is inlined.
        let r0 = _mm256_maskload_pd(vertices[faces[0][k] as usize].coords.as_ptr(), mask);
        let r1 = _mm256_maskload_pd(vertices[faces[1][k] as usize].coords.as_ptr(), mask);
        let r2 = _mm256_maskload_pd(vertices[faces[2][k] as usize].coords.as_ptr(), mask);
        let r3 = _mm256_maskload_pd(vertices[faces[3][k] as usize].coords.as_ptr(), mask);
        let (t0, t1) = (_mm256_unpacklo_pd(r0, r1), _mm256_unpackhi_pd(r0, r1));
        let (t2, t3) = (_mm256_unpacklo_pd(r2, r3), _mm256_unpackhi_pd(r2, r3));
        [
            _mm256_permute2f128_pd::<0x20>(t0, t2),
            _mm256_permute2f128_pd::<0x20>(t1, t3),
            _mm256_permute2f128_pd::<0x31>(t0, t2),
        ]
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

    /// The branch-free distance agrees with the closest point's, lane by lane, in every region
    /// and for triangles without area.
    #[test]
    fn lanes_measure_as_the_closest_point_does() {
        let mut rng = crate::test_points::seeded(3);
        let mut r = |s: f64| crate::test_points::random_point(&mut rng, -s..s);
        for k in 0..20_000 {
            let (a, b) = (r(1.0), r(1.0));
            // Every fifth triangle without area: a repeated vertex or three in a row.
            let c = match k % 5 {
                0 => b,
                1 => a + (b - a) * 0.3,
                _ => r(1.0),
            };
            let tris = [
                Triangle::new(a, b, c),
                Triangle::new(c, a, b),
                Triangle::new(b, c, a),
                tri(),
            ];
            let mut lanes = Lanes::<4>::default();
            for (l, t) in tris.iter().enumerate() {
                lanes.set(l, t);
            }
            let p = r(3.0);
            let four = lanes.dist2(&p);
            for (l, t) in tris.iter().enumerate() {
                assert_eq!(four[l].to_bits(), t.dist2(&p).to_bits(), "lane {l}");
                let exact = (p - t.closest_point(&p).0).norm_squared();
                if exact.is_finite() {
                    assert!(
                        (four[l] - exact).abs() <= 1e-12 * (1.0 + exact),
                        "{} vs {exact}",
                        four[l]
                    );
                }
            }
        }
    }

    /// Four faces loaded at once measure as the four triangles set one by one, bit for bit.
    #[test]
    fn faces_load_as_triangles_set_one_by_one() {
        use rand::{Rng, SeedableRng};
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(5);
        let vertices: Vec<Point3<f64>> = (0..50)
            .map(|_| Point3::from(std::array::from_fn(|_| rng.random_range(-3.0..3.0))))
            .collect();
        for _ in 0..2_000 {
            let faces: [[u32; 3]; 4] =
                std::array::from_fn(|_| std::array::from_fn(|_| rng.random_range(0..50)));
            let mut loaded = Lanes::<4>::default();
            loaded.set_faces(&vertices, [&faces[0], &faces[1], &faces[2], &faces[3]]);
            let mut set = Lanes::<4>::default();
            for (l, f) in faces.iter().enumerate() {
                let [a, b, c] = f.map(|i| vertices[i as usize]);
                set.set(l, &Triangle::new(a, b, c));
            }
            let p = Point3::from(std::array::from_fn(|_| rng.random_range(-4.0..4.0)));
            let (x, y) = (loaded.dist2(&p), set.dist2(&p));
            assert_eq!(x.map(f64::to_bits), y.map(f64::to_bits));
        }
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
