//! The one compute kernel of the native runtime and its dispatch.
//!
//! Every convolution, transposed convolution and dense layer is a sum of strided *segments*:
//! for `T` outputs `t` (consecutive voxels along z, or rows of a matrix) and `8·M` output
//! channels `c`, each segment with its own input step `tstride`,
//!
//! ```text
//! out[t·ostride + c] = act(bias[t·bias_stride + c] + Σ_seg Σ_k a_seg[t·tstride + k] · w_seg[k·wstride + c] + res[t·ostride + c])
//! ```
//!
//! In a channels-last grid the `3·C` inputs of one kernel row `(dx, dy)` for an output at `z` are
//! contiguous (`z−1 … z+1`, all channels), so a 3³ convolution is 9 segments of `K = 3C` per
//! output, a 1³ one 1 segment of `K = C`, a 2³ stride-2 one 4 segments of `K = 2C` with
//! `tstride = 2C`. The kernel keeps the `T × M` accumulators in registers, broadcasts one input
//! value per `k` and `t` and multiplies it with `M` weight vectors (AVX2 + FMA through `pulp`'s
//! `V3`; a portable scalar path otherwise). Register blocking: `T = 12` for 8 channels, else
//! `T = 6` outputs × 16 channels (wider outputs in chunks of 16).
#[cfg(target_arch = "x86_64")]
use pulp::x86::V3;
#[cfg(target_arch = "x86_64")]
use std::arch::x86_64::__m256;

/// One strided input of a tile (see the module docs).
#[derive(Debug, Clone, Copy)]
pub struct Seg {
    /// Input value for `t = 0`, `k = 0`.
    pub a: *const f32,
    /// Inner length.
    pub k: usize,
    /// Input step from one output to the next.
    pub tstride: usize,
    /// Weights for `k = 0`, channel 0 (rows of `wstride` floats).
    pub w: *const f32,
}

/// A run of outputs computed by [`run`].
#[derive(Debug, Clone, Copy)]
pub struct Job<'a> {
    /// The segments, each for the run's first output.
    pub segs: &'a [Seg],
    /// Weight row length (output channels, padded to a multiple of 8).
    pub wstride: usize,
    /// `wstride` biases for the first output.
    pub bias: *const f32,
    /// Bias step from one output to the next: 0 (one bias per channel) or a per-voxel field.
    pub bias_stride: usize,
    /// Residual for the first output (null: none), `ostride` apart like the outputs.
    pub res: *const f32,
    /// First output.
    pub out: *mut f32,
    /// Output step from one output to the next.
    pub ostride: usize,
    /// 0: outputs channels-last, `wstride` floats each. Else channel-major: channel `c` of
    /// output `t` at `out + c·out_plane + t·ostride`, only the first `out_channels` written.
    pub out_plane: usize,
    /// Channels written in channel-major mode.
    pub out_channels: usize,
    /// ReLU at the end.
    pub relu: bool,
}

/// Whether the AVX2 + FMA kernels run on this CPU.
#[derive(Debug, Clone, Copy)]
pub enum Simd {
    /// AVX2 + FMA (x86-64-v3).
    #[cfg(target_arch = "x86_64")]
    V3(V3),
    /// Portable scalar code.
    Scalar,
}

impl Simd {
    /// The best available.
    pub fn detect() -> Self {
        #[cfg(target_arch = "x86_64")]
        if let Some(v3) = V3::try_new() {
            return Self::V3(v3);
        }
        Self::Scalar
    }

    /// A name for reports.
    pub fn name(self) -> &'static str {
        match self {
            #[cfg(target_arch = "x86_64")]
            Self::V3(_) => "avx2+fma",
            Self::Scalar => "scalar",
        }
    }
}

/// Output channel vectors per register tile and outputs per tile for `remaining` channels
/// (12 accumulators; wider outputs in chunks of 16 keep a chunk's weights small enough to stay
/// in the L1/L2 cache while the tiles stream past them).
fn blocking(remaining: usize) -> (usize, usize) {
    match remaining {
        8 => (1, 12),
        _ => (2, 6),
    }
}

/// Computes `count` outputs of `job` (all `wstride` channels).
///
/// # Safety
/// Every pointer of `job` must be valid for the reads/writes the formula implies for `count`
/// outputs: segments for `(count−1)·tstride + k` floats, weights for `k` rows of `wstride`,
/// outputs and residual for `(count−1)·ostride + wstride`. `wstride` is a multiple of 8.
pub unsafe fn run(simd: Simd, job: &Job<'_>, count: usize) {
    debug_assert!(job.wstride.is_multiple_of(8));
    match simd {
        #[cfg(target_arch = "x86_64")]
        Simd::V3(v3) => {
            let mut c0 = 0;
            while c0 < job.wstride {
                let (m, tmax) = blocking(job.wstride - c0);
                // Balanced tiles (64 = 11+11+11+11+10+10, not 12·5 + 4): a short last tile
                // has too few independent accumulators to hide the FMA latency.
                let tiles = count.div_ceil(tmax);
                let mut t0 = 0;
                for i in 0..tiles {
                    let t = (count - t0) / (tiles - i);
                    // SAFETY: the caller's contract covers outputs t0..t0+t, channels c0..c0+8m.
                    unsafe { dispatch(v3, m, t, job, t0, c0) };
                    t0 += t;
                }
                debug_assert_eq!(t0, count);
                c0 += 8 * m;
            }
        }
        Simd::Scalar => unsafe { scalar(job, count) },
    }
}

#[cfg(target_arch = "x86_64")]
macro_rules! tiles {
    ($v3:expr, $m:expr, $t:expr, $job:expr, $t0:expr, $c0:expr; $($mm:literal => [$($tt:literal)*]),*) => {
        match ($m, $t) {
            $($( ($mm, $tt) => $v3.vectorize(
                #[inline(always)]
                || unsafe { tile::<$tt, $mm>($v3, $job, $t0, $c0) },
            ), )*)*
            _ => unreachable!("no tile for m = {}, t = {}", $m, $t),
        }
    };
}

#[cfg(target_arch = "x86_64")]
#[inline(never)]
unsafe fn dispatch(v3: V3, m: usize, t: usize, job: &Job<'_>, t0: usize, c0: usize) {
    tiles!(v3, m, t, job, t0, c0;
        1 => [1 2 3 4 5 6 7 8 9 10 11 12],
        2 => [1 2 3 4 5 6])
}

#[cfg(target_arch = "x86_64")]
#[inline(always)]
unsafe fn load(p: *const f32) -> __m256 {
    // SAFETY: the caller guarantees 8 readable floats.
    unsafe { core::ptr::read_unaligned(p as *const __m256) }
}

#[cfg(target_arch = "x86_64")]
#[inline(always)]
unsafe fn store(p: *mut f32, v: __m256) {
    // SAFETY: the caller guarantees 8 writable floats.
    unsafe { core::ptr::write_unaligned(p as *mut __m256, v) }
}

/// `T` outputs from `t0`, channels `c0 .. c0 + 8M`.
#[cfg(target_arch = "x86_64")]
#[inline(always)]
unsafe fn tile<const T: usize, const M: usize>(s: V3, job: &Job<'_>, t0: usize, c0: usize) {
    unsafe {
        let mut acc = [[s.avx._mm256_setzero_ps(); M]; T];
        for m in 0..M {
            let b = load(job.bias.add(c0 + 8 * m));
            for (t, row) in acc.iter_mut().enumerate() {
                row[m] = if job.bias_stride == 0 {
                    b
                } else {
                    load(job.bias.add((t0 + t) * job.bias_stride + c0 + 8 * m))
                };
            }
        }
        for sg in job.segs {
            let mut a = sg.a.add(t0 * sg.tstride);
            let mut w = sg.w.add(c0);
            for _ in 0..sg.k {
                let mut wv = [s.avx._mm256_setzero_ps(); M];
                for (m, v) in wv.iter_mut().enumerate() {
                    *v = load(w.add(8 * m));
                }
                for (t, row) in acc.iter_mut().enumerate() {
                    let x = s.avx._mm256_broadcast_ss(&*a.add(t * sg.tstride));
                    for m in 0..M {
                        row[m] = s.fma._mm256_fmadd_ps(x, wv[m], row[m]);
                    }
                }
                a = a.add(1);
                w = w.add(job.wstride);
            }
        }
        let zero = s.avx._mm256_setzero_ps();
        let res = job.res;
        for (t, row) in acc.iter().enumerate() {
            for (m, &v) in row.iter().enumerate() {
                let mut v = v;
                if !res.is_null() {
                    let r = load(res.add((t0 + t) * job.ostride + c0 + 8 * m));
                    v = s.avx._mm256_add_ps(v, r);
                }
                if job.relu {
                    v = s.avx._mm256_max_ps(v, zero);
                }
                if job.out_plane == 0 {
                    store(job.out.add((t0 + t) * job.ostride + c0 + 8 * m), v);
                } else {
                    let lanes: [f32; 8] = core::mem::transmute(v);
                    let first = c0 + 8 * m;
                    for (l, &x) in lanes
                        .iter()
                        .enumerate()
                        .take(job.out_channels.saturating_sub(first))
                    {
                        *job.out
                            .add((first + l) * job.out_plane + (t0 + t) * job.ostride) = x;
                    }
                }
            }
        }
    }
}

/// The same formula in plain Rust (CPUs without AVX2/FMA, and the tests' second opinion).
unsafe fn scalar(job: &Job<'_>, count: usize) {
    let n = job.wstride;
    let mut acc = vec![0.0f32; n];
    for t in 0..count {
        unsafe {
            acc.copy_from_slice(std::slice::from_raw_parts(
                job.bias.add(t * job.bias_stride),
                n,
            ));
            for sg in job.segs {
                let a = sg.a.add(t * sg.tstride);
                for k in 0..sg.k {
                    let x = *a.add(k);
                    let w = std::slice::from_raw_parts(sg.w.add(k * job.wstride), n);
                    for (o, &wv) in acc.iter_mut().zip(w) {
                        *o += x * wv;
                    }
                }
            }
            if !job.res.is_null() {
                let r = std::slice::from_raw_parts(job.res.add(t * job.ostride), n);
                for (o, &rv) in acc.iter_mut().zip(r) {
                    *o += rv;
                }
            }
            for (c, &v) in acc.iter().enumerate() {
                let v = if job.relu { v.max(0.0) } else { v };
                if job.out_plane == 0 {
                    *job.out.add(t * job.ostride + c) = v;
                } else if c < job.out_channels {
                    *job.out.add(c * job.out_plane + t * job.ostride) = v;
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Deterministic pseudo-random values in [-1, 1).
    pub(crate) fn noise(n: usize, seed: u64) -> Vec<f32> {
        let mut s = seed.wrapping_mul(0x9E37_79B9_7F4A_7C15) | 1;
        (0..n)
            .map(|_| {
                s ^= s << 13;
                s ^= s >> 7;
                s ^= s << 17;
                ((s >> 40) as f32 / (1u64 << 24) as f32) * 2.0 - 1.0
            })
            .collect()
    }

    /// The formula of the module docs, one output at a time in f64.
    #[allow(clippy::too_many_arguments)]
    fn naive(
        segs: &[(Vec<f32>, Vec<f32>)],
        k: usize,
        tstride: usize,
        n: usize,
        count: usize,
        bias: (&[f32], usize),
        res: Option<&[f32]>,
        relu: bool,
    ) -> Vec<f32> {
        let mut out = vec![0.0; count * n];
        for t in 0..count {
            for c in 0..n {
                let mut v = bias.0[t * bias.1 + c] as f64;
                for (a, w) in segs {
                    for kk in 0..k {
                        v += a[t * tstride + kk] as f64 * w[kk * n + c] as f64;
                    }
                }
                if let Some(r) = res {
                    v += r[t * n + c] as f64;
                }
                out[t * n + c] = if relu { v.max(0.0) as f32 } else { v as f32 };
            }
        }
        out
    }

    #[test]
    fn every_tile_shape_matches_the_formula() {
        for simd in [Simd::detect(), Simd::Scalar] {
            for n in [8usize, 16, 24, 32, 64] {
                for count in [1usize, 5, 12, 13, 29] {
                    for (k, tstride, relu, with_res) in [(24, 8, true, false), (7, 3, false, true)]
                    {
                        let segs: Vec<(Vec<f32>, Vec<f32>)> = (0..3)
                            .map(|i| (noise(count * tstride + k, 10 + i), noise(k * n, 20 + i)))
                            .collect();
                        // With a residual, also a per-output bias field.
                        let bias_stride = if with_res { n } else { 0 };
                        let bias = noise(n + count * bias_stride, 1);
                        let res = noise(count * n, 2);
                        let want = naive(
                            &segs,
                            k,
                            tstride,
                            n,
                            count,
                            (&bias, bias_stride),
                            with_res.then_some(&res[..]),
                            relu,
                        );
                        let ptrs: Vec<Seg> = segs
                            .iter()
                            .map(|(a, w)| Seg {
                                a: a.as_ptr(),
                                k,
                                tstride,
                                w: w.as_ptr(),
                            })
                            .collect();
                        let mut out = vec![f32::NAN; count * n];
                        let job = Job {
                            segs: &ptrs,
                            wstride: n,
                            bias: bias.as_ptr(),
                            bias_stride,
                            res: if with_res {
                                res.as_ptr()
                            } else {
                                std::ptr::null()
                            },
                            out: out.as_mut_ptr(),
                            ostride: n,
                            out_plane: 0,
                            out_channels: 0,
                            relu,
                        };
                        unsafe { run(simd, &job, count) };
                        for (i, (a, b)) in out.iter().zip(&want).enumerate() {
                            assert!(
                                (a - b).abs() < 1e-4,
                                "{} n={n} count={count} k={k} [{i}]: {a} vs {b}",
                                simd.name()
                            );
                        }
                    }
                }
            }
        }
    }
}
