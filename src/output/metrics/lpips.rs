//! LPIPS (Zhang et al. 2018, "The Unreasonable Effectiveness of Deep Features as a Perceptual Metric", v0.1 with
//! AlexNet), computed on the CPU from a weights file the user supplies (msnerf ships no pretrained network; without
//! one, LPIPS is reported as not computed, never as a number).
//!
//! The network and conventions are those of the `lpips` package that nerfstudio's metric (torchmetrics, normalize =
//! True) wraps: inputs in [0, 1] map to [-1, 1], then (x - shift) / scale per channel (shift -0.030, -0.088, -0.188;
//! scale 0.458, 0.448, 0.450); torchvision's AlexNet features tapped after each of its five ReLUs (conv 11x11 stride 4
//! pad 2 -> 64, max-pool 3/2, conv 5x5 pad 2 -> 192, max-pool 3/2, conv 3x3 pad 1 -> 384, -> 256, -> 256); each tap
//! normalised across channels per pixel (f / (|f| + 1e-10)), squared differences weighted per channel by the
//! non-negative 1x1 "lin" layer, averaged over the pixels, summed over the five taps.
//!
//! The weights file is a safetensors file holding the LPIPS module's own state-dict names (float32):
//! `net.slice1.0.{weight,bias}`, `net.slice2.3.*`, `net.slice3.6.*`, `net.slice4.8.*`, `net.slice5.10.*` and
//! `lin0.model.1.weight` ... `lin4.model.1.weight`. `tools/export_lpips_weights.py` writes it from the package.
//! Convolutions run as im2col plus the `matrixmultiply` sgemm the benchmarks already use.

use std::path::Path;

/// Channel shift and scale of LPIPS's ScalingLayer (inputs in [-1, 1]).
const SHIFT: [f32; 3] = [-0.030, -0.088, -0.188];
const SCALE: [f32; 3] = [0.458, 0.448, 0.450];

/// One convolution: `out` filters of `inp` x k x k, stride and zero padding.
struct Conv {
    name: &'static str,
    out: usize,
    inp: usize,
    k: usize,
    stride: usize,
    pad: usize,
    /// out x (inp k k), row-major as PyTorch stores [out, inp, k, k].
    weight: Vec<f32>,
    bias: Vec<f32>,
}

/// AlexNet's five convolutions as (state-dict prefix, out, in, kernel, stride, padding).
const CONVS: [(&str, usize, usize, usize, usize, usize); 5] = [
    ("net.slice1.0", 64, 3, 11, 4, 2),
    ("net.slice2.3", 192, 64, 5, 1, 2),
    ("net.slice3.6", 384, 192, 3, 1, 1),
    ("net.slice4.8", 256, 384, 3, 1, 1),
    ("net.slice5.10", 256, 256, 3, 1, 1),
];

/// A channels x height x width feature map.
#[derive(Clone, Debug)]
pub struct Features {
    pub c: usize,
    pub h: usize,
    pub w: usize,
    pub data: Vec<f32>,
}

/// The LPIPS network with its weights.
pub struct Lpips {
    convs: Vec<Conv>,
    /// Per tap, one non-negative weight per channel.
    lins: Vec<Vec<f32>>,
}

impl Lpips {
    /// Loads the weights; errors name the file and the tensor.
    pub fn load(path: &Path) -> Result<Self, String> {
        let bytes = std::fs::read(path).map_err(|e| format!("{}: {e}", path.display()))?;
        let st = safetensors::SafeTensors::deserialize(&bytes)
            .map_err(|e| format!("{}: not a safetensors file ({e})", path.display()))?;
        Self::from_tensors(|name| {
            let t = st.tensor(name).map_err(|_| "missing".to_string())?;
            if t.dtype() != safetensors::Dtype::F32 {
                return Err(format!("dtype {:?}, expected F32", t.dtype()));
            }
            let data = t.data().chunks_exact(4).map(|b| f32::from_le_bytes([b[0], b[1], b[2], b[3]])).collect();
            Ok((t.shape().to_vec(), data))
        })
        .map_err(|e| format!("{}: {e}", path.display()))
    }

    /// Builds the network from a tensor lookup (name -> shape and values); errors name the tensor.
    pub fn from_tensors(get: impl Fn(&str) -> Result<(Vec<usize>, Vec<f32>), String>) -> Result<Self, String> {
        let fetch = |name: &str, shape: &[usize]| -> Result<Vec<f32>, String> {
            let (s, v) = get(name).map_err(|e| format!("tensor `{name}`: {e}"))?;
            if s != shape {
                return Err(format!("tensor `{name}`: shape {s:?}, expected {shape:?}"));
            }
            if v.iter().any(|x| !x.is_finite()) {
                return Err(format!("tensor `{name}`: holds a NaN or Inf"));
            }
            Ok(v)
        };
        let mut convs = Vec::new();
        let mut lins = Vec::new();
        for (i, &(name, out, inp, k, stride, pad)) in CONVS.iter().enumerate() {
            let weight = fetch(&format!("{name}.weight"), &[out, inp, k, k])?;
            let bias = fetch(&format!("{name}.bias"), &[out])?;
            convs.push(Conv { name, out, inp, k, stride, pad, weight, bias });
            lins.push(fetch(&format!("lin{i}.model.1.weight"), &[1, out, 1, 1])?);
        }
        Ok(Self { convs, lins })
    }

    /// The five ReLU taps of an RGB image (`rgb`: 3 x h x w planar, values in [0, 1]).
    pub fn features(&self, rgb: &[f32], w: usize, h: usize) -> Result<Vec<Features>, String> {
        if rgb.len() != 3 * w * h {
            return Err(format!("LPIPS input: {} values for 3 x {w} x {h}", rgb.len()));
        }
        if w < 31 || h < 31 {
            return Err(format!("LPIPS input: {w} x {h} pixels is too small for AlexNet (at least 31 x 31)"));
        }
        let data = rgb.iter().enumerate().map(|(i, &v)| (2.0 * v - 1.0 - SHIFT[i / (w * h)]) / SCALE[i / (w * h)]);
        let x = Features { c: 3, h, w, data: data.collect() };
        let mut taps = Vec::with_capacity(5);
        let mut cur = x;
        for (i, conv) in self.convs.iter().enumerate() {
            if i == 1 || i == 2 {
                cur = max_pool(&cur);
            }
            cur = conv_relu(conv, &cur);
            taps.push(cur.clone());
        }
        Ok(taps)
    }

    /// LPIPS distance between two RGB images (3 x h x w planar, [0, 1]).
    pub fn distance(&self, a: &[f32], b: &[f32], w: usize, h: usize) -> Result<f64, String> {
        let (fa, fb) = (self.features(a, w, h)?, self.features(b, w, h)?);
        let mut total = 0.0f64;
        for ((ta, tb), lin) in fa.iter().zip(&fb).zip(&self.lins) {
            let (na, nb) = (normalise(ta), normalise(tb));
            let px = ta.h * ta.w;
            let mut sum = 0.0f64;
            for p in 0..px {
                for (c, &wc) in lin.iter().enumerate() {
                    let d = (na[c * px + p] - nb[c * px + p]) as f64;
                    sum += wc as f64 * d * d;
                }
            }
            total += sum / px as f64;
        }
        Ok(total)
    }
}

/// f / (|f| + 1e-10) across channels, per pixel.
fn normalise(f: &Features) -> Vec<f32> {
    let px = f.h * f.w;
    let mut out = f.data.clone();
    for p in 0..px {
        let n = (0..f.c).map(|c| (f.data[c * px + p] as f64).powi(2)).sum::<f64>().sqrt();
        for c in 0..f.c {
            out[c * px + p] = (f.data[c * px + p] as f64 / (n + 1e-10)) as f32;
        }
    }
    out
}

/// Max-pool 3 x 3, stride 2, no padding (floor), as torchvision's AlexNet.
fn max_pool(x: &Features) -> Features {
    let (oh, ow) = ((x.h - 3) / 2 + 1, (x.w - 3) / 2 + 1);
    let mut data = vec![f32::MIN; x.c * oh * ow];
    for c in 0..x.c {
        for oy in 0..oh {
            for ox in 0..ow {
                let mut m = f32::MIN;
                for dy in 0..3 {
                    for dx in 0..3 {
                        m = m.max(x.data[(c * x.h + 2 * oy + dy) * x.w + 2 * ox + dx]);
                    }
                }
                data[(c * oh + oy) * ow + ox] = m;
            }
        }
    }
    Features { c: x.c, h: oh, w: ow, data }
}

/// ReLU(conv(x) + bias) through im2col and sgemm.
fn conv_relu(conv: &Conv, x: &Features) -> Features {
    debug_assert_eq!(x.c, conv.inp, "{}", conv.name);
    let (k, s, p) = (conv.k, conv.stride, conv.pad);
    let oh = (x.h + 2 * p - k) / s + 1;
    let ow = (x.w + 2 * p - k) / s + 1;
    let rows = conv.inp * k * k;
    let cols = oh * ow;
    let mut col = vec![0.0f32; rows * cols];
    for ci in 0..conv.inp {
        for ky in 0..k {
            for kx in 0..k {
                let r = (ci * k + ky) * k + kx;
                for oy in 0..oh {
                    let iy = (oy * s + ky) as isize - p as isize;
                    if iy < 0 || iy >= x.h as isize {
                        continue;
                    }
                    for ox in 0..ow {
                        let ix = (ox * s + kx) as isize - p as isize;
                        if ix >= 0 && ix < x.w as isize {
                            col[r * cols + oy * ow + ox] = x.data[(ci * x.h + iy as usize) * x.w + ix as usize];
                        }
                    }
                }
            }
        }
    }
    let mut out = vec![0.0f32; conv.out * cols];
    for (o, chunk) in out.chunks_mut(cols).enumerate() {
        chunk.fill(conv.bias[o]);
    }
    // out (out x cols) += weight (out x rows) * col (rows x cols), all row-major.
    // SAFETY: the pointers and strides describe the three buffers above exactly (m = out, k = rows, n = cols).
    unsafe {
        matrixmultiply::sgemm(
            conv.out,
            rows,
            cols,
            1.0,
            conv.weight.as_ptr(),
            rows as isize,
            1,
            col.as_ptr(),
            cols as isize,
            1,
            1.0,
            out.as_mut_ptr(),
            cols as isize,
            1,
        );
    }
    for v in &mut out {
        *v = v.max(0.0);
    }
    Features { c: conv.out, h: oh, w: ow, data: out }
}
