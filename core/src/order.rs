//! The spatial order of a batch of points. A scanner writes its points line by line, so
//! consecutive points lie near each other and find the index's cells and triangles still in
//! cache. A merged or shuffled cloud does not: it is queried along a Morton (Z-order) curve
//! instead, and each result goes back to its point's own place. Queries are exact in any order,
//! so the results keep their bits.

use rayon::prelude::*;

/// Whether consecutive points lie near each other, as a scanner writes them: the mean step
/// between neighbours, over an even sample of pairs, is under 1/64 of the sample's extent. A
/// shuffled cloud steps about half its extent. Only the sample is read, so a batch in scan
/// order costs no pass of its own. `pos` gives a point's position, `None` when not finite.
pub(crate) fn in_spatial_order<T>(items: &[T], pos: impl Fn(&T) -> Option<[f64; 3]>) -> bool {
    const PAIRS: usize = 256;
    let stride = (items.len() / PAIRS).max(1);
    let pairs = || {
        (1..items.len())
            .step_by(stride)
            .filter_map(|i| Some((pos(&items[i - 1])?, pos(&items[i])?)))
    };
    let (lo, hi) = pairs()
        .flat_map(|(a, b)| [a, b])
        .fold(EMPTY, |b, p| grow(b, (p, p)));
    let diagonal = (0..3).map(|k| (hi[k] - lo[k]).powi(2)).sum::<f64>().sqrt();
    let (mut sum, mut n) = (0.0, 0usize);
    for (a, b) in pairs() {
        sum += (0..3).map(|k| (a[k] - b[k]).powi(2)).sum::<f64>().sqrt();
        n += 1;
    }
    n == 0 || diagonal.is_nan() || diagonal <= 0.0 || sum / (n as f64) < diagonal / 64.0
}

/// The points' indices along a Morton curve of 10 bits an axis over their box; points that are
/// not finite come first.
pub(crate) fn morton_order<T: Sync>(
    items: &[T],
    pos: impl Fn(&T) -> Option<[f64; 3]> + Sync,
) -> Vec<u32> {
    let (lo, hi) = items
        .par_iter()
        .fold(
            || EMPTY,
            |b, t| match pos(t) {
                Some(p) => grow(b, (p, p)),
                None => b,
            },
        )
        .reduce(|| EMPTY, grow);
    let scale: [f64; 3] = std::array::from_fn(|k| {
        let span = hi[k] - lo[k];
        if span > 0.0 { 1023.0 / span } else { 0.0 }
    });
    let spread = |v: u64| -> u64 {
        // Bits 0..10 of v moved to every third bit.
        let mut x = v & 0x3ff;
        x = (x | (x << 16)) & 0x0300_00ff;
        x = (x | (x << 8)) & 0x0300_f00f;
        x = (x | (x << 4)) & 0x030c_30c3;
        (x | (x << 2)) & 0x0924_9249
    };
    let mut keyed: Vec<(u32, u32)> = items
        .par_iter()
        .enumerate()
        .map(|(i, t)| {
            let key = match pos(t) {
                Some(p) => {
                    let q = |k: usize| ((p[k] - lo[k]) * scale[k]).clamp(0.0, 1023.0) as u64;
                    (spread(q(0)) | spread(q(1)) << 1 | spread(q(2)) << 2) as u32 + 1
                }
                None => 0,
            };
            (key, i as u32)
        })
        .collect();
    keyed.par_sort_unstable();
    keyed.into_iter().map(|(_, i)| i).collect()
}

/// `items` in `order` into `sorted` (cleared first), in parallel: a block's items scatter over
/// megabytes.
pub(crate) fn gather<T: Copy + Send + Sync>(items: &[T], order: &[u32], sorted: &mut Vec<T>) {
    sorted.clear();
    sorted.par_extend(order.par_iter().map(|&i| items[i as usize]));
}

/// Puts each result of the items taken in `order` back in its item's place:
/// `out[order[j]] = sorted[j]`, in parallel.
pub(crate) fn put_back<T: Copy + Send + Sync>(sorted: &[T], order: &[u32], out: &mut [T]) {
    let mut place = vec![0u32; order.len()];
    for (j, &i) in order.iter().enumerate() {
        place[i as usize] = j as u32;
    }
    out.par_iter_mut()
        .zip(place.par_iter())
        .for_each(|(o, &j)| *o = sorted[j as usize]);
}

type Bounds = ([f64; 3], [f64; 3]);

const EMPTY: Bounds = ([f64::INFINITY; 3], [f64::NEG_INFINITY; 3]);

fn grow(a: Bounds, b: Bounds) -> Bounds {
    (
        std::array::from_fn(|k| a.0[k].min(b.0[k])),
        std::array::from_fn(|k| a.1[k].max(b.1[k])),
    )
}
