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
