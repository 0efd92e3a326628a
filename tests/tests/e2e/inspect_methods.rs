//! `asbuilt inspect --method all` as a user runs it, on a box whose as-built top is 4 mm high
//! with a 10 mm deep pit: every method's section, the per-layer table and the extra files.

use std::io::Write;
use std::path::Path;
use std::process::Command;

use std::collections::HashMap;

use asbuilt_tests::write_box_stl;
use ply_rs_bw::parser::Parser;
use ply_rs_bw::ply::DefaultElement;
use serde_json::Value;

const STATION: [f64; 3] = [0.2, -0.6, 0.8];
const RAISE: f64 = 0.004;
const PIT: f64 = 0.010;
/// The pit floor under the design's top.
const PIT_BELOW_DESIGN: f64 = PIT - RAISE;

fn in_pit(x: f64, y: f64) -> bool {
    (0.1..0.2).contains(&x) && (0.1..0.2).contains(&y)
}

/// The as-built box 0.4 × 0.3 × (0.2 + 4 mm) on a 2 mm grid: top (with the pit floor) and the
/// four sides up to the raised top, no bottom. Written in the scanner frame: p_scan = p_design − station.
fn write_scan(path: &Path) -> Vec<[f64; 3]> {
    let mut f = std::io::BufWriter::new(std::fs::File::create(path).unwrap());
    let top = 0.2 + RAISE;
    let mut written = Vec::new();
    let mut put = |x: f64, y: f64, z: f64| {
        writeln!(
            f,
            "{:.6} {:.6} {:.6}",
            x - STATION[0],
            y - STATION[1],
            z - STATION[2]
        )
        .unwrap();
        written.push([x, y, z]);
    };
    let s = 0.002;
    for i in 0..=200 {
        for j in 0..=150 {
            let (x, y) = (i as f64 * s, j as f64 * s);
            put(x, y, if in_pit(x, y) { top - PIT } else { top });
        }
    }
    for k in 1..=102 {
        let z = k as f64 * s;
        for i in 0..=200 {
            put(i as f64 * s, 0.0, z);
            put(i as f64 * s, 0.3, z);
        }
        for j in 1..150 {
            put(0.0, j as f64 * s, z);
            put(0.4, j as f64 * s, z);
        }
    }
    written
}

/// A fresh folder with the design, the box 0.4 × 0.3 × 0.2 m (`box.stl`), and its as-built
/// scan (`scan.xyz`); returns the folder and the scan's points in the design frame.
fn box_job() -> (tempfile::TempDir, Vec<[f64; 3]>) {
    let dir = tempfile::tempdir().unwrap();
    write_box_stl(&dir.path().join("box.stl"), [0.0; 3], [0.4, 0.3, 0.2]);
    let scan = write_scan(&dir.path().join("scan.xyz"));
    (dir, scan)
}

fn inspect(dir: &Path, extra: &[&str]) -> (Value, std::path::PathBuf) {
    let out = dir.join(extra.join("_").replace(['-', '.', ','], ""));
    let status = Command::new(env!("CARGO_BIN_EXE_e2e-asbuilt"))
        .arg("inspect")
        .args(["--design", dir.join("box.stl").to_str().unwrap()])
        .args([
            "--units",
            "m",
            "--scan",
            dir.join("scan.xyz").to_str().unwrap(),
        ])
        .args([
            "--translation",
            "0.2,-0.6,0.8",
            "--rotation-xyzw",
            "0,0,0,1",
        ])
        .args(["--max-distance", "0.02", "--out", out.to_str().unwrap()])
        .args(extra)
        .status()
        .unwrap();
    assert!(status.success());
    let text = std::fs::read_to_string(out.join("report.json")).unwrap();
    (serde_json::from_str(&text).unwrap(), out)
}

/// Every vertex of a PLY file as column → value.
fn ply_rows(path: &Path) -> Vec<HashMap<String, f64>> {
    let mut f = std::io::BufReader::new(std::fs::File::open(path).unwrap());
    let ply = Parser::<DefaultElement>::new().read_ply(&mut f).unwrap();
    ply.payload["vertex"]
        .iter()
        .map(|v| {
            v.iter()
                .map(|(k, p)| (k.clone(), ply_scalar(p).unwrap()))
                .collect()
        })
        .collect()
}

/// A numeric PLY property as f64 (exact for every PLY scalar type).
fn ply_scalar(p: &ply_rs_bw::ply::Property) -> Option<f64> {
    use ply_rs_bw::ply::Property as P;
    Some(match *p {
        P::Float(v) => v as f64,
        P::Double(v) => v,
        P::Char(v) => v as f64,
        P::UChar(v) => v as f64,
        P::Short(v) => v as f64,
        P::UShort(v) => v as f64,
        P::Int(v) => v as f64,
        P::UInt(v) => v as f64,
        _ => return None,
    })
}

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

/// Inspect's findings for the box: the pit is one deficit region of -6 mm where it is (the
/// raised top's +4 mm is within the 5 mm tolerance), and every layer band's walls are where
/// the design has them.
fn assert_findings_at_the_pit(r: &serde_json::Value, truth: f64) {
    let findings = r["findings"].as_array().unwrap();
    assert_eq!(findings.len(), 1, "{findings:?}");
    let f = &findings[0];
    assert_eq!(f["stations"], 1);
    let regions = f["regions"].as_array().unwrap();
    assert_eq!(regions.len(), 1, "{regions:?}");
    let pit = &regions[0];
    assert_eq!(pit["kind"], "Deficit");
    assert!(
        (pit["peak"].as_f64().unwrap() + PIT_BELOW_DESIGN).abs() < 1e-4,
        "{pit}"
    );
    let c = &pit["centroid"];
    assert!(
        in_pit(c[0].as_f64().unwrap(), c[1].as_f64().unwrap()),
        "{pit}"
    );
    let pit_area = pit["area_m2"].as_f64().unwrap();
    assert!(
        (pit_area - truth).abs() < 0.15 * truth,
        "{pit_area} vs {truth}"
    );
    let rows = f["layers"].as_array().unwrap();
    assert_eq!(rows.len(), 4, "{rows:?}");
    assert!(
        rows.iter()
            .all(|l| l["width_deviation"].as_f64().unwrap().abs() < 1e-6),
        "{rows:?}"
    );
}

#[test]
fn every_method_reports_the_raised_top_and_the_pit() {
    let (dir, scan) = box_job();
    let points = scan.len();
    let (r, out) = inspect(
        dir.path(),
        &[
            "--method",
            "all",
            "--spacing",
            "0.004",
            "--layer-height",
            "0.05",
        ],
    );
    assert_eq!(
        r["methods"],
        serde_json::json!(["c2m", "c2c", "coverage", "m3c2"])
    );
    let o = &r["overall"];
    assert_eq!(o["points"], points);

    // C2C to design samples with a local plane follows the faces: the top's 4 mm, the pit's
    // 6 mm (more where six samples straddle an edge and the plane tilts).
    let c2c = &o["c2c"];
    assert_eq!(c2c["no_match"], 0);
    assert!(
        (c2c["p95_abs"].as_f64().unwrap() - RAISE).abs() < 0.0002,
        "{c2c}"
    );
    assert!(
        c2c["max"].as_f64().unwrap() > PIT_BELOW_DESIGN - 0.0002,
        "{c2c}"
    );

    // Coverage: only the pit is missing; its area is the pit less a rim where the raised top
    // beside it stands on the sample's normal line (within the 3 mm threshold of it).
    let cov = &o["coverage"];
    let rim: f64 = 0.003;
    let truth = (0.1 - 2.0 * rim).powi(2);
    let area = cov["missing_area_m2"].as_f64().unwrap();
    assert!((area - truth).abs() < 0.15 * truth, "{area} vs {truth}");
    assert!(cov["occluded"].as_u64().unwrap() == 0);
    assert!(cov["reverse_c2c"]["matched"].as_u64().unwrap() > 0);
    assert_eq!(r["stations"][0]["coverage"]["missing"], cov["missing"]);

    // M3C2 along the design normals: +4 mm on the top, −6 mm in the pit, both significant.
    // (STL holds f32: the top is at 0.2 to 1e-8.)
    // (Cylinders that cross an edge mix two faces; the table is read away from the edges.)
    let m = &o["m3c2"];
    let core = ply_rows(&out.join("m3c2.ply"));
    assert_eq!(core.len() as u64, m["core_points"].as_u64().unwrap());
    let on_top = |r: &HashMap<String, f64>| (r["z"] - 0.2).abs() < 1e-6;
    let away = |v: f64, lo: f64, hi: f64| v > lo + 0.01 && v < hi - 0.01;
    let pit: Vec<&HashMap<String, f64>> = core
        .iter()
        .filter(|r| on_top(r) && away(r["x"], 0.1, 0.2) && away(r["y"], 0.1, 0.2))
        .collect();
    let top: Vec<&HashMap<String, f64>> = core
        .iter()
        .filter(|r| on_top(r) && away(r["x"], 0.0, 0.4) && away(r["y"], 0.0, 0.3))
        .filter(|r| !(r["x"] > 0.09 && r["x"] < 0.21 && r["y"] > 0.09 && r["y"] < 0.21))
        .collect();
    let d = |v: &[&HashMap<String, f64>]| median(v.iter().map(|r| r["distance"]).collect());
    assert!((d(&pit) + PIT_BELOW_DESIGN).abs() < 1e-4, "{}", d(&pit));
    assert!((d(&top) - RAISE).abs() < 1e-4, "{}", d(&top));
    assert!(pit.iter().chain(&top).all(|r| r["significant"] == 1.0));

    // Layers: four bands of 5 cm up to the design's top; the walls sit on the design, the
    // pit floor (6 mm under the design's top) pulls the top band's C2M mean down, and the
    // raised top itself stands above every band.
    let layers = r["layers"].as_array().unwrap();
    assert_eq!(layers.len(), 4, "{layers:?}");
    for l in &layers[..3] {
        assert!(l["c2m"]["mean"].as_f64().unwrap().abs() < 1e-6, "{l}");
    }
    assert!(layers[3]["c2m"]["mean"].as_f64().unwrap() < -1e-4);
    // The design's top face closes the top band: the pit's missing area and the top's
    // +4 mm core points are there.
    assert_eq!(layers[3]["missing_area_m2"], cov["missing_area_m2"]);
    assert!(layers[3]["m3c2"]["mean"].as_f64().unwrap() > 0.001);
    assert_findings_at_the_pit(&r, truth);
    // missing.ply: the station's and the job's missing samples, all in the pit.
    let missing = ply_rows(&out.join("missing.ply"));
    assert_eq!(missing.len() as u64, 2 * cov["missing"].as_u64().unwrap());
    assert!(
        missing
            .iter()
            .all(|r| (r["z"] - 0.2).abs() < 1e-6 && in_pit(r["x"], r["y"])),
        "missing outside the pit"
    );
    // The job's rows carry the reverse distance: the pit floor, 6 mm under the design.
    let rev: Vec<f64> = missing
        .iter()
        .filter(|r| r["station"] == -1.0)
        .map(|r| r["reverse_c2c"])
        .collect();
    assert!((median(rev) + PIT_BELOW_DESIGN).abs() < 1e-4);
}

#[test]
fn the_design_cut_at_the_printed_height_is_compared_and_what_stands_above_is_excess() {
    let (dir, scan) = box_job();
    let (r, _) = inspect(
        dir.path(),
        &["--printed-height", "0.1", "--layer-height", "0.02"],
    );
    let o = &r["overall"];
    // Excess: more than the tolerance (5 mm) above the cut.
    let above = scan.iter().filter(|p| p[2] > 0.105 + 1e-6).count() as u64;
    assert_eq!(o["above_printed_height"].as_u64().unwrap(), above);
    // Five bands up to the cut; points on the walls below it are on the design.
    let layers = r["layers"].as_array().unwrap();
    assert_eq!(layers.len(), 5, "{layers:?}");
    for l in layers {
        assert!(l["c2m"]["mean"].as_f64().unwrap().abs() < 1e-6, "{l}");
    }
    assert_eq!(r["parameters"]["printed_height_m"], 0.1);
}

/// A reference cloud 1 mm above the scan: C2C to it is 1 mm, and two-cloud M3C2 from it to
/// the scan is −1 mm along the top's +z normal.
#[test]
fn a_reference_cloud_drives_c2c_and_two_cloud_m3c2() {
    let (dir, scan) = box_job();
    let reference = dir.path().join("reference.xyz");
    let mut f = std::io::BufWriter::new(std::fs::File::create(&reference).unwrap());
    writeln!(f, "X Y Z").unwrap();
    for p in &scan {
        writeln!(f, "{:.6} {:.6} {:.6}", p[0], p[1], p[2] + 0.001).unwrap();
    }
    drop(f);
    let (r, out) = inspect(
        dir.path(),
        &[
            "--method",
            "c2c,m3c2",
            "--reference",
            reference.to_str().unwrap(),
            "--spacing",
            "0.01",
            "--normal-diameter",
            "0.008",
        ],
    );
    let c2c = &r["overall"]["c2c"];
    assert!(
        (c2c["median_abs"].as_f64().unwrap() - 0.001).abs() < 2e-5,
        "{c2c}"
    );
    let two = &r["m3c2_two_cloud"];
    assert_eq!(two["reference_points"], scan.len());
    let rows = ply_rows(&out.join("m3c2_two_cloud.ply"));
    assert_eq!(rows.len() as u64, two["core_points"].as_u64().unwrap());
    let top: Vec<f64> = rows
        .iter()
        .filter(|r| {
            r["z"] > 0.2 && r["x"] > 0.01 && r["x"] < 0.39 && r["y"] > 0.01 && r["y"] < 0.29
        })
        .filter(|r| !(r["x"] > 0.09 && r["x"] < 0.21 && r["y"] > 0.09 && r["y"] < 0.21))
        .map(|r| r["distance"])
        .collect();
    assert!(top.len() > 100);
    assert!((median(top) + 0.001).abs() < 1e-5);
}

#[test]
fn bad_method_arguments_are_refused_with_what_to_do() {
    let out = Command::new(env!("CARGO_BIN_EXE_e2e-asbuilt"))
        .args([
            "inspect", "--design", "x.stl", "--units", "m", "--scan", "s.xyz",
        ])
        .args(["--translation", "0,0,0", "--rotation-xyzw", "0,0,0,1"])
        .args(["--method", "c2m,icp"])
        .output()
        .unwrap();
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("unknown method \"icp\""), "{err}");

    let out = Command::new(env!("CARGO_BIN_EXE_e2e-asbuilt"))
        .args([
            "inspect", "--design", "x.stl", "--units", "m", "--scan", "s.xyz",
        ])
        .args(["--translation", "0,0,0", "--rotation-xyzw", "0,0,0,1"])
        .args(["--method", "coverage", "--reference", "r.xyz"])
        .output()
        .unwrap();
    assert_eq!(out.status.code(), Some(2));
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("add --method c2c or --method m3c2"), "{err}");
}
