//! The transform tree of a bag (`/tf_static` and `/tf`): a pose between any two frames at any
//! time the recording covers, each moving transform interpolated at that time (translation
//! linear, rotation slerp).

use std::collections::BTreeMap;

use nalgebra::{Isometry3, Translation3};

/// One edge of the tree: the parent, and `p_parent = T · p_child` at each recorded time (one
/// sample at time 0 for a static transform).
#[derive(Debug, Clone)]
struct Edge {
    parent: String,
    fixed: bool,
    samples: Vec<(i64, Isometry3<f64>)>,
}

/// Why a pose cannot be had from the tree.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum TfError {
    /// The frame is in no transform of the bag.
    #[error("frame {frame:?} is not in the bag's transform tree (its frames: {known})")]
    UnknownFrame {
        /// The frame asked for.
        frame: String,
        /// The frames the tree has.
        known: String,
    },
    /// The two frames are in trees that do not meet.
    #[error(
        "no chain of transforms joins {from:?} and {to:?} (their roots: {from_root:?} and {to_root:?})"
    )]
    Broken {
        /// The frame whose pose is asked.
        from: String,
        /// The frame it is asked in.
        to: String,
        /// Where `from`'s chain ends.
        from_root: String,
        /// Where `to`'s chain ends.
        to_root: String,
    },
    /// The time lies outside what was recorded of a moving transform.
    #[error(
        "the transform {parent:?} → {child:?} is recorded from {first:.3} s to {last:.3} s; \
         {at:.3} s is {by_ms:.1} ms outside"
    )]
    Outside {
        /// The edge's parent frame.
        parent: String,
        /// The edge's child frame.
        child: String,
        /// The time asked for, seconds.
        at: f64,
        /// The first sample's time, seconds.
        first: f64,
        /// The last sample's time, seconds.
        last: f64,
        /// How far outside, milliseconds.
        by_ms: f64,
    },
    /// A frame was recorded under two parents.
    #[error("frame {child:?} is recorded under two parents, {first:?} and {second:?}")]
    TwoParents {
        /// The frame.
        child: String,
        /// Its first parent.
        first: String,
        /// The other.
        second: String,
    },
}

/// The bag's transforms, by child frame.
#[derive(Debug, Clone, Default)]
pub struct TfTree {
    edges: BTreeMap<String, Edge>,
}

impl TfTree {
    /// Adds `p_parent = t · p_child` at `stamp_ns` (ignored for a static transform, which holds
    /// at every time).
    pub fn add(
        &mut self,
        parent: &str,
        child: &str,
        stamp_ns: i64,
        t: Isometry3<f64>,
        fixed: bool,
    ) -> Result<(), TfError> {
        let edge = self.edges.entry(child.to_string()).or_insert_with(|| Edge {
            parent: parent.to_string(),
            fixed,
            samples: Vec::new(),
        });
        if edge.parent != parent {
            return Err(TfError::TwoParents {
                child: child.to_string(),
                first: edge.parent.clone(),
                second: parent.to_string(),
            });
        }
        if fixed {
            // The latest static transform wins, as in tf2.
            edge.fixed = true;
            edge.samples = vec![(0, t)];
        } else if !edge.fixed {
            edge.samples.push((stamp_ns, t));
        }
        Ok(())
    }

    /// Puts every moving transform's samples in time order; call once all are added.
    pub fn finish(&mut self) {
        for e in self.edges.values_mut() {
            e.samples.sort_by_key(|s| s.0);
            e.samples.dedup_by_key(|s| s.0);
        }
    }

    /// Transforms recorded, for the log.
    pub fn len(&self) -> usize {
        self.edges.values().map(|e| e.samples.len()).sum()
    }

    /// Whether nothing was recorded.
    pub fn is_empty(&self) -> bool {
        self.edges.is_empty()
    }

    /// `p_target = T · p_source` at `stamp_ns`.
    pub fn pose(
        &self,
        target: &str,
        source: &str,
        stamp_ns: i64,
    ) -> Result<Isometry3<f64>, TfError> {
        // A frame asked in itself needs no tree; any other must be in it.
        let known = |frame: &str| {
            frame == target && frame == source
                || self.edges.contains_key(frame)
                || self.edges.values().any(|e| e.parent == frame)
        };
        for frame in [target, source] {
            if !known(frame) {
                let mut frames: Vec<&str> = self
                    .edges
                    .iter()
                    .flat_map(|(c, e)| [c.as_str(), e.parent.as_str()])
                    .collect();
                frames.sort_unstable();
                frames.dedup();
                return Err(TfError::UnknownFrame {
                    frame: frame.to_string(),
                    known: frames.join(", "),
                });
            }
        }
        let up_source = self.chain(source);
        let up_target = self.chain(target);
        // The lowest frame both chains reach.
        let Some((i, j)) = up_source
            .iter()
            .enumerate()
            .find_map(|(i, f)| up_target.iter().position(|g| g == f).map(|j| (i, j)))
        else {
            return Err(TfError::Broken {
                from: source.to_string(),
                to: target.to_string(),
                from_root: up_source.last().cloned().unwrap_or_default(),
                to_root: up_target.last().cloned().unwrap_or_default(),
            });
        };
        let common_source = self.compose(&up_source[..=i], stamp_ns)?;
        let common_target = self.compose(&up_target[..=j], stamp_ns)?;
        Ok(common_target.inverse() * common_source)
    }

    /// `frame`, its parent, its parent's parent… to the root.
    fn chain(&self, frame: &str) -> Vec<String> {
        let mut out = vec![frame.to_string()];
        while let Some(e) = self.edges.get(out.last().expect("never empty")) {
            if out.contains(&e.parent) || out.len() > self.edges.len() {
                break; // a loop: tf2 refuses it too
            }
            out.push(e.parent.clone());
        }
        out
    }

    /// `p_last = T · p_first` along `chain` (a frame and its ancestors).
    fn compose(&self, chain: &[String], stamp_ns: i64) -> Result<Isometry3<f64>, TfError> {
        let mut t = Isometry3::identity();
        for child in &chain[..chain.len() - 1] {
            let e = &self.edges[child];
            t = self.at(child, e, stamp_ns)? * t;
        }
        Ok(t)
    }

    /// An edge's transform at `stamp_ns`.
    fn at(&self, child: &str, e: &Edge, stamp_ns: i64) -> Result<Isometry3<f64>, TfError> {
        if e.fixed {
            return Ok(e.samples[0].1);
        }
        let (first, last) = (e.samples[0].0, e.samples[e.samples.len() - 1].0);
        if stamp_ns < first || stamp_ns > last {
            let by = if stamp_ns < first {
                first - stamp_ns
            } else {
                stamp_ns - last
            };
            return Err(TfError::Outside {
                parent: e.parent.clone(),
                child: child.to_string(),
                at: stamp_ns as f64 * 1e-9,
                first: first as f64 * 1e-9,
                last: last as f64 * 1e-9,
                by_ms: by as f64 * 1e-6,
            });
        }
        let k = e.samples.partition_point(|s| s.0 <= stamp_ns);
        let (t0, a) = e.samples[k - 1];
        if t0 == stamp_ns || k == e.samples.len() {
            return Ok(a);
        }
        let (t1, b) = e.samples[k];
        Ok(interpolate(
            &a,
            &b,
            (stamp_ns - t0) as f64 / (t1 - t0) as f64,
        ))
    }
}

/// The pose a fraction `s` of the way from `a` to `b`: translation linear, rotation slerp.
pub fn interpolate(a: &Isometry3<f64>, b: &Isometry3<f64>, s: f64) -> Isometry3<f64> {
    let t = a.translation.vector.lerp(&b.translation.vector, s);
    let r = a.rotation.slerp(&b.rotation, s);
    Isometry3::from_parts(Translation3::from(t), r)
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{UnitQuaternion, Vector3};

    /// The flange on a path: at time t (s) at (0.2 t, 0.1 sin t, 1) turned by 0.3 t about z.
    fn flange(t: f64) -> Isometry3<f64> {
        Isometry3::from_parts(
            Translation3::new(0.2 * t, 0.1 * t.sin(), 1.0),
            UnitQuaternion::from_axis_angle(&Vector3::z_axis(), 0.3 * t),
        )
    }

    fn tree() -> TfTree {
        let mut tf = TfTree::default();
        let mount = Isometry3::translation(0.05, 0.0, 0.1);
        tf.add("flange", "scanner", 0, mount, true).unwrap();
        // 50 Hz over 2 s, out of order.
        for k in (0..=100).rev() {
            let t = k as f64 * 0.02;
            tf.add("world", "flange", (t * 1e9) as i64, flange(t), false)
                .unwrap();
        }
        tf.add(
            "world",
            "table",
            0,
            Isometry3::translation(3.0, 0.0, 0.0),
            true,
        )
        .unwrap();
        tf.finish();
        tf
    }

    #[test]
    fn a_pose_between_samples_is_near_the_true_path_and_exact_at_a_sample() {
        let tf = tree();
        let mount = Isometry3::translation(0.05, 0.0, 0.1);
        for &t in &[0.0, 0.02, 0.5, 0.513, 1.999, 2.0] {
            let got = tf.pose("world", "scanner", (t * 1e9) as i64).unwrap();
            let truth = flange(t) * mount;
            let err = (got.translation.vector - truth.translation.vector).norm();
            assert!(err < 5e-5, "t {t}: {err}");
            assert!(got.rotation.angle_to(&truth.rotation) < 1e-5);
        }
        // Between frames of different branches: scanner in the table's frame.
        let t = 0.7;
        let got = tf.pose("table", "scanner", (t * 1e9) as i64).unwrap();
        let truth = Isometry3::translation(-3.0, 0.0, 0.0) * flange(t) * mount;
        assert!((got.translation.vector - truth.translation.vector).norm() < 5e-5);
    }

    #[test]
    fn outside_the_recording_unknown_frames_and_broken_chains_are_named() {
        let mut tf = tree();
        let e = tf.pose("world", "scanner", 2_010_000_000).unwrap_err();
        assert!(
            matches!(&e, TfError::Outside { by_ms, .. } if (by_ms - 10.0).abs() < 1e-6),
            "{e}"
        );
        assert!(e.to_string().contains("10.0 ms outside"), "{e}");
        let e = tf.pose("map", "scanner", 0).unwrap_err();
        assert!(matches!(e, TfError::UnknownFrame { .. }), "{e}");
        tf.add("odom", "base", 0, Isometry3::identity(), true)
            .unwrap();
        let e = tf.pose("world", "base", 0).unwrap_err();
        assert!(matches!(e, TfError::Broken { .. }), "{e}");
        let e = tf
            .add("table", "flange", 0, Isometry3::identity(), false)
            .unwrap_err();
        assert!(matches!(e, TfError::TwoParents { .. }), "{e}");
        assert!(
            tf.pose("world", "world", 5)
                .unwrap()
                .translation
                .vector
                .norm()
                == 0.0
        );
    }
}
