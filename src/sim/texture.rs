//! Albedo texture of a material (opt-in per material, issue 18): real grass, gravel, asphalt, roof membranes and
//! crowns carry texture at every scale, and both photometric geometry and SfM live on it, while a uniform colour
//! leaves the depth of a surface unconstrained by the images. The factor multiplies every band alike:
//! f(p) = max(0, 1 + contrast * n(p)), n = fractal value noise in [-1, 1] of the hit point in the scene's local frame
//! (metres), `octaves` octaves from `scale` metres down, each half the size and half the amplitude of the one
//! before (scene authors: keep the finest octave at or above about one pixel footprint, since the simulator casts one
//! ray per pixel and finer texture aliases into view-dependent noise). Value noise: hashed lattice values with smoothstep trilinear interpolation; the hash is a function of
//! (seed, material, lattice point), so the pattern is deterministic and independent of views and threads.

use serde::Deserialize;

use super::effects::hash4;

/// `texture:` of a material in the scene YAML.
#[derive(Debug, Clone, Copy, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TextureDesc {
    /// Size of the coarsest octave, metres.
    pub scale: f64,
    /// Amplitude: the factor ranges over about 1 +- contrast.
    pub contrast: f64,
    #[serde(default = "default_octaves")]
    pub octaves: u32,
}

fn default_octaves() -> u32 {
    3
}

impl TextureDesc {
    /// Checks the ranges; the message names the key.
    pub fn validate(&self) -> Result<(), (String, String)> {
        if !(self.scale.is_finite() && self.scale > 0.0) {
            return Err(("texture.scale".into(), format!("must be > 0 metres, got {}", self.scale)));
        }
        if !(self.contrast.is_finite() && (0.0..=1.0).contains(&self.contrast)) {
            return Err(("texture.contrast".into(), format!("must be in [0, 1], got {}", self.contrast)));
        }
        if !(1..=8).contains(&self.octaves) {
            return Err(("texture.octaves".into(), format!("must be 1..=8, got {}", self.octaves)));
        }
        Ok(())
    }

    /// The albedo factor at local point `p` for material `material` of a scene with `seed`.
    pub fn factor(&self, seed: u64, material: usize, p: [f64; 3]) -> f64 {
        let (mut sum, mut norm, mut amp, mut size) = (0.0, 0.0, 1.0, self.scale);
        for o in 0..self.octaves {
            sum += amp * value_noise(seed, (material as u64) << 8 | o as u64, p.map(|v| v / size));
            norm += amp;
            amp *= 0.5;
            size *= 0.5;
        }
        (1.0 + self.contrast * sum / norm).max(0.0)
    }
}

/// Smooth value noise in [-1, 1] at lattice coordinates q.
fn value_noise(seed: u64, stream: u64, q: [f64; 3]) -> f64 {
    let i = q.map(|v| v.floor());
    let f = [0, 1, 2].map(|k| {
        let t = q[k] - i[k];
        t * t * (3.0 - 2.0 * t)
    });
    let lattice = |dx: i64, dy: i64, dz: i64| {
        let (x, y, z) = (i[0] as i64 + dx, i[1] as i64 + dy, i[2] as i64 + dz);
        let h = hash4(seed, 0x7e47_0000 ^ stream, x as u64, ((y as u64) << 32) ^ (z as u64 & 0xffff_ffff));
        (h >> 11) as f64 / (1u64 << 53) as f64 * 2.0 - 1.0
    };
    let lerp = |a: f64, b: f64, t: f64| a + (b - a) * t;
    let mut c = [[0.0; 2]; 2];
    for (dy, row) in c.iter_mut().enumerate() {
        for (dz, v) in row.iter_mut().enumerate() {
            *v = lerp(lattice(0, dy as i64, dz as i64), lattice(1, dy as i64, dz as i64), f[0]);
        }
    }
    lerp(lerp(c[0][0], c[0][1], f[2]), lerp(c[1][0], c[1][1], f[2]), f[1])
}
