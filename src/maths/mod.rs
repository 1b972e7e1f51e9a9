//! Maths shared by production code and the CPU twins in `crate::reference`: the scene contraction and hash-grid
//! input ([`field`]) and the SO(3) exp map of pose refinement ([`so3`]), generic over f32 and f64, each mirroring one
//! GLSL helper whose kernels the twins check; and, for the CPU only, small dense solves ([`linear`]) and similarity
//! fits ([`similarity`]). Production code (normals, refined camera poses) imports these from here, never from
//! `reference/`.

pub mod field;
pub mod linear;
pub mod similarity;
pub mod so3;

use num_traits::Float;

pub(crate) fn c<T: Float>(v: f64) -> T {
    T::from(v).expect("constant fits")
}

pub(crate) fn dot<T: Float>(a: [T; 3], b: [T; 3]) -> T {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

pub(crate) fn cross<T: Float>(a: [T; 3], b: [T; 3]) -> [T; 3] {
    [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]]
}
