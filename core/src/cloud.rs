//! A reference point cloud prepared for nearest-neighbour and radius queries (a k-d tree from
//! `kiddo`). Squared distances throughout, metres².

use std::num::NonZeroUsize;

use kiddo::{ImmutableKdTree, SquaredEuclidean};
use nalgebra::Point3;

/// A reference cloud that cannot be indexed.
#[derive(Debug, thiserror::Error)]
pub enum CloudError {
    /// No points.
    #[error("the reference cloud is empty")]
    Empty,
    /// More points than a `u32` indexes.
    #[error("the reference cloud has {0} points, more than the 4,294,967,295 a k-d tree indexes")]
    TooLarge(usize),
    /// A point is not finite.
    #[error("reference point {index} is not finite ({point:?}): remove it before indexing")]
    NotFinite {
        /// The point's index.
        index: usize,
        /// Its coordinates.
        point: [f64; 3],
    },
    /// The k-d tree could not be built.
    #[error("cannot index the reference cloud: {0}")]
    Build(String),
}

/// A reference cloud's k-d tree (kiddo), for nearest-neighbour and radius queries.
pub struct CloudIndex {
    tree: ImmutableKdTree<f64, 3>,
    points: Vec<[f64; 3]>,
}

impl CloudIndex {
    /// Indexes `points`; every point must be finite.
    pub fn new(points: &[Point3<f64>]) -> Result<Self, CloudError> {
        if points.is_empty() {
            return Err(CloudError::Empty);
        }
        if u32::try_from(points.len()).is_err() {
            return Err(CloudError::TooLarge(points.len()));
        }
        let points: Vec<[f64; 3]> = points.iter().map(|p| [p.x, p.y, p.z]).collect();
        if let Some(index) = points.iter().position(|p| !p.iter().all(|v| v.is_finite())) {
            return Err(CloudError::NotFinite {
                index,
                point: points[index],
            });
        }
        let tree = ImmutableKdTree::new_from_slice(&points)
            .map_err(|e| CloudError::Build(format!("{e:?}")))?;
        Ok(Self { tree, points })
    }

    /// Points indexed.
    pub fn len(&self) -> usize {
        self.points.len()
    }

    /// Whether no point is indexed (never, once built).
    pub fn is_empty(&self) -> bool {
        self.points.is_empty()
    }

    /// Reference point `i`.
    pub fn point(&self, i: u32) -> Point3<f64> {
        Point3::from(self.points[i as usize])
    }

    /// The nearest reference point: its index and squared distance.
    pub fn nearest(&self, p: &Point3<f64>) -> (u32, f64) {
        let r = self
            .tree
            .query(&[p.x, p.y, p.z])
            .nearest_one::<SquaredEuclidean<f64>>()
            .execute();
        (r.item, r.distance)
    }

    /// The `k` nearest reference points, nearest first, into `out`.
    pub fn k_nearest(&self, p: &Point3<f64>, k: NonZeroUsize, out: &mut Vec<(u32, f64)>) {
        out.clear();
        let r = self
            .tree
            .query(&[p.x, p.y, p.z])
            .nearest_n::<SquaredEuclidean<f64>>(k)
            .execute();
        out.extend(r.into_iter().map(|r| (r.item, r.distance)));
    }

    /// Every reference point within `radius` of `p`, in no particular order, into `out`.
    pub fn within(&self, p: &Point3<f64>, radius: f64, out: &mut Vec<u32>) {
        out.clear();
        let r = self
            .tree
            .query(&[p.x, p.y, p.z])
            .within::<SquaredEuclidean<f64>>(radius * radius)
            .unsorted()
            .execute();
        out.extend(r.into_iter().map(|r| r.item));
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::test_points::{random_points, seeded};

    #[test]
    fn queries_match_brute_force() {
        let mut rng = seeded(5);
        let pts = random_points(&mut rng, 2000, 0.0..1.0);
        let ix = CloudIndex::new(&pts).unwrap();
        let mut buf = Vec::new();
        let mut ibuf = Vec::new();
        for q in random_points(&mut rng, 200, 0.0..1.0) {
            let mut d: Vec<(f64, u32)> = pts
                .iter()
                .enumerate()
                .map(|(i, p)| ((p - q).norm_squared(), i as u32))
                .collect();
            d.sort_by(|a, b| a.0.total_cmp(&b.0));
            let (i, d2) = ix.nearest(&q);
            assert_eq!((i, d2), (d[0].1, d[0].0));
            ix.k_nearest(&q, NonZeroUsize::new(7).unwrap(), &mut buf);
            let got: Vec<f64> = buf.iter().map(|r| r.1).collect();
            let want: Vec<f64> = d[..7].iter().map(|r| r.0).collect();
            assert_eq!(got, want);
            ix.within(&q, 0.1, &mut ibuf);
            ibuf.sort_unstable();
            let mut want: Vec<u32> = d.iter().filter(|r| r.0 <= 0.01).map(|r| r.1).collect();
            want.sort_unstable();
            assert_eq!(ibuf, want);
        }
        assert!(matches!(CloudIndex::new(&[]), Err(CloudError::Empty)));
        assert!(matches!(
            CloudIndex::new(&[Point3::new(f64::NAN, 0.0, 0.0)]),
            Err(CloudError::NotFinite { index: 0, .. })
        ));
    }
}
