//! `Plane`: a single-band f32 image (row-major, pixel centres at integer coordinates, as OpenCV and
//! MicaSense index them) with the few operations the importer needs: bilinear and bicubic sampling, 2x box
//! downsampling, central-difference gradients.
//!
//! Bicubic is Keys' convolution kernel with a = -0.5 (Keys 1981; GDAL's `cubic`), exact on quadratics: the images a
//! dataset keeps are resampled with it, as photogrammetry undistorts, since bilinear interpolation low-passes by an
//! amount that changes with the sub-pixel phase, so one ground point looks sharper in one view than in the next.

#[derive(Debug, Clone, PartialEq)]
pub struct Plane {
    pub width: usize,
    pub height: usize,
    pub data: Vec<f32>,
}

impl Plane {
    pub fn new(width: usize, height: usize, data: Vec<f32>) -> Plane {
        assert_eq!(data.len(), width * height, "plane size");
        Plane { width, height, data }
    }

    pub fn filled(width: usize, height: usize, v: f32) -> Plane {
        Plane { width, height, data: vec![v; width * height] }
    }

    #[inline]
    pub fn at(&self, x: usize, y: usize) -> f32 {
        self.data[y * self.width + x]
    }

    /// Bilinear sample at (x, y) in pixel-centre coordinates; `None` outside `[0, w-1] x [0, h-1]` or next to NaN.
    #[inline]
    pub fn sample(&self, x: f64, y: f64) -> Option<f32> {
        if !(x >= 0.0 && y >= 0.0 && x <= (self.width - 1) as f64 && y <= (self.height - 1) as f64) {
            return None;
        }
        let x0 = (x.floor() as usize).min(self.width.saturating_sub(2));
        let y0 = (y.floor() as usize).min(self.height.saturating_sub(2));
        let (fx, fy) = ((x - x0 as f64) as f32, (y - y0 as f64) as f32);
        let i = y0 * self.width + x0;
        let (a, b) = (self.data[i], self.data[i + 1]);
        let (c, d) = (self.data[i + self.width], self.data[i + self.width + 1]);
        let v = (a * (1.0 - fx) + b * fx) * (1.0 - fy) + (c * (1.0 - fx) + d * fx) * fy;
        v.is_finite().then_some(v)
    }

    /// Bicubic sample (Keys, a = -0.5) at (x, y); bilinear within a pixel of the border or next to NaN; `None`
    /// outside `[0, w-1] x [0, h-1]`.
    pub fn sample_cubic(&self, x: f64, y: f64) -> Option<f32> {
        if !(x >= 1.0 && y >= 1.0 && x < (self.width as f64 - 2.0) && y < (self.height as f64 - 2.0)) {
            return self.sample(x, y);
        }
        let (x0, y0) = (x.floor() as usize, y.floor() as usize);
        let (wx, wy) = (keys_weights(x - x0 as f64), keys_weights(y - y0 as f64));
        let mut v = 0.0f64;
        for (j, wyj) in wy.iter().enumerate() {
            let row = (y0 + j - 1) * self.width;
            let mut r = 0.0f64;
            for (i, wxi) in wx.iter().enumerate() {
                r += *wxi * self.data[row + x0 + i - 1] as f64;
            }
            v += wyj * r;
        }
        if v.is_finite() {
            Some(v as f32)
        } else {
            self.sample(x, y)
        }
    }

    /// Half resolution by 2x2 box averaging (odd edges dropped).
    pub fn downsample(&self) -> Plane {
        let (w, h) = (self.width / 2, self.height / 2);
        let mut out = Vec::with_capacity(w * h);
        for y in 0..h {
            for x in 0..w {
                let s = self.at(2 * x, 2 * y)
                    + self.at(2 * x + 1, 2 * y)
                    + self.at(2 * x, 2 * y + 1)
                    + self.at(2 * x + 1, 2 * y + 1);
                out.push(0.25 * s);
            }
        }
        Plane::new(w, h, out)
    }

    /// Central-difference gradients (one-sided at the border): (d/dx, d/dy).
    pub fn gradients(&self) -> (Plane, Plane) {
        let (w, h) = (self.width, self.height);
        let mut gx = vec![0.0f32; w * h];
        let mut gy = vec![0.0f32; w * h];
        for y in 0..h {
            for x in 0..w {
                let (xl, xr) = (x.saturating_sub(1), (x + 1).min(w - 1));
                let (yu, yd) = (y.saturating_sub(1), (y + 1).min(h - 1));
                gx[y * w + x] = (self.at(xr, y) - self.at(xl, y)) / (xr - xl).max(1) as f32;
                gy[y * w + x] = (self.at(x, yd) - self.at(x, yu)) / (yd - yu).max(1) as f32;
            }
        }
        (Plane::new(w, h, gx), Plane::new(w, h, gy))
    }

    /// Gradient magnitude (the registration works on it: edges agree across bands where intensities do not).
    pub fn gradient_magnitude(&self) -> Plane {
        let (gx, gy) = self.gradients();
        let data = gx.data.iter().zip(&gy.data).map(|(a, b)| (a * a + b * b).sqrt()).collect();
        Plane::new(self.width, self.height, data)
    }

    /// 3x3 binomial blur ([1 2 1]/4 each way), clamped at the border.
    pub fn blur(&self) -> Plane {
        let (w, h) = (self.width, self.height);
        let mut tmp = vec![0.0f32; w * h];
        for y in 0..h {
            for x in 0..w {
                let (xl, xr) = (x.saturating_sub(1), (x + 1).min(w - 1));
                tmp[y * w + x] = 0.25 * self.at(xl, y) + 0.5 * self.at(x, y) + 0.25 * self.at(xr, y);
            }
        }
        let mut out = vec![0.0f32; w * h];
        for y in 0..h {
            let (yu, yd) = (y.saturating_sub(1), (y + 1).min(h - 1));
            for x in 0..w {
                out[y * w + x] = 0.25 * tmp[yu * w + x] + 0.5 * tmp[y * w + x] + 0.25 * tmp[yd * w + x];
            }
        }
        Plane::new(w, h, out)
    }
}

/// Keys' cubic convolution weights (a = -0.5) of the four samples at offsets -1, 0, 1, 2 from a point `t` in [0, 1)
/// past the second.
#[inline]
fn keys_weights(t: f64) -> [f64; 4] {
    const A: f64 = -0.5;
    let near = |d: f64| (A + 2.0) * d * d * d - (A + 3.0) * d * d + 1.0;
    let far = |d: f64| A * d * d * d - 5.0 * A * d * d + 8.0 * A * d - 4.0 * A;
    [far(1.0 + t), near(t), near(1.0 - t), far(2.0 - t)]
}
