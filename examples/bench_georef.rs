//! The cost of an IFC map placement: the shared KIT road IFC converted as it is, and with an
//! IfcProjectedCRS + IfcMapConversion added, in two forms: the road at Eastings/Northings in ETRS89
//! / UTM 32N (placed by one linear map), and the road scaled 10x (1.1 km) with its site in map
//! coordinates and E/N 0 (placed vertex by vertex through PROJ), each against the same geometry
//! without the map conversion. Prints the median wall time of each and the ratio, which should
//! stay at most 1.3.
//!
//! Usage: cargo run --release --example bench_georef -- [DATA_DIR] [--runs N]

use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::Instant;

const ROAD: &str = "KIT-Simple-Road-Test-Web-IFC4x3_RC2.ifc";

/// Appends STEP lines to the DATA section, numbered from the first free id.
fn append(text: &str, lines: &[String]) -> String {
    let i = text.rfind("ENDSEC;").expect("a DATA section");
    format!("{}{}\n{}", &text[..i], lines.join("\n"), &text[i..])
}

fn first_free_id(text: &str) -> u64 {
    text.lines()
        .filter_map(|l| {
            l.strip_prefix('#')?
                .split(['=', ' '])
                .next()?
                .parse::<u64>()
                .ok()
        })
        .max()
        .unwrap_or(0)
        + 1
}

/// The file's site RefLatitude/RefLongitude/RefElevation emptied (they name another place).
fn without_site_reference(text: &str) -> String {
    text.replace("(24, 28, 0), (54, 25, 0), 10.", "$, $, $")
}

fn with_map_conversion(text: &str, e: f64, n: f64, h: f64) -> String {
    let id = first_free_id(text);
    append(
        text,
        &[
            format!(
                "#{id} = IFCPROJECTEDCRS('EPSG:25832', 'ETRS89 / UTM zone 32N', 'EPSG:4258', \
                 'EPSG:7837', 'UTM', '32N', $);"
            ),
            format!(
                "#{} = IFCMAPCONVERSION(#20, #{id}, {e:?}, {n:?}, {h:?}, 1., 0., 0.001);",
                id + 1
            ),
        ],
    )
}

/// Every IfcCartesianPoint scaled 10x; the site's own point (#27) at `site` millimetres.
fn scaled_in_map_coordinates(text: &str, site: [f64; 3]) -> String {
    let mut out = String::with_capacity(text.len());
    for line in text.split_inclusive('\n') {
        if line.starts_with("#27 =") {
            out.push_str(&format!(
                "#27 = IFCCARTESIANPOINT(({:?}, {:?}, {:?}));\n",
                site[0], site[1], site[2]
            ));
        } else if let (Some(a), Some(b)) = (line.find("IFCCARTESIANPOINT(("), line.find("))")) {
            let start = a + "IFCCARTESIANPOINT((".len();
            let coords: Vec<String> = line[start..b]
                .split(',')
                .map(|c| {
                    format!(
                        "{:?}",
                        c.trim().parse::<f64>().expect("a coordinate") * 10.0
                    )
                })
                .collect();
            out.push_str(&line[..start]);
            out.push_str(&coords.join(", "));
            out.push_str(&line[b..]);
        } else {
            out.push_str(line);
        }
    }
    out
}

fn median_seconds(bin: &Path, ifc: &Path, out: &Path, runs: usize) -> f64 {
    let mut t: Vec<f64> = (0..runs)
        .map(|_| {
            let start = Instant::now();
            let status = Command::new(bin)
                .arg("convert")
                .arg(ifc)
                .arg("--out")
                .arg(out)
                .args(["--force", "--quiet"])
                .status()
                .expect("bimtiles runs");
            assert!(status.success(), "{} failed", ifc.display());
            start.elapsed().as_secs_f64()
        })
        .collect();
    t.sort_by(f64::total_cmp);
    t[runs / 2]
}

fn main() {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let repo = PathBuf::from(env!("CARGO_MANIFEST_DIR"));
    let runs = args
        .iter()
        .position(|a| a == "--runs")
        .and_then(|i| args.get(i + 1)?.parse().ok())
        .unwrap_or(15usize);
    let data = args
        .first()
        .filter(|a| !a.starts_with("--"))
        .map(PathBuf::from)
        .unwrap_or_else(|| repo.join("../shared/data"));
    let bin = repo.join("target/release/bimtiles");
    let text = std::fs::read_to_string(data.join(ROAD)).expect("the shared KIT road IFC");
    let text = without_site_reference(&text);
    let dir = std::env::temp_dir().join(format!("bench_georef_{}", std::process::id()));
    std::fs::create_dir_all(&dir).expect("a temporary folder");

    let (e, n, h) = (457300.0, 5439400.0, 110.0);
    let long = scaled_in_map_coordinates(&text, [e * 1000.0, n * 1000.0, h * 1000.0]);
    let pairs = [
        (
            "road, map conversion at E/N (one linear map)",
            text.clone(),
            with_map_conversion(&text, e, n, h),
        ),
        (
            "road 10x in map coordinates, E/N 0 (vertex by vertex)",
            long.clone(),
            with_map_conversion(&long, 0.0, 0.0, 0.0),
        ),
    ];
    println!("median of {runs} runs each");
    for (label, plain, placed) in pairs {
        let a = dir.join("plain.ifc");
        let b = dir.join("placed.ifc");
        std::fs::write(&a, plain).expect("write");
        std::fs::write(&b, placed).expect("write");
        let out = dir.join("out");
        let ta = median_seconds(&bin, &a, &out, runs);
        let tb = median_seconds(&bin, &b, &out, runs);
        println!(
            "{label}: without {:.1} ms, with {:.1} ms, ratio {:.2} (at most 1.3)",
            ta * 1e3,
            tb * 1e3,
            tb / ta
        );
    }
    let _ = std::fs::remove_dir_all(&dir);
}
