//! `--png`: the report's maps as PNG files in `OUT/maps`, with a line saying where they went.

use std::path::Path;

use anyhow::Result;
use asbuilt_report::Report;

pub fn write(report: &Report, out: &Path) -> Result<()> {
    let dir = out.join("maps");
    let written = asbuilt_report::export::write_map_pngs(report, &dir)?;
    if written.files.is_empty() {
        eprintln!("no maps to write as PNG: the job has no station");
        return Ok(());
    }
    if written.without_fonts {
        eprintln!(
            "warning: no system font found: the PNG maps have no text (install fonts-dejavu-core)"
        );
    }
    eprintln!(
        "wrote {} map(s) as PNG into {}",
        written.files.len(),
        dir.display()
    );
    Ok(())
}
