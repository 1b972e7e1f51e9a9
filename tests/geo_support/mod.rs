//! GDAL/PROJ as the independent peer for the CRS tests: `gdaltransform` projects points, `gdalsrsinfo` reads a
//! WKT's EPSG code, `gdalinfo` reads a GeoTIFF. All come with `gdal-bin` (tools/setup-debian.sh installs it); a
//! missing tool fails the test with the apt line, never skips it.
#![allow(dead_code)]

use std::io::Write;
use std::process::{Command, Stdio};

fn tool(name: &str) -> Command {
    let found = Command::new("sh").arg("-c").arg(format!("command -v {name}")).output().map(|o| o.status.success());
    assert!(
        found.unwrap_or(false),
        "{name} not found: the CRS tests compare against GDAL/PROJ. Install it with `apt-get install gdal-bin` \
         (tools/setup-debian.sh does)"
    );
    Command::new(name)
}

/// `gdaltransform -s_srs SRC -t_srs DST` on `points` (x y z each; geographic CRSs take longitude, latitude).
pub fn gdaltransform(src: &str, dst: &str, points: &[[f64; 3]]) -> Vec<[f64; 3]> {
    let mut child = tool("gdaltransform")
        .args(["-s_srs", src, "-t_srs", dst])
        .stdin(Stdio::piped())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("start gdaltransform");
    {
        let mut stdin = child.stdin.take().expect("stdin");
        for p in points {
            writeln!(stdin, "{:.12} {:.12} {:.12}", p[0], p[1], p[2]).expect("write");
        }
    }
    let out = child.wait_with_output().expect("gdaltransform");
    assert!(out.status.success(), "gdaltransform: {}", String::from_utf8_lossy(&out.stderr));
    let text = String::from_utf8_lossy(&out.stdout);
    let v: Vec<[f64; 3]> = text
        .lines()
        .filter(|l| !l.trim().is_empty())
        .map(|l| {
            let n: Vec<f64> = l.split_whitespace().map(|x| x.parse().expect("number")).collect();
            [n[0], n[1], n[2]]
        })
        .collect();
    assert_eq!(v.len(), points.len(), "gdaltransform output: {text}");
    v
}

/// What `gdalsrsinfo -o epsg` makes of a CRS definition (e.g. `EPSG:32650`).
pub fn gdalsrsinfo_epsg(definition: &str) -> String {
    let out = tool("gdalsrsinfo").args(["-o", "epsg", definition]).output().expect("gdalsrsinfo");
    assert!(out.status.success(), "gdalsrsinfo: {}", String::from_utf8_lossy(&out.stderr));
    String::from_utf8_lossy(&out.stdout).trim().to_string()
}

/// `gdalsrsinfo -o FORMAT EPSG:n` (e.g. `wkt1`, `wkt2`), on one line.
pub fn gdalsrsinfo(format: &str, definition: &str) -> String {
    let out = tool("gdalsrsinfo").args(["--single-line", "-o", format, definition]).output().expect("gdalsrsinfo");
    assert!(out.status.success(), "gdalsrsinfo: {}", String::from_utf8_lossy(&out.stderr));
    String::from_utf8_lossy(&out.stdout).trim().to_string()
}

/// `gdalinfo FILE` output.
pub fn gdalinfo(path: &std::path::Path) -> String {
    let out = tool("gdalinfo").arg(path).output().expect("gdalinfo");
    assert!(out.status.success(), "gdalinfo: {}", String::from_utf8_lossy(&out.stderr));
    String::from_utf8_lossy(&out.stdout).into_owned()
}

/// The OGC WKT of a LAS file's `LASF_Projection`/2112 record and whether the header's WKT bit is set, read from
/// the bytes as the LAS 1.4 specification lays them out (not through the `las` crate msnerf writes with).
pub fn las_wkt(path: &std::path::Path) -> (Option<String>, bool) {
    let b = std::fs::read(path).expect("read LAS");
    assert_eq!(&b[0..4], b"LASF", "not a LAS file");
    let u16_at = |o: usize| u16::from_le_bytes([b[o], b[o + 1]]);
    let u32_at = |o: usize| u32::from_le_bytes(b[o..o + 4].try_into().unwrap());
    let u64_at = |o: usize| u64::from_le_bytes(b[o..o + 8].try_into().unwrap());
    let global_encoding = u16_at(6);
    let header_size = u16_at(94) as usize;
    let n_vlr = u32_at(100) as usize;
    let mut wkt = None;
    let mut o = header_size;
    for _ in 0..n_vlr {
        let user = String::from_utf8_lossy(&b[o + 2..o + 18]).trim_end_matches('\0').to_string();
        let record = u16_at(o + 18);
        let len = u16_at(o + 20) as usize;
        if user == "LASF_Projection" && record == 2112 {
            wkt = Some(String::from_utf8_lossy(&b[o + 54..o + 54 + len]).trim_end_matches('\0').to_string());
        }
        o += 54 + len;
    }
    // LAS 1.4 extended VLRs (after the points) may hold it too.
    let (evlr_start, n_evlr) = (u64_at(235) as usize, u32_at(243) as usize);
    let mut o = evlr_start;
    for _ in 0..n_evlr {
        let user = String::from_utf8_lossy(&b[o + 2..o + 18]).trim_end_matches('\0').to_string();
        let record = u16_at(o + 18);
        let len = u64_at(o + 20) as usize;
        if user == "LASF_Projection" && record == 2112 {
            wkt = Some(String::from_utf8_lossy(&b[o + 60..o + 60 + len]).trim_end_matches('\0').to_string());
        }
        o += 60 + len;
    }
    (wkt, global_encoding & 0x10 != 0)
}

/// `gdalinfo -json FILE`, parsed.
pub fn gdalinfo_json(path: &std::path::Path) -> serde_json::Value {
    let out = tool("gdalinfo").arg("-json").arg(path).output().expect("gdalinfo");
    assert!(out.status.success(), "gdalinfo: {}", String::from_utf8_lossy(&out.stderr));
    serde_json::from_slice(&out.stdout).expect("gdalinfo -json output")
}

/// The band values GDAL reads at pixel (x, y) of the full resolution (`overview` None) or of overview `k` (x, y in
/// that overview's pixels).
pub fn gdallocationinfo(path: &std::path::Path, overview: Option<usize>, x: usize, y: usize) -> Vec<f64> {
    let mut cmd = tool("gdallocationinfo");
    cmd.arg("-valonly");
    let (mut x, mut y) = (x, y);
    if let Some(k) = overview {
        // gdallocationinfo (GDAL 3.6) takes the location in full-resolution pixels and rounds it to the overview's:
        // the overview pixel's top-left corner maps back exactly.
        cmd.args(["-overview", &(k + 1).to_string()]);
        let f = 2usize.pow(k as u32 + 1);
        (x, y) = (x * f, y * f);
    }
    let out = cmd.arg(path).arg(x.to_string()).arg(y.to_string()).output().expect("gdallocationinfo");
    assert!(out.status.success(), "gdallocationinfo: {}", String::from_utf8_lossy(&out.stderr));
    String::from_utf8_lossy(&out.stdout).lines().map(|l| l.trim().parse().expect("a number")).collect()
}

/// GDAL's own COG validator (`validate_cloud_optimized_geotiff.py --full-check=yes`, from python3-gdal): its output,
/// asserting that it calls the file valid.
pub fn validate_cog(path: &std::path::Path) -> String {
    let script = "/usr/lib/python3/dist-packages/osgeo_utils/samples/validate_cloud_optimized_geotiff.py";
    assert!(
        std::path::Path::new(script).is_file() && std::path::Path::new("/usr/bin/python3").is_file(),
        "{script} not found: the COG tests run GDAL's validator. Install it with `apt-get install python3-gdal` \
         (tools/setup-debian.sh does)"
    );
    let out =
        Command::new("/usr/bin/python3").arg(script).arg("--full-check=yes").arg(path).output().expect("validator");
    let text = format!("{}{}", String::from_utf8_lossy(&out.stdout), String::from_utf8_lossy(&out.stderr));
    assert!(out.status.success() && text.contains("is a valid cloud optimized GeoTIFF"), "COG validator: {text}");
    text
}
