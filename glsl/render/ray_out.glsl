// Per-ray output columns of composite.comp (`ray_out`, float[R][RAY_OUT_FIXED + B]): these fixed columns, then the
// B colours C_0..C_{B-1}. The Rust side reads them through `nerf::buffers::RayOut`; a unit test there compares the
// two lists, names and values.
#ifndef RAY_OUT_GLSL
#define RAY_OUT_GLSL
const uint RO_LOSS_RGB = 0u;        // band-weighted colour loss, times rgb_norm and the ray weight
const uint RO_LOSS_DISTORTION = 1u; // distortion loss, times dist_norm and the ray weight
const uint RO_ACCUMULATION = 2u;    // A = sum of the weights
const uint RO_MEDIAN_DEPTH = 3u;    // exact crossing of A = 0.5
const uint RO_EXPECTED_DEPTH = 4u;  // sum w t / A
const uint RO_SQUARED_ERROR = 5u;   // unweighted squared error summed over bands, times the ray weight
const uint RO_DEPTH_Q25 = 6u;       // crossing of 0.25 A
const uint RO_DEPTH_Q75 = 7u;       // crossing of 0.75 A
const uint RO_LOSS_DEPTH = 8u;      // depth loss, times depth_norm and the ray weight
const uint RAY_OUT_FIXED = 9u;      // the colours start here
#endif
