//! The tool-independent form every pose reader produces: images with camera-to-world in OpenGL axes (msnerf's
//! `transform_matrix`), their cameras as msnerf's per-frame keys, and sparse points with their tracks.

/// A camera as msnerf's per-frame keys: `camera_model` and the numbers (`fl_x`, `fl_y`, `cx`, `cy`, distortion).
#[derive(Debug, Clone, PartialEq)]
pub struct PoseCamera {
    pub width: u64,
    pub height: u64,
    pub model: &'static str,
    pub keys: Vec<(&'static str, f64)>,
}

impl PoseCamera {
    /// This camera on the same images scaled to `w` x `h`: the focal lengths and principal point scale (pixel units,
    /// the image's corner at 0), the distortion (normalised coordinates) does not. The factor is an integer or its
    /// inverse when sizes round to one (an image downscaled by 3 with the remainder cropped, as nerfstudio and ODM
    /// write them), else the width ratio; None when the height does not follow the same factor within a pixel.
    pub fn scaled_to(&self, w: u64, h: u64) -> Option<PoseCamera> {
        if w == 0 || h == 0 || self.width == 0 || self.height == 0 {
            return None;
        }
        let ratio = w as f64 / self.width as f64;
        let whole =
            |r: f64| (r.round() >= 1.0 && (r - r.round()).abs() * w.min(self.width) as f64 <= 1.0).then(|| r.round());
        let s = match (whole(ratio), whole(1.0 / ratio)) {
            (Some(k), _) => k,
            (None, Some(k)) => 1.0 / k,
            _ => ratio,
        };
        let fits = |full: u64, small: u64| ((full as f64 * s) - small as f64).abs() < 1.0;
        if !fits(self.width, w) || !fits(self.height, h) {
            return None;
        }
        let keys = self
            .keys
            .iter()
            .map(|&(k, v)| (k, if matches!(k, "fl_x" | "fl_y" | "cx" | "cy") { v * s } else { v }))
            .collect();
        Some(PoseCamera { width: w, height: h, model: self.model, keys })
    }
}

/// One posed image.
#[derive(Debug, Clone, PartialEq)]
pub struct PosedImage {
    /// The tool's id (points' tracks refer to it).
    pub id: u64,
    pub name: String,
    pub c2w: [[f64; 4]; 4],
    pub camera: PoseCamera,
}

/// One sparse point.
#[derive(Debug, Clone, PartialEq)]
pub struct PosePoint {
    pub xyz: [f64; 3],
    pub rgb: [u8; 3],
    pub error: Option<f64>,
    /// Ids of the images that observed it.
    pub images: Vec<u64>,
}

/// A whole reconstruction.
#[derive(Debug, Clone, Default)]
pub struct PoseModel {
    pub tool: &'static str,
    pub images: Vec<PosedImage>,
    pub points: Vec<PosePoint>,
    /// The projected CRS the poses are in, when the model is georeferenced (ODM's coords.txt, Metashape's chunk
    /// reference, `msnerf sfm` with GPS).
    pub crs: Option<crate::geo::Crs>,
    /// What the reader decided that the user should know (e.g. a reference without a chunk transform).
    pub notes: Vec<String>,
}

/// Camera-to-world in OpenGL axes from a world-to-camera rotation (row-major) and translation in OpenCV axes
/// (x right, y down, z forward; COLMAP, OpenSfM): `R_c2w = R^T`, centre `-R^T t`, camera y and z negated.
pub fn c2w_from_w2c_opencv(r: [[f64; 3]; 3], t: [f64; 3]) -> [[f64; 4]; 4] {
    let mut m = [[0.0; 4]; 4];
    for i in 0..3 {
        for j in 0..3 {
            m[i][j] = if j == 0 { r[j][i] } else { -r[j][i] };
        }
        m[i][3] = -(r[0][i] * t[0] + r[1][i] * t[1] + r[2][i] * t[2]);
    }
    m[3][3] = 1.0;
    m
}
