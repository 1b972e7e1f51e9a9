//! The files of a raw flight as the cameras write them: one single-band 16-bit TIFF per band and capture, its
//! EXIF (IFD0, the Exif IFD, the GPS IFD; DNG's BlackLevel) and its XMP packet (tag 700), written with
//! kamadak-exif's TIFF writer (a well-kept EXIF crate, independent of the importer's reader).
//!
//! MicaSense (the real RedEdge and Altum files are the template; docs/radiometry.md lists the tags): element-form
//! XMP in three `rdf:Description` blocks, `MicaSense:` (RadiometricCalibration, CaptureId, FlightId, DarkRowValue,
//! ...), `Camera:` (Pix4D: band identity, vignetting, lens, rig, attitude) and `DLS:` (the light sensor: spectral,
//! horizontal, direct and scattered irradiance in tag units, the sun's elevation and azimuth in radians, the
//! sensor's yaw, pitch and roll in radians). Irradiance tags hold SI units divided by
//! `Camera:IrradianceScaleToSIUnits` (0.01 on DLS2; MicaSense's library assumes 0.01 when a DLS2 file omits it).
//!
//! DJI P4 Multispectral: attribute-form XMP with `drone-dji:` (exposure in microseconds, sensor gain and its
//! adjustment, vignetting, dewarp data, relative optical centres, the sun sensor's `Irradiance`, capture UUID,
//! gimbal and flight attitude) and the Pix4D `Camera:` band identity.

use std::path::Path;

use exif::{Context, Field, In, Rational, Tag, Value};

use super::profile::{BandCamera, SensorProfile, Vendor};

/// A GPS fix as written (WGS 84 degrees, metres).
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct GpsTag {
    pub latitude: f64,
    pub longitude: f64,
    pub altitude: f64,
}

/// What the light sensor wrote for one band of one capture, in SI units (W / (m^2 nm); angles in radians).
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct DlsReading {
    pub horizontal: f64,
    pub direct: f64,
    pub scattered: f64,
    /// Irradiance on the (tilted) sensor.
    pub spectral: f64,
    pub solar_elevation: f64,
    pub solar_azimuth: f64,
    /// The sensor body's yaw, pitch, roll (radians, NED).
    pub ypr: [f64; 3],
    /// The horizontal-irradiance tag value when the firmware computes it wrongly (old RedEdge/Altum firmware),
    /// in SI units; `None` writes the right one.
    pub firmware_horizontal: Option<f64>,
}

/// One band file's facts.
#[derive(Debug, Clone)]
pub struct Shot<'a> {
    pub profile: &'a SensorProfile,
    /// `None` for the thermal band.
    pub band: Option<&'a BandCamera>,
    pub width: u32,
    pub height: u32,
    pub capture_id: String,
    pub flight_id: String,
    /// `YYYY:MM:DD HH:MM:SS` (UTC, as MicaSense writes it) and the sub-second digits.
    pub datetime: String,
    pub subsec: String,
    pub gps: Option<GpsTag>,
    /// Aircraft yaw, pitch, roll (degrees; yaw clockwise from north).
    pub attitude_deg: [f64; 3],
    pub exposure_s: f64,
    pub iso: u32,
    /// Mean of the masked (dark) rows, per quadrant, in container DN.
    pub dark_rows: [f64; 4],
    pub dls: Option<DlsReading>,
    /// Milliseconds since boot (MicaSense BootTimestamp, DLS TimeStamp).
    pub boot_ms: u64,
}

fn rational(v: f64, den: u32) -> Rational {
    Rational { num: (v * den as f64).round().max(0.0) as u32, denom: den }
}

fn dms(v: f64) -> Vec<Rational> {
    let v = v.abs();
    let d = v.floor();
    let m = ((v - d) * 60.0).floor();
    let s = ((v - d) * 60.0 - m) * 60.0;
    vec![Rational { num: d as u32, denom: 1 }, Rational { num: m as u32, denom: 1 }, rational(s, 100_000)]
}

fn seq(v: &[f64]) -> String {
    v.iter().map(|x| format!("<rdf:li>{x:e}</rdf:li>")).collect()
}

/// `(value, den)`: the exposure as EXIF writes it, a rational with a 10^7 denominator.
pub const EXPOSURE_DEN: u32 = 10_000_000;

/// The exposure time the file will carry (what the importer reads back).
pub fn written_exposure(t: f64) -> f64 {
    (t * EXPOSURE_DEN as f64).round() / EXPOSURE_DEN as f64
}

fn micasense_xmp(s: &Shot) -> String {
    let p = s.profile;
    let scale = p.irradiance_scale_tag.unwrap_or(0.01);
    let (band_name, center, fwhm, idx) = match s.band {
        Some(b) => (b.name.to_string(), b.center_nm, b.fwhm_nm, b.suffix - 1),
        None => ("LWIR".to_string(), 11000.0, 6000.0, p.thermal.map_or(5, |t| t.suffix - 1)),
    };
    let ms = format!(
        "<MicaSense:BootTimestamp>{boot}</MicaSense:BootTimestamp>\n\
         <MicaSense:RadiometricCalibration><rdf:Seq>{a}</rdf:Seq></MicaSense:RadiometricCalibration>\n\
         <MicaSense:FlightId>{flight}</MicaSense:FlightId>\n<MicaSense:CaptureId>{cap}</MicaSense:CaptureId>\n\
         <MicaSense:TriggerMethod>2</MicaSense:TriggerMethod>\n<MicaSense:PressureAlt>{alt:.3}</MicaSense:PressureAlt>\n\
         <MicaSense:DarkRowValue><rdf:Seq>{dark}</rdf:Seq></MicaSense:DarkRowValue>\n\
         <MicaSense:ImagerTemperatureC>31.5</MicaSense:ImagerTemperatureC>\n",
        boot = s.boot_ms / 1000,
        a = seq(&s.band.map_or([0.0; 3], |b| b.radiometric)),
        flight = s.flight_id,
        cap = s.capture_id,
        alt = s.gps.map_or(0.0, |g| g.altitude),
        dark = s.dark_rows.iter().map(|d| format!("<rdf:li>{}</rdf:li>", d.round())).collect::<String>(),
    );
    let mut cam = format!(
        "<Camera:BandName>{band_name}</Camera:BandName>\n<Camera:CentralWavelength>{center}</Camera:CentralWavelength>\n\
         <Camera:WavelengthFWHM>{fwhm}</Camera:WavelengthFWHM>\n<Camera:RigCameraIndex>{idx}</Camera:RigCameraIndex>\n\
         <Camera:RigName>{rig}</Camera:RigName>\n<Camera:ModelType>perspective</Camera:ModelType>\n\
         <Camera:Yaw>{yaw}</Camera:Yaw>\n<Camera:Pitch>{pitch}</Camera:Pitch>\n<Camera:Roll>{roll}</Camera:Roll>\n\
         <Camera:GPSXYAccuracy>1.2</Camera:GPSXYAccuracy>\n<Camera:GPSZAccuracy>1.8</Camera:GPSZAccuracy>\n",
        rig = p.model,
        yaw = s.attitude_deg[0],
        pitch = s.attitude_deg[1],
        roll = s.attitude_deg[2],
    );
    if let Some(b) = s.band {
        let l = &b.lens;
        let r = p.focal_plane_px_per_mm;
        cam += &format!(
            "<Camera:VignettingCenter><rdf:Seq>{vc}</rdf:Seq></Camera:VignettingCenter>\n\
             <Camera:VignettingPolynomial><rdf:Seq>{vp}</rdf:Seq></Camera:VignettingPolynomial>\n\
             <Camera:PrincipalPoint>{ppx},{ppy}</Camera:PrincipalPoint>\n\
             <Camera:PerspectiveFocalLength>{f}</Camera:PerspectiveFocalLength>\n\
             <Camera:PerspectiveFocalLengthUnits>mm</Camera:PerspectiveFocalLengthUnits>\n\
             <Camera:PerspectiveDistortion><rdf:Seq>{d}</rdf:Seq></Camera:PerspectiveDistortion>\n\
             <Camera:BandSensitivity>{sens}</Camera:BandSensitivity>\n\
             <Camera:RigRelatives>{rr0}, {rr1}, {rr2}</Camera:RigRelatives>\n\
             <Camera:RigTranslations>{rt0}, {rt1}, {rt2}</Camera:RigTranslations>\n\
             <Camera:RigRelativesReferenceRigCameraIndex>{refi}</Camera:RigRelativesReferenceRigCameraIndex>\n",
            vc = seq(&b.vignetting_center),
            vp = seq(&b.vignetting_poly),
            ppx = l.cx / r,
            ppy = l.cy / r,
            f = l.fx / r,
            d = seq(&[l.k1, l.k2, l.k3, l.p1, l.p2]),
            sens = 0.01 / b.radiometric[0],
            rr0 = b.rig_rotation_deg[0],
            rr1 = b.rig_rotation_deg[1],
            rr2 = b.rig_rotation_deg[2],
            rt0 = b.rig_translation_m[0],
            rt1 = b.rig_translation_m[1],
            rt2 = b.rig_translation_m[2],
            refi = p.reference,
        );
    }
    let mut dls = format!(
        "<DLS:Serial>DL05-2001234-SC</DLS:Serial>\n<DLS:SwVersion>v1.2.4</DLS:SwVersion>\n\
         <DLS:SensorId>{idx}</DLS:SensorId>\n<DLS:TimeStamp>{ts}</DLS:TimeStamp>\n",
        ts = s.boot_ms,
    );
    if let (Some(d), Some(b)) = (&s.dls, s.band) {
        if let Some(k) = p.irradiance_scale_tag {
            cam += &format!("<Camera:IrradianceScaleToSIUnits>{k}</Camera:IrradianceScaleToSIUnits>\n");
        }
        let deg = f64::to_degrees;
        cam += &format!(
            "<Camera:Irradiance>{e}</Camera:Irradiance>\n<Camera:IrradianceExposureTime>0.0100</Camera:IrradianceExposureTime>\n\
             <Camera:IrradianceGain>16</Camera:IrradianceGain>\n<Camera:IrradianceYaw>{y}</Camera:IrradianceYaw>\n\
             <Camera:IrradiancePitch>{pi}</Camera:IrradiancePitch>\n<Camera:IrradianceRoll>{ro}</Camera:IrradianceRoll>\n",
            e = d.spectral / scale,
            y = deg(d.ypr[0]),
            pi = deg(d.ypr[1]),
            ro = deg(d.ypr[2]),
        );
        let dir = [
            d.solar_elevation.cos() * d.solar_azimuth.cos(),
            d.solar_elevation.cos() * d.solar_azimuth.sin(),
            -d.solar_elevation.sin(),
        ];
        dls += &format!(
            "<DLS:CenterWavelength>{c}</DLS:CenterWavelength>\n<DLS:Bandwidth>{w}</DLS:Bandwidth>\n\
             <DLS:Exposure>0.0100</DLS:Exposure>\n<DLS:Gain>16</DLS:Gain>\n\
             <DLS:SpectralIrradiance>{spec}</DLS:SpectralIrradiance>\n\
             <DLS:HorizontalIrradiance>{hor}</DLS:HorizontalIrradiance>\n\
             <DLS:DirectIrradiance>{dirr}</DLS:DirectIrradiance>\n\
             <DLS:ScatteredIrradiance>{sca}</DLS:ScatteredIrradiance>\n\
             <DLS:SolarElevation>{el}</DLS:SolarElevation>\n<DLS:SolarAzimuth>{az}</DLS:SolarAzimuth>\n\
             <DLS:EstimatedDirectLightVector><rdf:Seq>{v}</rdf:Seq></DLS:EstimatedDirectLightVector>\n\
             <DLS:Yaw>{y}</DLS:Yaw>\n<DLS:Pitch>{pi}</DLS:Pitch>\n<DLS:Roll>{ro}</DLS:Roll>\n",
            c = b.center_nm,
            w = b.fwhm_nm,
            spec = d.spectral / scale,
            hor = d.firmware_horizontal.unwrap_or(d.horizontal) / scale,
            dirr = d.direct / scale,
            sca = d.scattered / scale,
            el = d.solar_elevation,
            az = d.solar_azimuth,
            v = seq(&dir),
            y = d.ypr[0],
            pi = d.ypr[1],
            ro = d.ypr[2],
        );
    }
    format!(
        "<?xpacket begin=\"\u{feff}\" id=\"W5M0MpCehiHzreSzNTczkc9d\"?>\n\
         <x:xmpmeta xmlns:x=\"adobe:ns:meta/\" x:xmptk=\"XMP Core 4.4.0\">\n\
         <rdf:RDF xmlns:rdf=\"http://www.w3.org/1999/02/22-rdf-syntax-ns#\">\n\
         <rdf:Description rdf:about=\"Pix4D Camera Information\" xmlns:MicaSense=\"http://micasense.com/MicaSense/1.0/\">\n{ms}</rdf:Description>\n\
         <rdf:Description rdf:about=\"Pix4D Camera Information\" xmlns:Camera=\"http://pix4d.com/1.0\">\n{cam}</rdf:Description>\n\
         <rdf:Description rdf:about=\"Pix4D Camera Information\" xmlns:DLS=\"http://micasense.com/DLS/1.0/\">\n{dls}</rdf:Description>\n\
         </rdf:RDF>\n</x:xmpmeta>\n<?xpacket end=\"w\"?>"
    )
}

/// DJI's `DewarpData`: "date;fx,fy,cx,cy,k1,k2,p1,p2,k3", cx and cy relative to the calibrated optical centre.
fn dewarp(b: &BandCamera, center: [f64; 2]) -> String {
    let l = &b.lens;
    format!(
        "2019-06-14;{},{},{},{},{},{},{},{},{}",
        l.fx,
        l.fy,
        l.cx - center[0],
        l.cy - center[1],
        l.k1,
        l.k2,
        l.p1,
        l.p2,
        l.k3
    )
}

fn dji_xmp(s: &Shot, relative_center: [f64; 2]) -> String {
    let p = s.profile;
    let b = s.band.expect("DJI rigs have no thermal band");
    let center = b.vignetting_center;
    let v = b.vignetting_poly.iter().map(|k| format!("{k:e}")).collect::<Vec<_>>().join(", ");
    let irr = s.dls.map_or(0.0, |d| d.horizontal * p.dji_irradiance_units);
    let g = s.gps.unwrap_or(GpsTag { latitude: 0.0, longitude: 0.0, altitude: 0.0 });
    format!(
        "<x:xmpmeta xmlns:x=\"adobe:ns:meta/\"><rdf:RDF xmlns:rdf=\"http://www.w3.org/1999/02/22-rdf-syntax-ns#\">\n\
         <rdf:Description rdf:about=\"DJI Meta Data\" xmlns:tiff=\"http://ns.adobe.com/tiff/1.0/\" \
         xmlns:drone-dji=\"http://www.dji.com/drone-dji/1.0/\" xmlns:Camera=\"http://pix4d.com/camera/1.0/\"\n \
         tiff:Make=\"DJI\" tiff:Model=\"{model}\" Camera:BandName=\"{band}\" Camera:CentralWavelength=\"{c}\" \
         Camera:WavelengthFWHM=\"{fw}\" Camera:ModelType=\"perspective\"\n \
         drone-dji:BandFreq=\"{c:.0}(+/-{half:.0})nm\" drone-dji:CaptureUUID=\"{cap}\" drone-dji:ExposureTime=\"{t}\" \
         drone-dji:SensorGain=\"{gain}\" drone-dji:SensorGainAdjustment=\"{sga}\" drone-dji:SensorIndex=\"{idx}\"\n \
         drone-dji:CalibratedOpticalCenterX=\"{cx}\" drone-dji:CalibratedOpticalCenterY=\"{cy}\" \
         drone-dji:VignettingData=\"{v}\" drone-dji:DewarpData=\"{dw}\"\n \
         drone-dji:RelativeOpticalCenterX=\"{rx}\" drone-dji:RelativeOpticalCenterY=\"{ry}\" drone-dji:Irradiance=\"{irr}\"\n \
         drone-dji:GimbalYawDegree=\"{yaw}\" drone-dji:GimbalPitchDegree=\"-90.0\" drone-dji:GimbalRollDegree=\"0.0\" \
         drone-dji:FlightYawDegree=\"{yaw}\" drone-dji:FlightPitchDegree=\"{pitch}\" drone-dji:FlightRollDegree=\"{roll}\"\n \
         drone-dji:AbsoluteAltitude=\"{alt}\" drone-dji:Latitude=\"{lat}\" drone-dji:Longitude=\"{lon}\"/>\n\
         </rdf:RDF></x:xmpmeta>",
        model = p.model,
        band = b.name,
        c = b.center_nm,
        fw = b.fwhm_nm,
        half = b.fwhm_nm / 2.0,
        cap = s.capture_id,
        t = s.exposure_s * 1e6,
        gain = s.iso as f64 / 100.0,
        sga = b.gain_adjustment,
        idx = b.suffix,
        cx = center[0],
        cy = center[1],
        dw = dewarp(b, center),
        rx = relative_center[0],
        ry = relative_center[1],
        yaw = s.attitude_deg[0],
        pitch = s.attitude_deg[1],
        roll = s.attitude_deg[2],
        alt = g.altitude,
        lat = g.latitude,
        lon = g.longitude,
    )
}

/// Writes one band file. `relative_center`: DJI's `RelativeOpticalCenterX/Y` of the band (ignored otherwise).
pub fn write_band_file(path: &Path, s: &Shot, pixels: &[u16], relative_center: [f64; 2]) -> std::io::Result<()> {
    let p = s.profile;
    let xmp = match p.vendor {
        Vendor::MicaSense => micasense_xmp(s),
        Vendor::Dji => dji_xmp(s, relative_center),
    };
    let f = |tag: Tag, value: Value| Field { tag, ifd_num: In::PRIMARY, value };
    let ascii = |t: &str| Value::Ascii(vec![t.as_bytes().to_vec()]);
    let bl = p.black_level.round() as u16;
    let focal_mm = s.band.map_or(1.77, |b| b.lens.fx / p.focal_plane_px_per_mm);
    let mut fields = vec![
        f(Tag(Context::Tiff, 254), Value::Long(vec![0])),
        f(Tag::ImageWidth, Value::Long(vec![s.width])),
        f(Tag::ImageLength, Value::Long(vec![s.height])),
        f(Tag::BitsPerSample, Value::Short(vec![16])),
        f(Tag::Compression, Value::Short(vec![1])),
        f(Tag::PhotometricInterpretation, Value::Short(vec![1])),
        f(Tag::Orientation, Value::Short(vec![1])),
        f(Tag::SamplesPerPixel, Value::Short(vec![1])),
        f(Tag::RowsPerStrip, Value::Long(vec![s.height])),
        f(Tag::PlanarConfiguration, Value::Short(vec![1])),
        f(Tag::Make, ascii(p.make)),
        f(Tag::Model, ascii(p.model)),
        f(Tag::Software, ascii(&p.firmware)),
        f(Tag::DateTime, ascii(&s.datetime)),
        f(Tag(Context::Tiff, 700), Value::Byte(xmp.into_bytes())),
        f(Tag(Context::Tiff, 50713), Value::Short(vec![2, 2])),
        f(Tag(Context::Tiff, 50714), Value::Short(vec![bl; 4])),
        f(Tag::ExposureTime, Value::Rational(vec![rational(s.exposure_s, EXPOSURE_DEN)])),
        f(Tag::FNumber, Value::Rational(vec![rational(p.f_number, 100)])),
        f(Tag::ExposureProgram, Value::Short(vec![2])),
        f(Tag::ISOSpeed, Value::Long(vec![s.iso])),
        f(Tag::ExifVersion, Value::Undefined(b"0230".to_vec(), 0)),
        f(Tag::DateTimeOriginal, ascii(&s.datetime)),
        f(Tag::DateTimeDigitized, ascii(&s.datetime)),
        f(Tag::SubSecTime, ascii(&s.subsec)),
        f(Tag::SubSecTimeOriginal, ascii(&s.subsec)),
        f(Tag::MeteringMode, Value::Short(vec![1])),
        f(Tag::FocalLength, Value::Rational(vec![rational(focal_mm, 1000)])),
        f(Tag::FocalPlaneXResolution, Value::Rational(vec![rational(p.focal_plane_px_per_mm, 1_000_000)])),
        f(Tag::FocalPlaneYResolution, Value::Rational(vec![rational(p.focal_plane_px_per_mm, 1_000_000)])),
        f(Tag::FocalPlaneResolutionUnit, Value::Short(vec![4])),
        f(Tag::BodySerialNumber, ascii("SIM0-0000001-SC")),
    ];
    if let Some(g) = s.gps {
        fields.push(f(Tag::GPSVersionID, Value::Byte(vec![2, 2, 0, 0])));
        fields.push(f(Tag::GPSLatitudeRef, ascii(if g.latitude < 0.0 { "S" } else { "N" })));
        fields.push(f(Tag::GPSLatitude, Value::Rational(dms(g.latitude))));
        fields.push(f(Tag::GPSLongitudeRef, ascii(if g.longitude < 0.0 { "W" } else { "E" })));
        fields.push(f(Tag::GPSLongitude, Value::Rational(dms(g.longitude))));
        fields.push(f(Tag::GPSAltitudeRef, Value::Byte(vec![u8::from(g.altitude < 0.0)])));
        fields.push(f(Tag::GPSAltitude, Value::Rational(vec![rational(g.altitude.abs(), 1000)])));
        fields.push(f(Tag::GPSDOP, Value::Rational(vec![rational(0.9, 10)])));
    }
    let bytes: Vec<u8> = pixels.iter().flat_map(|v| v.to_le_bytes()).collect();
    let strips: [&[u8]; 1] = [&bytes];
    let mut wr = exif::experimental::Writer::new();
    for fl in &fields {
        wr.push_field(fl);
    }
    wr.set_strips(&strips, In::PRIMARY);
    let mut buf = std::io::Cursor::new(Vec::with_capacity(bytes.len() + 8192));
    wr.write(&mut buf, true).map_err(|e| std::io::Error::other(format!("writing TIFF tags: {e}")))?;
    std::fs::write(path, buf.into_inner())
}
