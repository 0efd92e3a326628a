//! Cloud-to-cloud distance (C2C): from each scan point to the nearest point of a reference
//! cloud. Unsigned, and as coarse as the reference's spacing, so an optional local model fits a
//! least-squares plane through the k nearest reference points and takes the distance to it;
//! like CloudCompare, the smaller of the two distances is reported.

use std::num::NonZeroUsize;

use nalgebra::Point3;
use rayon::prelude::*;

use crate::cloud::CloudIndex;
use crate::m3c2::classic::plane_normal;

/// The parameters of a cloud-to-cloud distance.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct C2cParams {
    /// Beyond this a point has no match, metres.
    pub max_distance: f64,
    /// Neighbours for the local plane; `None` for plain nearest-neighbour distance.
    pub local_plane_k: Option<NonZeroUsize>,
}

/// C2C parameters that cannot be used.
#[derive(Debug, thiserror::Error)]
pub enum C2cError {
    /// The maximum distance is not a positive number.
    #[error("C2C maximum distance must be a positive number of metres, got {0}")]
    MaxDistance(f64),
    /// A local plane needs three neighbours at least.
    #[error("a local plane needs at least 3 neighbours, got {0}")]
    TooFewNeighbours(usize),
}

impl C2cParams {
    /// Checks the parameters.
    pub fn validate(&self) -> Result<(), C2cError> {
        if !(self.max_distance > 0.0 && self.max_distance.is_finite()) {
            return Err(C2cError::MaxDistance(self.max_distance));
        }
        if let Some(k) = self.local_plane_k
            && k.get() < 3
        {
            return Err(C2cError::TooFewNeighbours(k.get()));
        }
        Ok(())
    }
}

/// The distance of `p` to the reference, or `None` beyond the maximum distance or for a
/// non-finite point.
pub fn distance(
    reference: &CloudIndex,
    p: &Point3<f64>,
    params: &C2cParams,
    buf: &mut Vec<(u32, f64)>,
) -> Option<f64> {
    if !(p.x.is_finite() && p.y.is_finite() && p.z.is_finite()) {
        return None;
    }
    let (_, d2) = reference.nearest(p);
    let mut d = d2.sqrt();
    if let Some(k) = params.local_plane_k {
        reference.k_nearest(p, k, buf);
        let pts = buf.iter().map(|&(j, _)| reference.point(j));
        if let Some(n) = plane_normal(pts.clone()) {
            let count = buf.len() as f64;
            let centroid = pts.fold(Point3::origin(), |c, q| c + q.coords / count);
            d = d.min((p - centroid).dot(&n).abs());
        }
    }
    (d <= params.max_distance).then_some(d)
}

/// [`distance`] for a batch, in parallel; `out[i]` answers `points[i]`.
pub fn distances(
    reference: &CloudIndex,
    points: &[Point3<f64>],
    params: &C2cParams,
    out: &mut [Option<f64>],
) {
    assert_eq!(points.len(), out.len(), "one output per point");
    points
        .par_chunks(2048)
        .zip(out.par_chunks_mut(2048))
        .for_each_init(Vec::new, |buf, (ps, os)| {
            for (p, o) in ps.iter().zip(os) {
                *o = distance(reference, p, params, buf);
            }
        });
}

#[cfg(test)]
mod tests {
    use super::*;

    fn grid(z: f64, step: f64) -> Vec<Point3<f64>> {
        (0..50)
            .flat_map(|i| (0..50).map(move |j| Point3::new(i as f64 * step, j as f64 * step, z)))
            .collect()
    }

    #[test]
    fn nearest_point_and_local_plane_against_a_plane_by_hand() {
        let reference = CloudIndex::new(&grid(0.0, 0.01)).unwrap();
        let plain = C2cParams {
            max_distance: 0.05,
            local_plane_k: None,
        };
        let local = C2cParams {
            local_plane_k: NonZeroUsize::new(8),
            ..plain
        };
        let mut buf = Vec::new();
        // Above a grid node: both give the height.
        let p = Point3::new(0.2, 0.2, 0.003);
        assert!((distance(&reference, &p, &plain, &mut buf).unwrap() - 0.003).abs() < 1e-12);
        assert!((distance(&reference, &p, &local, &mut buf).unwrap() - 0.003).abs() < 1e-12);
        // Above a cell centre: the nearest node is off to the side, the plane is not.
        let p = Point3::new(0.205, 0.205, 0.003);
        let nn = (0.005f64.powi(2) * 2.0 + 0.003f64.powi(2)).sqrt();
        assert!((distance(&reference, &p, &plain, &mut buf).unwrap() - nn).abs() < 1e-12);
        assert!((distance(&reference, &p, &local, &mut buf).unwrap() - 0.003).abs() < 1e-9);
        // Beyond the maximum distance, and not finite.
        assert_eq!(
            distance(&reference, &Point3::new(0.2, 0.2, 0.06), &plain, &mut buf),
            None
        );
        assert_eq!(
            distance(
                &reference,
                &Point3::new(f64::NAN, 0.0, 0.0),
                &plain,
                &mut buf
            ),
            None
        );
        let pts = grid(0.002, 0.01);
        let mut out = vec![None; pts.len()];
        distances(&reference, &pts, &plain, &mut out);
        assert!(out.iter().all(|d| (d.unwrap() - 0.002).abs() < 1e-12));
        assert!(
            C2cParams {
                local_plane_k: NonZeroUsize::new(2),
                ..plain
            }
            .validate()
            .is_err()
        );
    }
}
