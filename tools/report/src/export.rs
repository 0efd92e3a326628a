//! The maps as PNG files next to report.html, for a site diary or a printed page: each map's SVG
//! (call-outs and axes included) under a title line, rendered by resvg in the system's fonts.

use std::path::{Path, PathBuf};

use crate::Report;
use crate::maps::{MapKind, ScanLayerMaps, Side};

/// Rendered at this many pixels per SVG pixel, for print.
const SCALE: f32 = 2.0;
const TITLE_PX: f64 = 22.0;

/// The maps could not be written as PNG files.
#[derive(Debug, thiserror::Error)]
pub enum ExportError {
    /// The output folder cannot be made.
    #[error("cannot create {}: {source}", dir.display())]
    Folder {
        /// The folder.
        dir: PathBuf,
        /// What the operating system said.
        source: std::io::Error,
    },
    /// A PNG file cannot be written.
    #[error("cannot write {}: {source}", path.display())]
    Write {
        /// The file.
        path: PathBuf,
        /// What the operating system said.
        source: std::io::Error,
    },
    /// A map that resvg cannot read or draw: a fault of this program, not of the input.
    #[error("cannot render {name}: {cause}")]
    Render {
        /// The map's file name.
        name: String,
        /// What resvg said.
        cause: String,
    },
}

/// What the export wrote.
#[derive(Debug, Default)]
pub struct Exported {
    /// The files written.
    pub files: Vec<PathBuf>,
    /// No system font was found: the maps carry no text (numbers, axes, titles).
    pub without_fonts: bool,
}

/// Writes every map of `report` into `dir` as `after-NNN-layers-KIND-SIDE.png` (or
/// `all-stations-…` for a job not scanned while printing).
pub fn write_map_pngs(report: &Report, dir: &Path) -> Result<Exported, ExportError> {
    std::fs::create_dir_all(dir).map_err(|source| ExportError::Folder {
        dir: dir.to_path_buf(),
        source,
    })?;
    let mut options = resvg::usvg::Options {
        font_family: "DejaVu Sans".into(),
        ..Default::default()
    };
    let fonts = options.fontdb_mut();
    fonts.load_system_fonts();
    let mut out = Exported {
        without_fonts: fonts.is_empty(),
        ..Default::default()
    };
    for maps in &report.maps {
        let scan_layer = report.assessment.as_ref().and_then(|a| {
            a.scan_layers
                .iter()
                .find(|s| s.job == maps.job && s.printed_height.map(f64::to_bits) == height(maps))
        });
        let items = scan_layer.map_or(&[][..], |s| &s.items[..]);
        let (stem, title) = match scan_layer {
            Some(s) if s.printed_height.is_some() => {
                (format!("after-{:03}-layers", s.layer + 1), s.title())
            }
            _ => ("all-stations".to_string(), "All stations".to_string()),
        };
        for kind in [MapKind::Points, MapKind::Samples] {
            for side in Side::ALL {
                let Some(svg) = maps.svg(kind, side, items) else {
                    continue;
                };
                let name = format!("{stem}-{}-{}.png", kind.name(), side.name());
                let caption = format!(
                    "{title}: {} from the {}",
                    match kind {
                        MapKind::Points => "C2M of the points",
                        MapKind::Samples => "M3C2 of the design samples",
                    },
                    side.title()
                );
                let png = render(
                    &titled(&svg, maps.svg_size(side), &caption),
                    &options,
                    &name,
                )?;
                let path = dir.join(&name);
                std::fs::write(&path, png).map_err(|source| ExportError::Write {
                    path: path.clone(),
                    source,
                })?;
                out.files.push(path);
            }
        }
    }
    Ok(out)
}

fn height(m: &ScanLayerMaps) -> Option<u64> {
    m.printed_height
        .is_finite()
        .then(|| m.printed_height.to_bits())
}

/// The map (`size` wide and high) under a title line, as a standalone SVG document.
fn titled(map: &str, (w, h): (f64, f64), caption: &str) -> String {
    // A narrow map (a wall seen end on) still gets its whole title: about 7 pixels a character.
    let w = w.max(7.0 * caption.chars().count() as f64 + 12.0);
    let inner = map.replacen("<svg ", &format!("<svg y=\"{TITLE_PX}\" "), 1);
    format!(
        "<svg xmlns=\"http://www.w3.org/2000/svg\" width=\"{w}\" height=\"{}\" \
         viewBox=\"0 0 {w} {}\"><rect width=\"100%\" height=\"100%\" fill=\"#fff\"/>\
         <text x=\"6\" y=\"15\" font-size=\"12\" font-family=\"DejaVu Sans, sans-serif\">{}</text>\
         {inner}</svg>",
        h + TITLE_PX,
        h + TITLE_PX,
        crate::markup::esc(caption)
    )
}

fn render(svg: &str, options: &resvg::usvg::Options, name: &str) -> Result<Vec<u8>, ExportError> {
    let fail = |cause: String| ExportError::Render {
        name: name.to_string(),
        cause,
    };
    let tree = resvg::usvg::Tree::from_str(svg, options).map_err(|e| fail(e.to_string()))?;
    let size = tree
        .size()
        .to_int_size()
        .scale_by(SCALE)
        .ok_or_else(|| fail("the map has no size".into()))?;
    let mut pixmap = resvg::tiny_skia::Pixmap::new(size.width(), size.height())
        .ok_or_else(|| fail(format!("{}×{} pixels", size.width(), size.height())))?;
    resvg::render(
        &tree,
        resvg::tiny_skia::Transform::from_scale(SCALE, SCALE),
        &mut pixmap.as_mut(),
    );
    pixmap.encode_png().map_err(|e| fail(e.to_string()))
}
