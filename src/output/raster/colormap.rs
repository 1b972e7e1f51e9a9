//! Colour maps for previews: turbo (Google's polynomial fit), viridis and inferno (9-stop piecewise-linear
//! approximations of matplotlib's), RdYlGn (ColorBrewer, 11 stops) for vegetation indices, and grey.

/// A colour map from [0, 1] to sRGB bytes.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Colormap {
    Turbo,
    Viridis,
    Inferno,
    RdYlGn,
    Gray,
}

const VIRIDIS: [[u8; 3]; 9] = [
    [68, 1, 84],
    [71, 44, 122],
    [59, 81, 139],
    [44, 113, 142],
    [33, 144, 141],
    [39, 173, 129],
    [92, 200, 99],
    [170, 220, 50],
    [253, 231, 37],
];
const INFERNO: [[u8; 3]; 9] = [
    [0, 0, 4],
    [31, 12, 72],
    [85, 15, 109],
    [136, 34, 106],
    [186, 54, 85],
    [227, 89, 51],
    [249, 140, 10],
    [249, 201, 50],
    [252, 255, 164],
];
const RDYLGN: [[u8; 3]; 11] = [
    [0xa5, 0x00, 0x26],
    [0xd7, 0x30, 0x27],
    [0xf4, 0x6d, 0x43],
    [0xfd, 0xae, 0x61],
    [0xfe, 0xe0, 0x8b],
    [0xff, 0xff, 0xbf],
    [0xd9, 0xef, 0x8b],
    [0xa6, 0xd9, 0x6a],
    [0x66, 0xbd, 0x63],
    [0x1a, 0x98, 0x50],
    [0x00, 0x68, 0x37],
];

fn lerp_table(t: f64, table: &[[u8; 3]]) -> [u8; 3] {
    let x = t * (table.len() - 1) as f64;
    let i = (x.floor() as usize).min(table.len() - 2);
    let f = x - i as f64;
    let (a, b) = (table[i], table[i + 1]);
    [0, 1, 2].map(|c| (a[c] as f64 + (b[c] as f64 - a[c] as f64) * f).round().clamp(0.0, 255.0) as u8)
}

fn to_byte(v: f64) -> u8 {
    (v.clamp(0.0, 1.0) * 255.0).round() as u8
}

impl Colormap {
    /// Colour of `t` (clamped to [0, 1]; NaN gives black).
    pub fn map(self, t: f64) -> [u8; 3] {
        if t.is_nan() {
            return [0, 0, 0];
        }
        let x = t.clamp(0.0, 1.0);
        match self {
            Colormap::Turbo => {
                let r = 0.13572138
                    + x * (4.6153926 + x * (-42.66032258 + x * (132.13108234 + x * (-152.94239396 + x * 59.28637943))));
                let g = 0.09140261
                    + x * (2.19418839 + x * (4.84296658 + x * (-14.18503333 + x * (4.27729857 + x * 2.82956604))));
                let b = 0.1066733
                    + x * (12.64194608
                        + x * (-60.58204836 + x * (110.36276771 + x * (-89.90310912 + x * 27.34824973))));
                [to_byte(r), to_byte(g), to_byte(b)]
            }
            Colormap::Viridis => lerp_table(x, &VIRIDIS),
            Colormap::Inferno => lerp_table(x, &INFERNO),
            Colormap::RdYlGn => lerp_table(x, &RDYLGN),
            Colormap::Gray => [to_byte(x); 3],
        }
    }

    /// Parses "turbo", "viridis", "inferno", "rdylgn", "gray"/"grey".
    pub fn parse(s: &str) -> Option<Colormap> {
        match s.to_ascii_lowercase().as_str() {
            "turbo" => Some(Colormap::Turbo),
            "viridis" => Some(Colormap::Viridis),
            "inferno" => Some(Colormap::Inferno),
            "rdylgn" => Some(Colormap::RdYlGn),
            "gray" | "grey" => Some(Colormap::Gray),
            _ => None,
        }
    }
}
