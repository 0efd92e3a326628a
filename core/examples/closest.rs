//! Prints the brute-force closest distance of a point to a design: `closest MESH UNITS X Y Z`.
use asbuilt_core::{C2mIndex, C2mParams};
use nalgebra::Point3;

fn main() {
    let a: Vec<String> = std::env::args().collect();
    if a.len() != 6 {
        eprintln!("usage: closest MESH m|mm X Y Z");
        std::process::exit(2);
    }
    let design =
        asbuilt_io::read_design(a[1].as_ref(), a[2].parse().expect("m or mm")).expect("design");
    let index = C2mIndex::build(&design, C2mParams::within(1e3)).expect("index");
    let p = Point3::new(
        a[3].parse().unwrap(),
        a[4].parse().unwrap(),
        a[5].parse().unwrap(),
    );
    match index.brute_force(&p) {
        Some(c) => println!(
            "distance {:.6} m, triangle {}, {:?}",
            c.distance, c.triangle, c.region
        ),
        None => println!("no triangle"),
    }
}
