//! The "dex" depth-noise model of GIGA/VGN (after Dex-Net): a multiplicative Gamma factor for the
//! whole frame plus, with probability `gp_rate`, Gaussian noise drawn on a grid `gp_scale` times
//! coarser than the image and upsampled bicubically (spatially correlated), added to every valid
//! pixel.
use psgrasp_geometry::depth::is_valid_depth;
use psgrasp_geometry::DepthImage;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, Gamma, Normal};
use serde::{Deserialize, Serialize};

/// Parameters of the dex noise model (defaults are GIGA's).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct NoiseConfig {
    /// Shape of the multiplicative Gamma factor (mean = shape · scale = 1).
    pub gamma_shape: f32,
    /// Scale of the multiplicative Gamma factor.
    pub gamma_scale: f32,
    /// Standard deviation of the correlated additive noise (metres).
    pub gp_sigma: f32,
    /// Downsampling factor of the grid the additive noise is drawn on.
    pub gp_scale: f32,
    /// Probability that the additive noise is applied to a frame.
    pub gp_rate: f32,
}

impl Default for NoiseConfig {
    fn default() -> Self {
        Self {
            gamma_shape: 1000.0,
            gamma_scale: 0.001,
            gp_sigma: 0.005,
            gp_scale: 4.0,
            gp_rate: 0.5,
        }
    }
}

impl NoiseConfig {
    /// True if all parameters are usable.
    pub fn is_valid(&self) -> bool {
        self.gamma_shape.is_finite()
            && self.gamma_shape > 0.0
            && self.gamma_scale.is_finite()
            && self.gamma_scale > 0.0
            && self.gp_sigma.is_finite()
            && self.gp_sigma >= 0.0
            && self.gp_scale.is_finite()
            && self.gp_scale >= 1.0
            && (0.0..=1.0).contains(&self.gp_rate)
    }
}

/// Returns a noisy copy of `depth` (the input is not changed). Invalid pixels stay 0. The same
/// `seed` gives the same noise. An invalid config (see [`NoiseConfig::is_valid`]) returns the
/// input unchanged.
pub fn add_dex_noise(depth: &DepthImage, seed: u64, config: &NoiseConfig) -> DepthImage {
    let mut out = depth.clone();
    if !config.is_valid() || depth.data.len() != depth.width as usize * depth.height as usize {
        return out;
    }
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let factor = Gamma::new(config.gamma_shape, config.gamma_scale)
        .map(|g| g.sample(&mut rng))
        .unwrap_or(1.0);
    let apply_gp = rng.random::<f32>() < config.gp_rate;
    let (w, h) = (depth.width as usize, depth.height as usize);
    let field = if apply_gp && config.gp_sigma > 0.0 {
        let gw = ((w as f32 / config.gp_scale) as usize).max(1);
        let gh = ((h as f32 / config.gp_scale) as usize).max(1);
        let normal = Normal::new(0.0f32, config.gp_sigma).ok();
        let coarse: Vec<f32> = (0..gw * gh)
            .map(|_| normal.map(|n| n.sample(&mut rng)).unwrap_or(0.0))
            .collect();
        Some(resize_bicubic(&coarse, gw, gh, w, h))
    } else {
        None
    };
    for (i, d) in out.data.iter_mut().enumerate() {
        if is_valid_depth(*d) {
            *d *= factor;
            if let Some(f) = &field {
                *d += f[i];
            }
            if !is_valid_depth(*d) {
                *d = 0.0;
            }
        } else {
            *d = 0.0;
        }
    }
    out
}

/// Bicubic resize (Keys kernel, a = −0.75, half-pixel centres, replicated border), matching
/// OpenCV's `INTER_CUBIC`.
pub fn resize_bicubic(src: &[f32], sw: usize, sh: usize, dw: usize, dh: usize) -> Vec<f32> {
    fn weights(t: f32) -> [f32; 4] {
        const A: f32 = -0.75;
        let w0 = ((A * (t + 1.0) - 5.0 * A) * (t + 1.0) + 8.0 * A) * (t + 1.0) - 4.0 * A;
        let w1 = ((A + 2.0) * t - (A + 3.0)) * t * t + 1.0;
        let w2 = ((A + 2.0) * (1.0 - t) - (A + 3.0)) * (1.0 - t) * (1.0 - t) + 1.0;
        [w0, w1, w2, 1.0 - w0 - w1 - w2]
    }
    let mut out = vec![0.0f32; dw * dh];
    if sw == 0 || sh == 0 || src.len() != sw * sh {
        return out;
    }
    let sx = sw as f32 / dw as f32;
    let sy = sh as f32 / dh as f32;
    let taps = |pos: f32, n: usize| -> ([usize; 4], [f32; 4]) {
        let f = pos.floor();
        let w = weights(pos - f);
        let i0 = f as isize;
        let idx = std::array::from_fn(|k| (i0 - 1 + k as isize).clamp(0, n as isize - 1) as usize);
        (idx, w)
    };
    let cols: Vec<([usize; 4], [f32; 4])> = (0..dw)
        .map(|x| taps((x as f32 + 0.5) * sx - 0.5, sw))
        .collect();
    for y in 0..dh {
        let (ry, wy) = taps((y as f32 + 0.5) * sy - 0.5, sh);
        for (x, (rx, wx)) in cols.iter().enumerate() {
            let mut acc = 0.0;
            for (j, &row) in ry.iter().enumerate() {
                let line = &src[row * sw..(row + 1) * sw];
                let mut r = 0.0;
                for (k, &col) in rx.iter().enumerate() {
                    r += wx[k] * line[col];
                }
                acc += wy[j] * r;
            }
            out[y * dw + x] = acc;
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    fn flat(d: f32) -> DepthImage {
        let mut img = DepthImage {
            width: 64,
            height: 48,
            data: vec![d; 64 * 48],
        };
        img.data[5] = 0.0;
        img.data[6] = f32::NAN;
        img
    }

    #[test]
    fn noise_is_deterministic_and_keeps_invalid_pixels() {
        let img = flat(0.8);
        let cfg = NoiseConfig {
            gp_rate: 1.0,
            ..Default::default()
        };
        let a = add_dex_noise(&img, 7, &cfg);
        let b = add_dex_noise(&img, 7, &cfg);
        let c = add_dex_noise(&img, 8, &cfg);
        assert_eq!(a, b);
        assert_ne!(a, c);
        assert_eq!(a.data[5], 0.0);
        assert_eq!(a.data[6], 0.0);
        // Noise has the documented size: a few millimetres, not centimetres.
        let dev: Vec<f32> = a
            .data
            .iter()
            .filter(|d| **d > 0.0)
            .map(|d| d - 0.8)
            .collect();
        let rms = (dev.iter().map(|d| d * d).sum::<f32>() / dev.len() as f32).sqrt();
        assert!(rms > 1e-4 && rms < 0.05, "rms {rms}");
    }

    #[test]
    fn additive_noise_is_spatially_correlated() {
        let img = flat(1.0);
        let cfg = NoiseConfig {
            gamma_shape: 1e9,
            gamma_scale: 1e-9,
            gp_rate: 1.0,
            ..Default::default()
        };
        let a = add_dex_noise(&img, 3, &cfg);
        // Neighbouring pixels differ far less than the noise amplitude.
        let mut neigh = 0.0;
        let mut amp = 0.0;
        let mut n = 0;
        for y in 10..40 {
            for x in 10..60 {
                let i = y * 64 + x;
                neigh += (a.data[i] - a.data[i + 1]).powi(2);
                amp += (a.data[i] - 1.0).powi(2);
                n += 1;
            }
        }
        assert!(neigh / (n as f32) < 0.25 * amp / n as f32);
    }

    #[test]
    fn bicubic_reproduces_constant_and_interpolates_samples() {
        let src = vec![2.5f32; 12];
        assert!(resize_bicubic(&src, 4, 3, 16, 12)
            .iter()
            .all(|v| (v - 2.5).abs() < 1e-5));
        // Identity size is the identity.
        let src: Vec<f32> = (0..20).map(|i| i as f32 * 0.1).collect();
        let same = resize_bicubic(&src, 5, 4, 5, 4);
        for (a, b) in src.iter().zip(&same) {
            assert!((a - b).abs() < 1e-5);
        }
    }
}
