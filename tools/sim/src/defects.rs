//! Printing defects, each with the truth a test or a reviewer checks the agent's findings
//! against.

use nalgebra::{Point3, Vector2};

use super::part::Part;

/// One way a print departs from its design. Lengths in metres, layers 0-based from the bed.
#[derive(Debug, Clone, PartialEq)]
pub enum Defect {
    /// Layers `first..=last` come out `width` wider (over-extrusion, > 0) or narrower (< 0),
    /// half of it on each side.
    Extrusion {
        /// The first layer affected.
        first: u32,
        /// The last layer affected.
        last: u32,
        /// Metres wider (> 0) or narrower (< 0) than the design.
        width: f64,
    },
    /// From layer `from` on, every layer is `per_layer` thicker (> 0) or thinner than nominal.
    HeightDrift {
        /// The first layer affected.
        from: u32,
        /// Metres each layer gains (> 0) or loses.
        per_layer: f64,
    },
    /// From layer `from` on, the layers sit shifted by `offset` (x, y).
    LateralShift {
        /// The first layer affected.
        from: u32,
        /// Metres in x and y.
        offset: [f64; 2],
    },
    /// The top `layers` layers of the print, still fresh, settle so that the top ends `depth`
    /// low, most of it in the top layer, and spread sideways by half of what they lose.
    Sag {
        /// Top layers that settle.
        layers: u32,
        /// Metres the top ends low.
        depth: f64,
    },
    /// Layer `layer` is missing over `length` of its path around `centre`, along `direction`.
    MissingSegment {
        /// The layer with the gap.
        layer: u32,
        /// The gap's middle in x and y; the path nearest to it loses the segment.
        centre: [f64; 2],
        /// The gap's direction in the plane.
        direction: [f64; 2],
        /// The gap's length, metres.
        length: f64,
    },
    /// The surface swells outward by up to `height` within `radius` of `centre`.
    Bulge {
        /// The bulge's centre in the design frame, on or near the surface.
        centre: [f64; 3],
        /// Metres from the centre where the swelling ends.
        radius: f64,
        /// The swelling at the centre, metres.
        height: f64,
    },
}

/// What a defect did to a print after `printed` layers, in the terms the agent reports.
#[derive(Debug, Clone, PartialEq)]
pub struct Truth {
    /// The defect's kind.
    pub kind: DefectKind,
    /// The quantity the agent should measure: width deviation, top height deviation, shift,
    /// missing length, bulge height. Signed, metres.
    pub magnitude: f64,
    /// Where: the middle of the affected surface in the design frame.
    pub position: Point3<f64>,
    /// Layers affected, inclusive.
    pub layers: (u32, u32),
    /// For a shift or a gap, the direction in the plane.
    pub direction: Option<[f64; 2]>,
}

/// The kinds of defect, as `--defect` spells them (`over-extrusion`, …).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum DefectKind {
    /// Layers narrower than designed.
    UnderExtrusion,
    /// Layers wider than designed.
    OverExtrusion,
    /// Each layer a little higher (or lower) than designed, adding up.
    HeightDrift,
    /// Layers printed beside where they belong.
    LateralShift,
    /// The top sinking under its own weight.
    Sag,
    /// A length of a layer not printed.
    MissingSegment,
    /// A local swelling of the surface.
    Bulge,
}

impl DefectKind {
    /// The kind as `--defect` spells it.
    pub fn as_str(self) -> &'static str {
        match self {
            DefectKind::UnderExtrusion => "under-extrusion",
            DefectKind::OverExtrusion => "over-extrusion",
            DefectKind::HeightDrift => "height-drift",
            DefectKind::LateralShift => "lateral-shift",
            DefectKind::Sag => "sag",
            DefectKind::MissingSegment => "missing-segment",
            DefectKind::Bulge => "bulge",
        }
    }
}

impl std::fmt::Display for DefectKind {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.as_str())
    }
}

impl Defect {
    /// The defect's kind.
    pub fn kind(&self) -> DefectKind {
        match self {
            Defect::Extrusion { width, .. } if *width < 0.0 => DefectKind::UnderExtrusion,
            Defect::Extrusion { .. } => DefectKind::OverExtrusion,
            Defect::HeightDrift { .. } => DefectKind::HeightDrift,
            Defect::LateralShift { .. } => DefectKind::LateralShift,
            Defect::Sag { .. } => DefectKind::Sag,
            Defect::MissingSegment { .. } => DefectKind::MissingSegment,
            Defect::Bulge { .. } => DefectKind::Bulge,
        }
    }

    /// The truth after `printed` layers; `None` when the defect has not been printed yet.
    pub fn truth(&self, part: &Part, printed: u32) -> Option<Truth> {
        let (lo, hi) = part.design.bounds();
        let centre = nalgebra::center(&lo, &hi);
        let top = printed.checked_sub(1)?;
        let layers_z = |a: u32, b: u32| 0.5 * (part.layer_span(a).0 + part.layer_span(b).1);
        let t = match *self {
            Defect::Extrusion { first, last, width } => {
                if first > top {
                    return None;
                }
                let last = last.min(top);
                Truth {
                    kind: self.kind(),
                    magnitude: width,
                    position: Point3::new(centre.x, centre.y, layers_z(first, last)),
                    layers: (first, last),
                    direction: None,
                }
            }
            Defect::HeightDrift { from, per_layer } => {
                if from > top {
                    return None;
                }
                Truth {
                    kind: self.kind(),
                    magnitude: per_layer * (printed - from) as f64,
                    position: Point3::new(centre.x, centre.y, part.layer_span(top).1),
                    layers: (from, top),
                    direction: None,
                }
            }
            Defect::LateralShift { from, offset } => {
                if from > top {
                    return None;
                }
                let v = Vector2::from(offset);
                Truth {
                    kind: self.kind(),
                    magnitude: v.norm(),
                    position: Point3::new(centre.x, centre.y, layers_z(from, top)),
                    layers: (from, top),
                    direction: Some((v / v.norm().max(f64::MIN_POSITIVE)).into()),
                }
            }
            Defect::Sag { layers, depth } => {
                let first = printed.saturating_sub(layers);
                Truth {
                    kind: self.kind(),
                    magnitude: -depth,
                    position: Point3::new(centre.x, centre.y, part.layer_span(top).1),
                    layers: (first, top),
                    direction: None,
                }
            }
            Defect::MissingSegment {
                layer,
                centre: c,
                direction,
                length,
            } => {
                if layer > top {
                    return None;
                }
                Truth {
                    kind: self.kind(),
                    magnitude: length,
                    position: Point3::new(c[0], c[1], layers_z(layer, layer)),
                    layers: (layer, layer),
                    direction: Some(direction),
                }
            }
            Defect::Bulge {
                centre: c,
                radius,
                height,
            } => {
                let printed_top = part.layer_span(top).1;
                if c[2] - radius > printed_top {
                    return None;
                }
                let lh = part.layer_height;
                let first = ((c[2] - radius) / lh).floor().max(0.0) as u32;
                let last = (((c[2] + radius) / lh).ceil() as u32).min(printed) - 1;
                Truth {
                    kind: self.kind(),
                    magnitude: height,
                    position: Point3::from(c),
                    layers: (first, last.max(first)),
                    direction: None,
                }
            }
        };
        Some(t)
    }
}

/// What the printer was set to for one layer: the advice it applied, nominal without any.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LayerSettings {
    /// Metres added to the layer's height.
    pub z_offset: f64,
    /// Factor on the nominal flow.
    pub flow: f64,
    /// Metres the path is moved by, x and y.
    pub path_offset: [f64; 2],
}

impl LayerSettings {
    /// As designed.
    pub const NOMINAL: LayerSettings = LayerSettings {
        z_offset: 0.0,
        flow: 1.0,
        path_offset: [0.0; 2],
    };

    /// The share `k` of these settings' departure from nominal: what a printer that applies
    /// that much of the advice prints.
    pub fn scaled(self, k: f64) -> Self {
        Self {
            z_offset: self.z_offset * k,
            flow: 1.0 + (self.flow - 1.0) * k,
            path_offset: [self.path_offset[0] * k, self.path_offset[1] * k],
        }
    }

    /// Layer `j` as `advice` says to print it (nominal before the layer it is for).
    pub fn advised(advice: &asbuilt_protocol::LayerCorrection, j: u32) -> Self {
        if j < advice.from_layer {
            return Self::NOMINAL;
        }
        Self {
            z_offset: advice.z_offset(j),
            flow: advice.flow,
            path_offset: advice.path_offset,
        }
    }
}

/// Per-layer effect of all defects after `printed` layers.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct LayerState {
    pub z0: f64,
    pub z1: f64,
    /// Nominal span, which selects the design outline the printer followed.
    pub nominal: (f64, f64),
    /// Outward offset of the outline, per side.
    pub offset: f64,
    pub shift: [f64; 2],
}

/// Each layer's span, outline offset and shift after `printed` layers: the process
/// disturbances among `defects` (drift, extrusion, shift, sag), acted against by the
/// `settings` the printer applied to each layer (nominal past their end). A layer `bead` wide
/// at nominal flow comes out `(bead + excess) · flow` wide.
pub(crate) fn layer_states(
    part: &Part,
    defects: &[Defect],
    printed: u32,
    settings: &[LayerSettings],
    bead: f64,
) -> Vec<LayerState> {
    let mut out = Vec::with_capacity(printed as usize);
    let mut z = 0.0;
    for j in 0..printed {
        let nominal = part.layer_span(j);
        let set = settings
            .get(j as usize)
            .copied()
            .unwrap_or(LayerSettings::NOMINAL);
        let mut h = nominal.1 - nominal.0 + set.z_offset;
        let mut excess = 0.0;
        let mut offset = 0.0;
        let mut shift = set.path_offset;
        for d in defects {
            match *d {
                Defect::Extrusion { first, last, width } if (first..=last).contains(&j) => {
                    excess += width;
                }
                Defect::HeightDrift { from, per_layer } if j >= from => h += per_layer,
                Defect::LateralShift { from, offset: o } if j >= from => {
                    shift[0] += o[0];
                    shift[1] += o[1];
                }
                Defect::Sag { layers, depth } if layers > 0 => {
                    let i = printed - 1 - j;
                    if i < layers {
                        let n = layers as f64;
                        let loss = depth * 2.0 * (n - i as f64) / (n * (n + 1.0));
                        h -= loss;
                        offset += 0.5 * loss;
                    }
                }
                _ => {}
            }
        }
        // At nominal flow this adds nothing, so an open-loop print is what it always was.
        offset += 0.5 * excess + 0.5 * (bead + excess) * (set.flow - 1.0);
        out.push(LayerState {
            z0: z,
            z1: z + h,
            nominal,
            offset,
            shift,
        });
        z += h;
    }
    out
}

/// One printed layer as built, for a reviewer: where it ended up against its design.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct BuiltLayer {
    /// The layer, 0-based.
    pub layer: u32,
    /// Its bottom and top, metres.
    pub z: [f64; 2],
    /// Its top less the nominal one: the print's height error there, metres.
    pub top_error_m: f64,
    /// As built minus designed width (both sides), metres.
    pub width_error_m: f64,
    /// Its shift in x and y, metres.
    pub shift_m: [f64; 2],
}

/// Every layer of the print after `printed` layers, as built with `settings`.
pub fn built_layers(
    part: &Part,
    defects: &[Defect],
    printed: u32,
    settings: &[LayerSettings],
) -> Result<Vec<BuiltLayer>, crate::PartError> {
    let states = layer_states(part, defects, printed, settings, part.bead_width()?);
    Ok(states
        .iter()
        .enumerate()
        .map(|(j, s)| BuiltLayer {
            layer: j as u32,
            z: [s.z0, s.z1],
            top_error_m: s.z1 - s.nominal.1,
            width_error_m: 2.0 * s.offset,
            shift_m: s.shift,
        })
        .collect())
}

/// Outward displacement of a bulge at `p`.
pub(crate) fn bulge_at(defects: &[Defect], p: Point3<f64>) -> f64 {
    defects
        .iter()
        .map(|d| match *d {
            Defect::Bulge {
                centre,
                radius,
                height,
            } => {
                let r = (p - Point3::from(centre)).norm();
                if r < radius {
                    height * 0.5 * (1.0 + (std::f64::consts::PI * r / radius).cos())
                } else {
                    0.0
                }
            }
            _ => 0.0,
        })
        .sum()
}

/// The gaps of layer `j`: (centre, unit direction, length).
pub(crate) fn gaps_of(defects: &[Defect], j: u32) -> Vec<([f64; 2], [f64; 2], f64)> {
    defects
        .iter()
        .filter_map(|d| match *d {
            Defect::MissingSegment {
                layer,
                centre,
                direction,
                length,
            } if layer == j => {
                let v = Vector2::from(direction);
                let u = v / v.norm().max(f64::MIN_POSITIVE);
                Some((centre, [u.x, u.y], length))
            }
            _ => None,
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn height_drift_and_sag_change_the_layer_heights_as_specified() {
        let p = Part::wall();
        let s = layer_states(
            &p,
            &[Defect::HeightDrift {
                from: 5,
                per_layer: 0.001,
            }],
            10,
            &[],
            0.1734,
        );
        assert!((s[9].z1 - (0.2 + 0.005)).abs() < 1e-12);
        assert!((s[4].z1 - 0.1).abs() < 1e-12);
        let s = layer_states(
            &p,
            &[Defect::Sag {
                layers: 3,
                depth: 0.006,
            }],
            10,
            &[],
            0.1734,
        );
        assert!((s[9].z1 - (0.2 - 0.006)).abs() < 1e-12);
        assert!((s[6].z1 - 0.14).abs() < 1e-12);
        assert!(s[9].offset > s[8].offset && s[8].offset > s[7].offset);
    }

    #[test]
    fn settings_act_against_the_process() {
        let p = Part::wall();
        let defects = [
            Defect::HeightDrift {
                from: 2,
                per_layer: 0.001,
            },
            Defect::Extrusion {
                first: 0,
                last: 9,
                width: 0.01,
            },
            Defect::LateralShift {
                from: 0,
                offset: [0.002, -0.001],
            },
        ];
        let bead = 0.1;
        let set = LayerSettings {
            z_offset: -0.001,
            flow: bead / (bead + 0.01),
            path_offset: [-0.002, 0.001],
        };
        let open = layer_states(&p, &defects, 10, &[], bead);
        let closed = layer_states(
            &p,
            &defects,
            10,
            &[LayerSettings::NOMINAL, set, set, set],
            bead,
        );
        assert!((open[4].offset - 0.005).abs() < 1e-15);
        assert!(closed[3].offset.abs() < 1e-15 && closed[4].offset == open[4].offset);
        assert!(closed[3].shift.iter().all(|v| v.abs() < 1e-15));
        // Layers 2 and 3 drift +1 mm each, taken back; layer 1 is printed 1 mm thin.
        assert!((closed[3].z1 - (0.08 - 0.001)).abs() < 1e-12);
        assert!((open[3].z1 - 0.082).abs() < 1e-12);
    }

    #[test]
    fn a_defect_not_yet_printed_has_no_truth() {
        let p = Part::wall();
        let d = Defect::Extrusion {
            first: 20,
            last: 25,
            width: 0.01,
        };
        assert!(d.truth(&p, 10).is_none());
        let t = d.truth(&p, 23).unwrap();
        assert_eq!(t.layers, (20, 22));
        assert_eq!(t.kind, DefectKind::OverExtrusion);
    }
}
