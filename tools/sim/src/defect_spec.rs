//! Defects as the command line spells them: `over-extrusion:layers=2-4,width=12mm`.

use super::defects::Defect;
use super::part::Part;

/// A defect's spelling that does not name a defect: the spelling and what is wrong with it.
#[derive(Debug, thiserror::Error)]
#[error("{spec:?}: {problem}")]
pub struct DefectSpecError {
    /// The spelling as given.
    pub spec: String,
    /// What is wrong with it.
    pub problem: String,
}

fn problem(spec: &str, problem: String) -> DefectSpecError {
    DefectSpecError {
        spec: spec.to_string(),
        problem,
    }
}

impl Defect {
    /// A defect from its command-line spelling, `KIND[:key=value,...]`, on `part`: lengths in
    /// metres or with an `mm` suffix, layers 0-based; keys left out take defaults placed on
    /// the part (its middle layers, its middle).
    pub fn parse(spec: &str, part: &Part) -> Result<Defect, DefectSpecError> {
        let (kind, rest) = spec.split_once(':').unwrap_or((spec, ""));
        let mut kv = std::collections::BTreeMap::new();
        for item in rest.split(',').filter(|s| !s.is_empty()) {
            let (k, v) = item
                .split_once('=')
                .ok_or_else(|| problem(spec, format!("{item:?} is not key=value")))?;
            kv.insert(k.trim().to_string(), v.trim().to_string());
        }
        let bad = |what: &str| problem(spec, what.to_string());
        let len = |k: &str, default: f64| -> Result<f64, DefectSpecError> {
            match kv.get(k) {
                None => Ok(default),
                Some(v) => {
                    let (num, scale) = match v.strip_suffix("mm") {
                        Some(n) => (n, 1e-3),
                        None => (v.strip_suffix('m').unwrap_or(v), 1.0),
                    };
                    num.parse::<f64>()
                        .map(|x| x * scale)
                        .ok()
                        .filter(|x| x.is_finite())
                        .ok_or_else(|| bad(&format!("{k}={v} is not a length")))
                }
            }
        };
        let layer = |k: &str, default: u32| -> Result<u32, DefectSpecError> {
            kv.get(k).map_or(Ok(default), |v| {
                v.parse()
                    .map_err(|_| bad(&format!("{k}={v} is not a layer number")))
            })
        };
        let n = part.layers();
        let (lo, hi) = part.design.bounds();
        let mid = nalgebra::center(&lo, &hi);
        let d = match kind {
            "over-extrusion" | "under-extrusion" => {
                let (a, b) = match kv.get("layers") {
                    Some(r) => {
                        let (a, b) = r.split_once('-').unwrap_or((r, r));
                        (
                            a.parse().map_err(|_| bad("layers=A-B"))?,
                            b.parse().map_err(|_| bad("layers=A-B"))?,
                        )
                    }
                    None => (n / 6, n / 6 + 3),
                };
                let w = len("width", 0.01)?.abs();
                Defect::Extrusion {
                    first: a,
                    last: b,
                    width: if kind == "over-extrusion" { w } else { -w },
                }
            }
            "height-drift" => Defect::HeightDrift {
                from: layer("from", n / 3)?,
                per_layer: len("per-layer", 0.001)?,
            },
            "lateral-shift" => Defect::LateralShift {
                from: layer("from", n / 3)?,
                offset: [len("dx", 0.0)?, len("dy", 0.008)?],
            },
            "sag" => Defect::Sag {
                layers: layer("layers", 3)?.max(1),
                depth: len("depth", 0.008)?,
            },
            "missing-segment" => Defect::MissingSegment {
                layer: layer("layer", n / 2)?,
                centre: [len("x", mid.x + 0.2 * (hi.x - lo.x))?, len("y", mid.y)?],
                direction: match kv.get("along").map(String::as_str) {
                    None | Some("x") => [1.0, 0.0],
                    Some("y") => [0.0, 1.0],
                    Some(o) => return Err(bad(&format!("along={o}: give x or y"))),
                },
                length: len("length", 0.2)?,
            },
            "bulge" => Defect::Bulge {
                centre: [
                    len("x", mid.x - 0.25 * (hi.x - lo.x))?,
                    len("y", lo.y)?,
                    len("z", 0.5 * part.height())?,
                ],
                radius: len("radius", 0.1)?,
                height: len("height", 0.012)?,
            },
            other => {
                return Err(bad(&format!(
                    "unknown kind {other:?}; kinds: over-extrusion, under-extrusion, height-drift, \
                     lateral-shift, sag, missing-segment, bulge"
                )));
            }
        };
        Ok(d)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn spellings_give_their_defects_and_mistakes_say_what_is_wrong() {
        let wall = Part::wall();
        assert_eq!(
            Defect::parse("over-extrusion:layers=2-4,width=12mm", &wall).unwrap(),
            Defect::Extrusion {
                first: 2,
                last: 4,
                width: 0.012
            }
        );
        assert_eq!(
            Defect::parse("under-extrusion:layers=3,width=0.01m", &wall).unwrap(),
            Defect::Extrusion {
                first: 3,
                last: 3,
                width: -0.01
            }
        );
        assert_eq!(
            Defect::parse("height-drift:from=5,per-layer=1mm", &wall).unwrap(),
            Defect::HeightDrift {
                from: 5,
                per_layer: 0.001
            }
        );
        for (spec, says) in [
            ("wobble", "unknown kind \"wobble\""),
            ("sag:depth", "\"depth\" is not key=value"),
            ("sag:depth=deep", "depth=deep is not a length"),
            ("sag:depth=NaN", "depth=NaN is not a length"),
            ("sag:layers=-1", "layers=-1 is not a layer number"),
            ("missing-segment:along=z", "along=z: give x or y"),
        ] {
            let e = Defect::parse(spec, &wall).unwrap_err().to_string();
            assert!(e.starts_with(&format!("{spec:?}: ")), "{e}");
            assert!(e.contains(says), "{spec}: {e}");
        }
    }
}
