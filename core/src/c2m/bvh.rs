//! A bounding volume hierarchy over the triangles: exact closest-triangle queries under a bound,
//! balls, and segments. The grid answers most points; this answers the rest, builds the grid and
//! casts the lines of sight.
//!
//! Boxes are stored in f32, rounded outwards, so a box still holds its triangles and a distance
//! to a box is still a lower bound: searches stay exact at 32 bytes a node. Leaves hold runs of
//! the mesh's internal order, which is the order this build leaves the triangles in.

use nalgebra::{Point3, Vector3};

use super::mesh::Mesh;
use super::triangle::Lanes;
use crate::simd::avx2;

const LEAF_SIZE: usize = 8;
/// Below this many triangles a subtree is built on one thread.
const PARALLEL_MIN: usize = 16_384;

#[derive(Debug, Clone, Copy, Default)]
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize))]
struct Node {
    min: [f32; 3],
    max: [f32; 3],
    /// Leaf: first internal triangle; inner: index of the right child (the left is next).
    start: u32,
    /// Leaf: number of triangles; inner: 0.
    count: u32,
}

#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize))]
pub struct Bvh {
    nodes: Vec<Node>,
}

/// Which triangles a search may return: all of them, or those of the design cut at a height.
pub trait Filter: Sync {
    /// Whether a node whose boxes start at `min_z` can hold a kept triangle.
    fn node(&self, min_z: f32) -> bool;
    fn triangle(&self, mesh: &Mesh, t: usize) -> bool;
}

pub struct All;

impl Filter for All {
    #[inline]
    fn node(&self, _: f32) -> bool {
        true
    }
    #[inline]
    fn triangle(&self, _: &Mesh, _: usize) -> bool {
        true
    }
}

/// Triangles wholly below `z` (every vertex strictly below): those the cut at `z` keeps whole.
pub struct Below(pub f64);

impl Filter for Below {
    #[inline]
    fn node(&self, min_z: f32) -> bool {
        (min_z as f64) < self.0
    }
    #[inline]
    fn triangle(&self, mesh: &Mesh, t: usize) -> bool {
        mesh.top(t) < self.0
    }
}

#[inline]
fn down(v: f64) -> f32 {
    let f = v as f32;
    if f as f64 > v { f.next_down() } else { f }
}

#[inline]
fn up(v: f64) -> f32 {
    let f = v as f32;
    if (f as f64) < v { f.next_up() } else { f }
}

/// A squared distance grown by a hair (absolute, from the coordinates' size) and a relative
/// 1e-12: the bound a box must lie within to be searched.
#[inline(always)]
fn widen(d2: f64, hair: f64) -> f64 {
    let d = d2.sqrt();
    let w = d + 1e-12 * d + hair;
    w * w
}

/// A leaf's `m` triangles `ids`, loaded in `lanes`, measured against the best so far: the
/// closest within `limit2` (ties to the lowest design id) becomes `best`, and the bound
/// tightens to it and a hair. Always inlined, not a closure: one left out of line would run
/// without AVX2.
#[inline(always)]
#[allow(clippy::too_many_arguments)]
fn measure(
    mesh: &Mesh,
    p: &Point3<f64>,
    limit2: f64,
    m: usize,
    lanes: &Lanes<4>,
    ids: &[u32; 4],
    best: &mut Option<(u32, f64)>,
    bound2: &mut f64,
    hair: f64,
) {
    let d2 = lanes.dist2(p);
    for (&t, &d2) in ids[..m].iter().zip(&d2) {
        if d2 <= limit2 && super::better_internal(mesh, t, d2, *best) {
            *best = Some((t, d2));
            *bound2 = widen(d2, hair);
        }
    }
}

#[inline]
fn box_dist2(n: &Node, p: &Point3<f64>) -> f64 {
    let mut d2 = 0.0;
    for k in 0..3 {
        let v = p[k];
        let (lo, hi) = (n.min[k] as f64, n.max[k] as f64);
        let d = if v < lo {
            lo - v
        } else if v > hi {
            v - hi
        } else {
            0.0
        };
        d2 += d * d;
    }
    d2
}

/// The nodes still to visit, depth first, from the root. The depth is at most
/// log2(triangles) + 1 (median splits), far below 64.
struct NodeStack {
    nodes: [u32; 64],
    len: usize,
}

impl NodeStack {
    #[inline(always)]
    fn from_root() -> Self {
        Self {
            nodes: [0; 64],
            len: 1,
        }
    }

    #[inline(always)]
    fn pop(&mut self) -> Option<usize> {
        self.len = self.len.checked_sub(1)?;
        Some(self.nodes[self.len] as usize)
    }

    #[inline(always)]
    fn push(&mut self, node: usize) {
        self.nodes[self.len] = node as u32;
        self.len += 1;
    }
}

fn nodes_for(n: usize) -> usize {
    if n <= LEAF_SIZE {
        1
    } else {
        1 + nodes_for(n / 2) + nodes_for(n - n / 2)
    }
}

struct Item {
    lo: [f64; 3],
    hi: [f64; 3],
    tri: u32,
}

impl Bvh {
    /// Builds over `triangles` of `vertices`; returns the hierarchy and the order of the
    /// triangles in its leaves (internal position → design triangle).
    pub fn build(vertices: &[Point3<f64>], triangles: &[[u32; 3]]) -> (Self, Vec<u32>) {
        use rayon::prelude::*;
        let mut items: Vec<Item> = triangles
            .par_iter()
            .enumerate()
            .map(|(t, f)| {
                let [a, b, c] = f.map(|i| vertices[i as usize]);
                let lo = a.inf(&b).inf(&c);
                let hi = a.sup(&b).sup(&c);
                Item {
                    lo: [lo.x, lo.y, lo.z],
                    hi: [hi.x, hi.y, hi.z],
                    tri: t as u32,
                }
            })
            .collect();
        let mut nodes = vec![Node::default(); nodes_for(items.len().max(1))];
        build_range(&mut items, &mut nodes, 0, 0);
        let order = items.iter().map(|i| i.tri).collect();
        (Self { nodes }, order)
    }

    pub fn bytes(&self) -> usize {
        self.nodes.len() * size_of::<Node>()
    }

    /// The triangle closest to `p` among those within `sqrt(limit2)` that `filter` keeps, with
    /// its squared distance; ties go to the lowest design id. `hint` (an internal triangle likely
    /// to be close) tightens the bound before the descent.
    pub fn closest<F: Filter>(
        &self,
        mesh: &Mesh,
        p: &Point3<f64>,
        limit2: f64,
        hint: Option<u32>,
        filter: &F,
    ) -> Option<(u32, f64)> {
        avx2!(<F: Filter> [
            bvh: &Bvh = self,
            mesh: &Mesh = mesh,
            p: &Point3<f64> = p,
            limit2: f64 = limit2,
            hint: Option<u32> = hint,
            filter: &F = filter,
        ] -> Option<(u32, f64)> {
            // The descent, a leaf's triangles measured four at a time.
            const L: usize = 4;
            let mut best: Option<(u32, f64)> = None;
            // A box is searched while it lies within the bound and a hair more: where the
            // closest point is on the box's face (an edge of an axis-aligned face), the box's
            // distance and the triangle's are one distance rounded two ways, and the box's may
            // come out an ulp beyond a tie or a nearer triangle's.
            let hair = 1e-12 * (1.0 + p.coords.amax());
            let mut bound2 = widen(limit2, hair);
            let mut lanes = Lanes::<L>::default();
            let mut ids = [0u32; L];
            if let Some(h) = hint
                && (h as usize) < mesh.len()
                && filter.triangle(mesh, h as usize)
            {
                ids[0] = h;
                mesh.load(&mut lanes, &ids[..1]);
                measure(mesh, p, limit2, 1, &lanes, &ids, &mut best, &mut bound2, hair);
            }
            // Boxes farther than the bound cannot hold a closer triangle; boxes exactly at the
            // bound may hold a tie with a lower id, so they are still searched.
            let mut stack = NodeStack::from_root();
            while let Some(i) = stack.pop() {
                let node = &bvh.nodes[i];
                if node.count > 0 {
                    let s = node.start as usize;
                    let mut m = 0;
                    for t in (s..s + node.count as usize).filter(|&t| filter.triangle(mesh, t)) {
                        ids[m] = t as u32;
                        m += 1;
                        if m == L {
                            mesh.load(&mut lanes, &ids);
                            measure(mesh, p, limit2, m, &lanes, &ids, &mut best, &mut bound2, hair);
                            m = 0;
                        }
                    }
                    if m > 0 {
                        mesh.load(&mut lanes, &ids[..m]);
                        measure(mesh, p, limit2, m, &lanes, &ids, &mut best, &mut bound2, hair);
                    }
                    continue;
                }
                let (l, r) = (i + 1, node.start as usize);
                let (nl, nr) = (&bvh.nodes[l], &bvh.nodes[r]);
                let dl = if filter.node(nl.min[2]) {
                    box_dist2(nl, p)
                } else {
                    f64::INFINITY
                };
                let dr = if filter.node(nr.min[2]) {
                    box_dist2(nr, p)
                } else {
                    f64::INFINITY
                };
                let (near, dn, far, df) = if dl <= dr {
                    (l, dl, r, dr)
                } else {
                    (r, dr, l, dl)
                };
                if df <= bound2 {
                    stack.push(far);
                }
                if dn <= bound2 {
                    stack.push(near);
                }
            }
            best
        })
    }

    /// Every triangle whose distance to `p` is at most `radius` and whose box meets the box
    /// `region`, with that distance (and some within `radius` whose box does not: only the
    /// nodes are tested against `region`).
    pub fn within(
        &self,
        mesh: &Mesh,
        p: &Point3<f64>,
        radius: f64,
        region: (Point3<f64>, Point3<f64>),
        out: &mut Vec<(u32, f64)>,
    ) {
        avx2!([
            bvh: &Bvh = self,
            mesh: &Mesh = mesh,
            p: &Point3<f64> = p,
            radius: f64 = radius,
            region: (Point3<f64>, Point3<f64>) = region,
            out: &mut Vec<(u32, f64)> = out,
        ] -> () {
            // The leaves' triangles gathered first, then measured four at a time here, not in the
            // visit's closure (one left out of line would run without AVX2).
            let (lo, hi) = region;
            let r2 = radius * radius;
            let start = out.len();
            bvh.visit_leaves(
                |n| {
                    box_dist2(n, p) <= r2
                        && (0..3).all(|k| n.min[k] as f64 <= hi[k] && n.max[k] as f64 >= lo[k])
                },
                |leaf| {
                    out.extend(leaf.map(|t| (t as u32, f64::INFINITY)));
                    false
                },
            );
            let mut lanes = Lanes::<4>::default();
            let (mut kept, mut i) = (start, start);
            while i < out.len() {
                let m = (out.len() - i).min(4);
                let ids: [u32; 4] = std::array::from_fn(|l| out[i + l.min(m - 1)].0);
                mesh.load(&mut lanes, &ids[..m]);
                // Four roots in one instruction, not four in turn: a root is correctly
                // rounded either way, so the bits are the same.
                let d4 = lanes.dist2(p).map(f64::sqrt);
                for (&t, &d) in ids[..m].iter().zip(&d4) {
                    if d <= radius {
                        out[kept] = (t, d);
                        kept += 1;
                    }
                }
                i += m;
            }
            out.truncate(kept);
        })
    }

    /// Internal triangles whose box meets the plane `z` (conservatively).
    pub fn crossing(&self, z: f64, out: &mut Vec<u32>) {
        self.visit(
            |n| (n.min[2] as f64) <= z && (n.max[2] as f64) >= z,
            |t| {
                out.push(t);
                false
            },
        );
    }

    /// Internal triangles whose box holds the point `p`.
    pub fn containing(&self, p: &Point3<f64>, out: &mut Vec<u32>) {
        self.visit(
            |n| box_dist2(n, p) == 0.0,
            |t| {
                out.push(t);
                false
            },
        );
    }

    /// Hands every triangle of every leaf reached through nodes that `enter` accepts to `leaf`,
    /// until `leaf` says it is done; returns whether it did.
    fn visit(&self, enter: impl Fn(&Node) -> bool, mut leaf: impl FnMut(u32) -> bool) -> bool {
        self.visit_leaves(enter, |r| r.map(|t| t as u32).any(&mut leaf))
    }

    /// [`Bvh::visit`] a leaf (its range of internal triangles) at a time.
    #[inline(always)]
    fn visit_leaves(
        &self,
        enter: impl Fn(&Node) -> bool,
        mut leaf: impl FnMut(std::ops::Range<usize>) -> bool,
    ) -> bool {
        let mut stack = NodeStack::from_root();
        while let Some(i) = stack.pop() {
            let node = &self.nodes[i];
            if !enter(node) {
                continue;
            }
            if node.count > 0 {
                let s = node.start as usize;
                if leaf(s..s + node.count as usize) {
                    return true;
                }
            } else {
                stack.push(i + 1);
                stack.push(node.start as usize);
            }
        }
        false
    }

    /// Whether a triangle that `filter` keeps crosses the segment from `from` to
    /// `from + dir · t` for some `t` in `(t_min, t_max)`.
    pub fn segment_blocked<F: Filter>(
        &self,
        mesh: &Mesh,
        from: &Point3<f64>,
        dir: &Vector3<f64>,
        t_min: f64,
        t_max: f64,
        filter: &F,
    ) -> bool {
        let inv = dir.map(|d| 1.0 / d);
        self.visit(
            |n| filter.node(n.min[2]) && slab_hit(n, from, &inv, t_min, t_max),
            |t| {
                filter.triangle(mesh, t as usize)
                    && mesh
                        .triangle(t as usize)
                        .ray_hit(from, dir)
                        .is_some_and(|hit| hit > t_min && hit < t_max)
            },
        )
    }
}

/// Builds the subtree of `items` at `nodes[0]`, which is node `base` of the whole tree; `first`
/// is the internal index of `items[0]`. Node counts follow from the sizes alone, so both halves
/// know where they go and build in parallel.
fn build_range(items: &mut [Item], nodes: &mut [Node], first: usize, base: usize) {
    let mut min = [f64::INFINITY; 3];
    let mut max = [f64::NEG_INFINITY; 3];
    let mut cmin = [f64::INFINITY; 3];
    let mut cmax = [f64::NEG_INFINITY; 3];
    for it in items.iter() {
        for k in 0..3 {
            min[k] = min[k].min(it.lo[k]);
            max[k] = max[k].max(it.hi[k]);
            let c = 0.5 * (it.lo[k] + it.hi[k]);
            cmin[k] = cmin[k].min(c);
            cmax[k] = cmax[k].max(c);
        }
    }
    nodes[0].min = min.map(down);
    nodes[0].max = max.map(up);
    let n = items.len();
    if n <= LEAF_SIZE {
        nodes[0].start = first as u32;
        nodes[0].count = n as u32;
        return;
    }
    let axis = (0..3)
        .max_by(|&a, &b| (cmax[a] - cmin[a]).total_cmp(&(cmax[b] - cmin[b])))
        .unwrap_or(0);
    let mid = n / 2;
    let key = |it: &Item| it.lo[axis] + it.hi[axis];
    items.select_nth_unstable_by(mid, |a, b| {
        key(a).total_cmp(&key(b)).then(a.tri.cmp(&b.tri))
    });
    let left_nodes = nodes_for(mid);
    let right = base + 1 + left_nodes;
    nodes[0].start = right as u32;
    nodes[0].count = 0;
    let (ln, rn) = nodes[1..].split_at_mut(left_nodes);
    let (li, ri) = items.split_at_mut(mid);
    if n >= PARALLEL_MIN {
        rayon::join(
            || build_range(li, ln, first, base + 1),
            || build_range(ri, rn, first + mid, right),
        );
    } else {
        build_range(li, ln, first, base + 1);
        build_range(ri, rn, first + mid, right);
    }
}

/// Ray against box by slabs (Kay and Kajiya); infinities from zero direction components compare
/// correctly.
#[inline]
fn slab_hit(n: &Node, o: &Point3<f64>, inv: &Vector3<f64>, t_min: f64, t_max: f64) -> bool {
    let (mut lo, mut hi) = (t_min, t_max);
    for k in 0..3 {
        let a = (n.min[k] as f64 - o[k]) * inv[k];
        let b = (n.max[k] as f64 - o[k]) * inv[k];
        let (a, b) = if a <= b { (a, b) } else { (b, a) };
        // A NaN (0 · ∞ on a box face) must not exclude the box.
        if a > lo {
            lo = a;
        }
        if b < hi {
            hi = b;
        }
        if lo > hi {
            return false;
        }
    }
    true
}
