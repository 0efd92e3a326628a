//! Two-cloud M3C2 against CloudCompare and PDAL on real airborne lidar (PDAL's autzen test data).

use std::path::Path;

use asbuilt_core::cloud::CloudIndex;
use asbuilt_core::m3c2::classic::{self, ClassicParams};
use asbuilt_tests::shared_data;
use las::Reader;
use nalgebra::Point3;

fn read_las(path: &Path) -> Vec<Point3<f64>> {
    let mut reader = Reader::from_path(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    let data = reader.read_all().expect("valid LAS points");
    data.x()
        .zip(data.y())
        .zip(data.z())
        .map(|((x, y), z)| Point3::new(x, y, z))
        .collect()
}

/// Rows of a CSV text export with a quoted header: column name → values.
fn read_csv(path: &Path) -> (Vec<String>, Vec<Vec<f64>>) {
    let text = std::fs::read_to_string(path).unwrap();
    let mut lines = text.lines();
    let header: Vec<String> = lines
        .next()
        .unwrap()
        .split(',')
        .map(|h| h.trim_matches('"').to_string())
        .collect();
    let rows = lines
        .filter(|l| !l.trim().is_empty())
        .map(|l| {
            l.split(',')
                .map(|v| v.trim().parse::<f64>().unwrap_or(f64::NAN))
                .collect()
        })
        .collect();
    (header, rows)
}

fn col(header: &[String], name: &str) -> usize {
    header
        .iter()
        .position(|h| h == name)
        .unwrap_or_else(|| panic!("no column {name}"))
}

fn clouds() -> (CloudIndex, CloudIndex) {
    let dir = shared_data().join("autzen-m3c2");
    let c1 = read_las(&dir.join("autzen-bmx-2010.las"));
    let c2 = read_las(&dir.join("autzen-bmx-2023.las"));
    assert_eq!((c1.len(), c2.len()), (829, 687));
    (CloudIndex::new(&c1).unwrap(), CloudIndex::new(&c2).unwrap())
}

#[test]
fn m3c2_matches_cloudcompare_at_the_larger_sample() {
    let (c1, c2) = clouds();
    let dir = shared_data().join("autzen-m3c2");
    let (h, rows) = read_csv(&dir.join("autzen-bmx-cc.txt"));
    let (x, y, z) = (col(&h, "X"), col(&h, "Y"), col(&h, "Z"));
    let (dist, unc, sig) = (
        col(&h, "M3C2 distance"),
        col(&h, "distance uncertainty"),
        col(&h, "significant change"),
    );
    let (n1, n2, s1, s2) = (
        col(&h, "Npoints_cloud1"),
        col(&h, "Npoints_cloud2"),
        col(&h, "STD_cloud1"),
        col(&h, "STD_cloud2"),
    );
    let cores: Vec<Point3<f64>> = rows.iter().map(|r| Point3::new(r[x], r[y], r[z])).collect();
    let params = ClassicParams::new(2.780864, 5.780864, 5.5);
    let ours = classic::compare(&c1, &c2, &cores, &params).unwrap();

    let (pdal_h, pdal_rows) = read_csv(&dir.join("autzen-bmx-m3c2.txt"));
    let pdal_d = col(&pdal_h, "m3c2_distance");

    let mut comparable = 0;
    let mut within = 0;
    let mut verdicts_agree = 0;
    let mut largest: f64 = 0.0;
    let mut pdal_comparable = 0;
    let mut pdal_within = 0;
    println!("core  CC distance  ours      diff     CC n1/n2  ours n1/n2  CC sig ours");
    for (i, (r, o)) in rows.iter().zip(&ours).enumerate() {
        // CloudCompare writes 0 with a zero normal where it could not fit one, and NaN where a
        // cylinder is empty: neither is a result to compare with.
        let cc_normal = [col(&h, "NormalX"), col(&h, "NormalY"), col(&h, "NormalZ")];
        if !r[dist].is_finite() || cc_normal.iter().all(|&k| r[k] == 0.0) {
            continue;
        }
        comparable += 1;
        let p = pdal_rows[i][pdal_d];
        if p.is_finite() {
            pdal_comparable += 1;
            pdal_within += ((p - r[dist]).abs() <= 0.01) as u32;
        }
        let Some(d) = o.distance else {
            println!("{i:>4}  {:>10.3}  none", r[dist]);
            continue;
        };
        let diff = d - r[dist];
        largest = largest.max(diff.abs());
        if diff.abs() <= 0.01 {
            within += 1;
            if o.significant == (r[sig] == 1.0) {
                verdicts_agree += 1;
            }
        }
        if diff.abs() > 0.01 || o.significant != (r[sig] == 1.0) {
            println!(
                "{i:>4}  {:>10.3}  {d:>8.3}  {diff:>7.3}  {:>3}/{:<3}    {:>3}/{:<3}    {}  {}",
                r[dist], r[n1], r[n2], o.cloud1.count, o.cloud2.count, r[sig], o.significant as u8
            );
        }
        // Where the distance agrees, the statistics behind it agree too (to the printed
        // precision, plus what a normal a few thousandths of a radian apart moves).
        if diff.abs() <= 0.01 {
            assert_eq!(o.cloud1.count as f64, r[n1], "core {i}");
            assert_eq!(o.cloud2.count as f64, r[n2], "core {i}");
            assert!((o.cloud1.spread - r[s1]).abs() < 0.005, "core {i}");
            assert!((o.cloud2.spread - r[s2]).abs() < 0.005, "core {i}");
            match o.lod95 {
                Some(l) => assert!((l - r[unc]).abs() < 0.005, "core {i}"),
                None => assert!(r[unc].is_nan(), "core {i}"),
            }
        }
    }
    println!(
        "asbuilt: {within} of {comparable} comparable core points within 0.01 of CloudCompare, \
         largest difference {largest:.3}; significant-change verdicts agree at {verdicts_agree} \
         of those; PDAL: {pdal_within} of {pdal_comparable}"
    );
    assert_eq!(comparable, 91);
    assert!(within >= 86, "{within} of {comparable} within 0.01");
    assert_eq!(verdicts_agree, within);
}

#[test]
fn m3c2_matches_pdal_at_its_three_core_points() {
    let (c1, c2) = clouds();
    let dir = shared_data().join("autzen-m3c2");
    let (h, rows) = read_csv(&dir.join("autzen-bmx-cores.txt"));
    let cores: Vec<Point3<f64>> = rows
        .iter()
        .map(|r| Point3::new(r[col(&h, "X")], r[col(&h, "Y")], r[col(&h, "Z")]))
        .collect();
    let params = ClassicParams::new(2.0 * 5.24414, 2.0 * 10.4882815, 2.763006);
    let ours = classic::compare(&c1, &c2, &cores, &params).unwrap();
    let want = [(1.396, 0.275), (0.670, 0.140), (1.246, 0.226)];
    for (o, (d, u)) in ours.iter().zip(want) {
        println!("{o:?}");
        assert!((o.distance.unwrap() - d).abs() <= 0.01, "{o:?} vs {d}");
        assert!((o.lod95.unwrap() - u).abs() <= 0.01, "{o:?} vs {u}");
    }
    let first = &ours[0];
    assert_eq!((first.cloud1.count, first.cloud2.count), (118, 166));
    assert!((first.cloud1.spread - 0.732).abs() <= 0.01, "{first:?}");
    assert!((first.cloud2.spread - 1.582).abs() <= 0.01, "{first:?}");
}
