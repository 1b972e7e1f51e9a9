//! Shared by the rig-import tests: where the real files are, and an independent phase correlation.

#![allow(dead_code)]

use std::path::PathBuf;

use rustfft::num_complex::Complex;
use rustfft::FftPlanner;

/// The real sensor files: `tests/fixtures/real` in the repository (with their licences), or `$MSNERF_REAL_DATA`.
/// Fails loudly: these tests must run.
pub fn real_dir() -> PathBuf {
    let dir = match std::env::var("MSNERF_REAL_DATA") {
        Ok(p) => PathBuf::from(p),
        Err(_) => PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("tests/fixtures/real"),
    };
    assert!(dir.join("micasense-rededge").is_dir(), "the real sensor files are missing from {}", dir.display());
    dir
}

/// Reads a float32 chunky TIFF into per-band planes (width, height, bands).
pub fn read_f32_bands(path: &std::path::Path) -> (usize, usize, Vec<Vec<f32>>) {
    use tiff::decoder::{Decoder, DecodingResult};
    let mut d = Decoder::new(std::io::BufReader::new(std::fs::File::open(path).unwrap())).unwrap();
    let (w, h) = d.dimensions().unwrap();
    let DecodingResult::F32(v) = d.read_image().unwrap() else { panic!("not float32") };
    let (w, h) = (w as usize, h as usize);
    let nb = v.len() / (w * h);
    let bands = (0..nb).map(|b| (0..w * h).map(|i| v[i * nb + b]).collect()).collect();
    (w, h, bands)
}

/// Gradient magnitude by central differences.
pub fn grad_mag(v: &[f32], w: usize, h: usize) -> Vec<f64> {
    let mut out = vec![0.0; w * h];
    for y in 1..h - 1 {
        for x in 1..w - 1 {
            let gx = (v[y * w + x + 1] - v[y * w + x - 1]) as f64;
            let gy = (v[(y + 1) * w + x] - v[(y - 1) * w + x]) as f64;
            out[y * w + x] = (gx * gx + gy * gy).sqrt();
        }
    }
    out
}

/// Shift (dx, dy) such that b(x) ~ a(x - d), by phase correlation of an `n` x `n` tile at (x0, y0) (Hann
/// window; the normalised cross-power spectrum weighted by a Gaussian so the peak is smooth; sub-pixel peak by
/// a 3-point fit of the log peak, exact for a Gaussian).
pub fn phase_shift(a: &[f64], b: &[f64], w: usize, x0: usize, y0: usize, n: usize) -> (f64, f64) {
    let mut planner = FftPlanner::<f64>::new();
    let fft = planner.plan_fft_forward(n);
    let ifft = planner.plan_fft_inverse(n);
    let tile = |src: &[f64]| -> Vec<Complex<f64>> {
        let mut m = 0.0;
        for y in 0..n {
            for x in 0..n {
                m += src[(y0 + y) * w + x0 + x];
            }
        }
        m /= (n * n) as f64;
        let hann = |i: usize| 0.5 - 0.5 * (2.0 * std::f64::consts::PI * i as f64 / n as f64).cos();
        (0..n * n)
            .map(|i| {
                let (x, y) = (i % n, i / n);
                Complex::new((src[(y0 + y) * w + x0 + x] - m) * hann(x) * hann(y), 0.0)
            })
            .collect()
    };
    let fft2 = |d: &mut Vec<Complex<f64>>, inverse: bool| {
        let f = if inverse { &ifft } else { &fft };
        for r in d.chunks_mut(n) {
            f.process(r);
        }
        let mut col = vec![Complex::new(0.0, 0.0); n];
        for x in 0..n {
            for y in 0..n {
                col[y] = d[y * n + x];
            }
            f.process(&mut col);
            for y in 0..n {
                d[y * n + x] = col[y];
            }
        }
    };
    let (mut fa, mut fb) = (tile(a), tile(b));
    fft2(&mut fa, false);
    fft2(&mut fb, false);
    let sigma = n as f64 / 6.0;
    let mut r: Vec<Complex<f64>> = fa
        .iter()
        .zip(&fb)
        .enumerate()
        .map(|(i, (p, q))| {
            let c = q * p.conj();
            let (u, v) = ((i % n) as f64, (i / n) as f64);
            let (u, v) =
                (if u > n as f64 / 2.0 { u - n as f64 } else { u }, if v > n as f64 / 2.0 { v - n as f64 } else { v });
            let g = (-(u * u + v * v) / (2.0 * sigma * sigma)).exp();
            if c.norm() > 1e-30 {
                c / c.norm() * g
            } else {
                Complex::new(0.0, 0.0)
            }
        })
        .collect();
    fft2(&mut r, true);
    let re: Vec<f64> = r.iter().map(|c| c.re).collect();
    let (imax, _) = re.iter().enumerate().max_by(|a, b| a.1.total_cmp(b.1)).unwrap();
    let (px, py) = (imax % n, imax / n);
    let at = |x: isize, y: isize| {
        re[(y.rem_euclid(n as isize) as usize) * n + x.rem_euclid(n as isize) as usize].max(1e-12).ln()
    };
    let fit = |m: f64, c: f64, p: f64| {
        let den = m - 2.0 * c + p;
        if den.abs() < 1e-12 {
            0.0
        } else {
            0.5 * (m - p) / den
        }
    };
    let (xi, yi) = (px as isize, py as isize);
    let dx = fit(at(xi - 1, yi), at(xi, yi), at(xi + 1, yi));
    let dy = fit(at(xi, yi - 1), at(xi, yi), at(xi, yi + 1));
    let wrap = |p: usize, d: f64| if p > n / 2 { p as f64 - n as f64 + d } else { p as f64 + d };
    (wrap(px, dx), wrap(py, dy))
}

/// EXIF facts of a fixture file.
pub struct FixtureExif {
    pub exposure: (u32, u32),
    pub iso: u16,
    pub black_level: u16,
    pub make: &'static str,
    pub model: &'static str,
    /// EXIF Software: the firmware version (MicaSense's DLS2 rules depend on it).
    pub software: &'static str,
    pub datetime: String,
    pub gps: Option<(f64, f64, f64)>,
    pub focal_plane_res_per_mm: Option<f64>,
    /// EXIF FocalLength (mm).
    pub focal_mm: Option<f64>,
}

fn dms(v: f64) -> Vec<exif::Rational> {
    let v = v.abs();
    let d = v.floor();
    let m = ((v - d) * 60.0).floor();
    let s = ((v - d) * 60.0 - m) * 60.0;
    vec![
        exif::Rational { num: d as u32, denom: 1 },
        exif::Rational { num: m as u32, denom: 1 },
        exif::Rational { num: (s * 1e6).round() as u32, denom: 1_000_000 },
    ]
}

/// Writes a single-band 16-bit TIFF the way rig cameras do: IFD0 with the image, BlackLevel (50714) and the XMP
/// packet (700); the Exif IFD with exposure and ISO; a GPS IFD. Written with kamadak-exif's TIFF writer, an
/// implementation independent of msnerf's readers.
pub fn write_rig_tiff(path: &std::path::Path, w: u32, h: u32, px: &[u16], xmp: &str, e: &FixtureExif) {
    use exif::{Context, Field, In, Rational, Tag, Value};
    let f = |tag: Tag, value: Value| Field { tag, ifd_num: In::PRIMARY, value };
    let ascii = |s: &str| Value::Ascii(vec![s.as_bytes().to_vec()]);
    let mut fields = vec![
        f(Tag::ImageWidth, Value::Long(vec![w])),
        f(Tag::ImageLength, Value::Long(vec![h])),
        f(Tag::BitsPerSample, Value::Short(vec![16])),
        f(Tag::Compression, Value::Short(vec![1])),
        f(Tag::PhotometricInterpretation, Value::Short(vec![1])),
        f(Tag::SamplesPerPixel, Value::Short(vec![1])),
        f(Tag::RowsPerStrip, Value::Long(vec![h])),
        f(Tag::PlanarConfiguration, Value::Short(vec![1])),
        f(Tag::Make, ascii(e.make)),
        f(Tag::Model, ascii(e.model)),
        f(Tag::Software, ascii(e.software)),
        f(Tag(Context::Tiff, 700), Value::Byte(xmp.as_bytes().to_vec())),
        f(Tag(Context::Tiff, 50714), Value::Short(vec![e.black_level; 4])),
        f(Tag::ExposureTime, Value::Rational(vec![Rational { num: e.exposure.0, denom: e.exposure.1 }])),
        f(Tag::ISOSpeed, Value::Long(vec![e.iso as u32])),
        f(Tag::DateTimeOriginal, ascii(&e.datetime)),
    ];
    if let Some(r) = e.focal_plane_res_per_mm {
        fields.push(f(
            Tag::FocalPlaneXResolution,
            Value::Rational(vec![Rational { num: (r * 1000.0) as u32, denom: 1000 }]),
        ));
        fields.push(f(
            Tag::FocalPlaneYResolution,
            Value::Rational(vec![Rational { num: (r * 1000.0) as u32, denom: 1000 }]),
        ));
        fields.push(f(Tag::FocalPlaneResolutionUnit, Value::Short(vec![4])));
    }
    if let Some(fm) = e.focal_mm {
        fields.push(f(Tag::FocalLength, Value::Rational(vec![Rational { num: (fm * 1000.0) as u32, denom: 1000 }])));
    }
    if let Some((lat, lon, alt)) = e.gps {
        fields.push(f(Tag::GPSLatitudeRef, ascii(if lat < 0.0 { "S" } else { "N" })));
        fields.push(f(Tag::GPSLatitude, Value::Rational(dms(lat))));
        fields.push(f(Tag::GPSLongitudeRef, ascii(if lon < 0.0 { "W" } else { "E" })));
        fields.push(f(Tag::GPSLongitude, Value::Rational(dms(lon))));
        fields.push(f(Tag::GPSAltitudeRef, Value::Byte(vec![0])));
        fields.push(f(Tag::GPSAltitude, Value::Rational(vec![Rational { num: (alt * 1000.0) as u32, denom: 1000 }])));
    }
    let bytes: Vec<u8> = px.iter().flat_map(|v| v.to_le_bytes()).collect();
    let strips: [&[u8]; 1] = [&bytes];
    let mut wr = exif::experimental::Writer::new();
    for fl in &fields {
        wr.push_field(fl);
    }
    wr.set_strips(&strips, In::PRIMARY);
    let mut buf = std::io::Cursor::new(Vec::new());
    wr.write(&mut buf, true).expect("write TIFF");
    std::fs::write(path, buf.into_inner()).expect("write fixture");
}

/// A MicaSense-style XMP packet (element form, `MicaSense:` and `Camera:` namespaces).
pub struct MsXmp<'a> {
    pub band: &'a str,
    pub center: f64,
    pub fwhm: f64,
    pub capture: &'a str,
    pub a: [f64; 3],
    pub vignetting_center: [f64; 2],
    pub vignetting_poly: [f64; 6],
    pub focal_px: f64,
    pub principal_mm: [f64; 2],
    pub distortion: [f64; 5],
    pub horizontal_irradiance: Option<f64>,
    /// `Camera:RigRelatives` (degrees) and `Camera:RigTranslations` (metres), as newer firmware writes them.
    pub rig: Option<([f64; 3], [f64; 3])>,
}

pub fn micasense_xmp(x: &MsXmp) -> String {
    let seq = |v: &[f64]| v.iter().map(|a| format!("<rdf:li>{a:e}</rdf:li>")).collect::<String>();
    // DLS2 as MicaSense firmware writes it: tag values in units of 0.01 W/(m^2 nm) (Camera:IrradianceScaleToSIUnits),
    // the horizontal irradiance = direct sin(elevation) + scattered, the elevation in radians.
    let irr = x
        .horizontal_irradiance
        .map(|e| {
            let (el, diffuse) = (0.9f64, 0.2);
            let direct = (1.0 - diffuse) * e / el.sin();
            format!(
                "<Camera:IrradianceScaleToSIUnits>0.01</Camera:IrradianceScaleToSIUnits>\
                 <DLS:HorizontalIrradiance xmlns:DLS=\"http://micasense.com/DLS/1.0/\">{h}</DLS:HorizontalIrradiance>\
                 <DLS:DirectIrradiance xmlns:DLS=\"http://micasense.com/DLS/1.0/\">{d}</DLS:DirectIrradiance>\
                 <DLS:ScatteredIrradiance xmlns:DLS=\"http://micasense.com/DLS/1.0/\">{s}</DLS:ScatteredIrradiance>\
                 <DLS:SolarElevation xmlns:DLS=\"http://micasense.com/DLS/1.0/\">{el}</DLS:SolarElevation>",
                h = e / 0.01,
                d = direct / 0.01,
                s = diffuse * e / 0.01,
            )
        })
        .unwrap_or_default();
    let rig = x
        .rig
        .map(|(r, t)| {
            format!(
                "<Camera:RigRelatives>{},{},{}</Camera:RigRelatives><Camera:RigTranslations>{},{},{}</Camera:RigTranslations>",
                r[0], r[1], r[2], t[0], t[1], t[2]
            )
        })
        .unwrap_or_default();
    format!(
        r#"<?xpacket begin="" id="W5M0MpCehiHzreSzNTczkc9d"?><x:xmpmeta xmlns:x="adobe:ns:meta/"><rdf:RDF xmlns:rdf="http://www.w3.org/1999/02/22-rdf-syntax-ns#">
<rdf:Description rdf:about="" xmlns:MicaSense="http://micasense.com/MicaSense/1.0/">
<MicaSense:RadiometricCalibration><rdf:Seq>{a}</rdf:Seq></MicaSense:RadiometricCalibration>
<MicaSense:CaptureId>{cap}</MicaSense:CaptureId>
</rdf:Description>
<rdf:Description rdf:about="" xmlns:Camera="http://pix4d.com/1.0">
<Camera:BandName>{band}</Camera:BandName><Camera:CentralWavelength>{c}</Camera:CentralWavelength><Camera:WavelengthFWHM>{fw}</Camera:WavelengthFWHM>
<Camera:VignettingCenter><rdf:Seq>{vc}</rdf:Seq></Camera:VignettingCenter>
<Camera:VignettingPolynomial><rdf:Seq>{vp}</rdf:Seq></Camera:VignettingPolynomial>
<Camera:ModelType>perspective</Camera:ModelType>
<Camera:PrincipalPoint>{ppx},{ppy}</Camera:PrincipalPoint>
<Camera:PerspectiveFocalLength>{f}</Camera:PerspectiveFocalLength>
<Camera:PerspectiveDistortion><rdf:Seq>{d}</rdf:Seq></Camera:PerspectiveDistortion>
{irr}{rig}
</rdf:Description></rdf:RDF></x:xmpmeta><?xpacket end="w"?>"#,
        a = seq(&x.a),
        cap = x.capture,
        band = x.band,
        c = x.center,
        fw = x.fwhm,
        vc = seq(&x.vignetting_center),
        vp = seq(&x.vignetting_poly),
        ppx = x.principal_mm[0],
        ppy = x.principal_mm[1],
        f = x.focal_px,
        d = seq(&x.distortion),
    )
}

/// A DJI-style XMP packet (attribute form, `drone-dji:` namespace).
pub struct DjiXmp<'a> {
    pub band: &'a str,
    pub freq: &'a str,
    pub capture: &'a str,
    pub exposure_us: f64,
    pub gain: f64,
    pub gain_adjustment: f64,
    pub center: [f64; 2],
    pub vignetting: [f64; 6],
    pub irradiance: f64,
    pub yaw: f64,
}

pub fn dji_xmp(x: &DjiXmp) -> String {
    let v = x.vignetting.iter().map(|k| format!("{k:e}")).collect::<Vec<_>>().join(", ");
    format!(
        r#"<x:xmpmeta xmlns:x="adobe:ns:meta/"><rdf:RDF xmlns:rdf="http://www.w3.org/1999/02/22-rdf-syntax-ns#">
<rdf:Description rdf:about="DJI Meta Data" xmlns:drone-dji="http://www.dji.com/drone-dji/1.0/" xmlns:Camera="http://pix4d.com/camera/1.0/"
 Camera:BandName="{band}" drone-dji:BandFreq="{freq}" drone-dji:CaptureUUID="{cap}" drone-dji:ExposureTime="{t}"
 drone-dji:SensorGain="{g}" drone-dji:SensorGainAdjustment="{sga}" drone-dji:CalibratedOpticalCenterX="{cx}"
 drone-dji:CalibratedOpticalCenterY="{cy}" drone-dji:VignettingData="{v}" drone-dji:Irradiance="{irr}"
 drone-dji:GimbalYawDegree="{yaw}"/>
</rdf:RDF></x:xmpmeta>"#,
        band = x.band,
        freq = x.freq,
        cap = x.capture,
        t = x.exposure_us,
        g = x.gain,
        sga = x.gain_adjustment,
        cx = x.center[0],
        cy = x.center[1],
        irr = x.irradiance,
        yaw = x.yaw,
    )
}
