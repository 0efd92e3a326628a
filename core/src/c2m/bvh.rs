//! A bounding volume hierarchy over triangles for exact closest-triangle queries under a bound.
//! The grid answers most points; this answers the rest and builds the grid.

use nalgebra::Point3;

use super::triangle::Triangle;

const LEAF_SIZE: usize = 4;

#[derive(Debug, Clone, Copy)]
struct Node {
    min: [f64; 3],
    max: [f64; 3],
    /// Leaf: first index into `order`; inner: index of the left child (right is `left + 1`).
    start: u32,
    /// Leaf: number of triangles; inner: 0.
    count: u32,
}

pub struct Bvh {
    nodes: Vec<Node>,
    order: Vec<u32>,
}

#[inline]
fn box_dist2(min: &[f64; 3], max: &[f64; 3], p: &Point3<f64>) -> f64 {
    let mut d2 = 0.0;
    for k in 0..3 {
        let v = p[k];
        let d = if v < min[k] {
            min[k] - v
        } else if v > max[k] {
            v - max[k]
        } else {
            0.0
        };
        d2 += d * d;
    }
    d2
}

impl Bvh {
    pub fn new(triangles: &[Triangle]) -> Self {
        let boxes: Vec<([f64; 3], [f64; 3])> = triangles
            .iter()
            .map(|t| {
                let (lo, hi) = t.aabb();
                ([lo.x, lo.y, lo.z], [hi.x, hi.y, hi.z])
            })
            .collect();
        let centroids: Vec<[f64; 3]> = boxes
            .iter()
            .map(|(lo, hi)| std::array::from_fn(|k| 0.5 * (lo[k] + hi[k])))
            .collect();
        let mut order: Vec<u32> = (0..triangles.len() as u32).collect();
        let mut nodes = Vec::with_capacity(2 * triangles.len() / LEAF_SIZE + 1);
        nodes.push(Node {
            min: [0.0; 3],
            max: [0.0; 3],
            start: 0,
            count: 0,
        });
        // Iterative build: (node index, range in `order`).
        let mut stack = vec![(0usize, 0usize, order.len())];
        while let Some((node, lo, hi)) = stack.pop() {
            let mut min = [f64::INFINITY; 3];
            let mut max = [f64::NEG_INFINITY; 3];
            let mut cmin = [f64::INFINITY; 3];
            let mut cmax = [f64::NEG_INFINITY; 3];
            for &t in &order[lo..hi] {
                let (bl, bh) = &boxes[t as usize];
                let c = &centroids[t as usize];
                for k in 0..3 {
                    min[k] = min[k].min(bl[k]);
                    max[k] = max[k].max(bh[k]);
                    cmin[k] = cmin[k].min(c[k]);
                    cmax[k] = cmax[k].max(c[k]);
                }
            }
            nodes[node].min = min;
            nodes[node].max = max;
            if hi - lo <= LEAF_SIZE {
                nodes[node].start = lo as u32;
                nodes[node].count = (hi - lo) as u32;
                continue;
            }
            let axis = (0..3)
                .max_by(|&a, &b| (cmax[a] - cmin[a]).total_cmp(&(cmax[b] - cmin[b])))
                .unwrap_or(0);
            let mid = lo + (hi - lo) / 2;
            order[lo..hi].select_nth_unstable_by(mid - lo, |&a, &b| {
                centroids[a as usize][axis].total_cmp(&centroids[b as usize][axis])
            });
            let left = nodes.len();
            let blank = Node {
                min: [0.0; 3],
                max: [0.0; 3],
                start: 0,
                count: 0,
            };
            nodes.push(blank);
            nodes.push(blank);
            nodes[node].start = left as u32;
            nodes[node].count = 0;
            stack.push((left, lo, mid));
            stack.push((left + 1, mid, hi));
        }
        Self { nodes, order }
    }

    pub fn bytes(&self) -> usize {
        self.nodes.len() * size_of::<Node>() + self.order.len() * size_of::<u32>()
    }

    /// The triangle closest to `p` among those within `sqrt(limit2)`, with its squared distance;
    /// ties go to the lowest index. `hint` (a triangle likely to be close, such as the previous
    /// point's) tightens the bound before the descent.
    pub fn closest(
        &self,
        triangles: &[Triangle],
        p: &Point3<f64>,
        limit2: f64,
        hint: Option<u32>,
    ) -> Option<(u32, f64)> {
        let mut best: Option<(u32, f64)> = None;
        let mut bound2 = limit2;
        let consider = |t: u32, best: &mut Option<(u32, f64)>, bound2: &mut f64| {
            let (q, _) = triangles[t as usize].closest_point(p);
            let d2 = (p - q).norm_squared();
            if d2 <= limit2 && super::better(t, d2, *best) {
                *best = Some((t, d2));
                *bound2 = d2;
            }
        };
        if let Some(h) = hint {
            consider(h, &mut best, &mut bound2);
        }
        // Boxes farther than the bound cannot hold a closer triangle; boxes exactly at the bound
        // may hold a tie with a lower index, so they are still searched.
        let mut stack = [0u32; 64];
        let mut top = 1usize;
        while top > 0 {
            top -= 1;
            let node = &self.nodes[stack[top] as usize];
            if box_dist2(&node.min, &node.max, p) > bound2 {
                continue;
            }
            if node.count > 0 {
                let s = node.start as usize;
                for &t in &self.order[s..s + node.count as usize] {
                    consider(t, &mut best, &mut bound2);
                }
            } else {
                let l = node.start as usize;
                let dl = box_dist2(&self.nodes[l].min, &self.nodes[l].max, p);
                let dr = box_dist2(&self.nodes[l + 1].min, &self.nodes[l + 1].max, p);
                // Push the farther child first so the nearer one is searched first.
                let (near, dn, far, df) = if dl <= dr {
                    (l, dl, l + 1, dr)
                } else {
                    (l + 1, dr, l, dl)
                };
                // Depth is at most log2(triangles) + 1 (median splits), far below 63.
                if df <= bound2 {
                    stack[top] = far as u32;
                    top += 1;
                }
                if dn <= bound2 {
                    stack[top] = near as u32;
                    top += 1;
                }
            }
        }
        best
    }

    /// Every triangle whose distance to `p` is at most `radius`, with that distance.
    pub fn within(
        &self,
        triangles: &[Triangle],
        p: &Point3<f64>,
        radius: f64,
        out: &mut Vec<(u32, f64)>,
    ) {
        let r2 = radius * radius;
        let mut stack = vec![0u32];
        while let Some(n) = stack.pop() {
            let node = &self.nodes[n as usize];
            if box_dist2(&node.min, &node.max, p) > r2 {
                continue;
            }
            if node.count > 0 {
                let s = node.start as usize;
                for &t in &self.order[s..s + node.count as usize] {
                    let (q, _) = triangles[t as usize].closest_point(p);
                    let d = (p - q).norm();
                    if d <= radius {
                        out.push((t, d));
                    }
                }
            } else {
                stack.push(node.start);
                stack.push(node.start + 1);
            }
        }
    }

    /// Whether any triangle crosses the segment from `from` to `from + dir · t` for some `t` in
    /// `(t_min, t_max)`.
    pub fn segment_blocked(
        &self,
        triangles: &[Triangle],
        from: &Point3<f64>,
        dir: &nalgebra::Vector3<f64>,
        t_min: f64,
        t_max: f64,
    ) -> bool {
        let inv = dir.map(|d| 1.0 / d);
        let mut stack = [0u32; 64];
        let mut top = 1usize;
        while top > 0 {
            top -= 1;
            let node = &self.nodes[stack[top] as usize];
            if !slab_hit(&node.min, &node.max, from, &inv, t_min, t_max) {
                continue;
            }
            if node.count > 0 {
                let s = node.start as usize;
                for &t in &self.order[s..s + node.count as usize] {
                    if let Some(hit) = triangles[t as usize].ray_hit(from, dir)
                        && hit > t_min
                        && hit < t_max
                    {
                        return true;
                    }
                }
            } else {
                stack[top] = node.start;
                stack[top + 1] = node.start + 1;
                top += 2;
            }
        }
        false
    }
}

/// Ray against box by slabs (Kay and Kajiya); infinities from zero direction components compare
/// correctly.
#[inline]
fn slab_hit(
    min: &[f64; 3],
    max: &[f64; 3],
    o: &Point3<f64>,
    inv: &nalgebra::Vector3<f64>,
    t_min: f64,
    t_max: f64,
) -> bool {
    let (mut lo, mut hi) = (t_min, t_max);
    for k in 0..3 {
        let a = (min[k] - o[k]) * inv[k];
        let b = (max[k] - o[k]) * inv[k];
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
