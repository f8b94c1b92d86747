//! Runs a [`UnetPlan`]: channels-last buffers with a one-voxel zero halo (the convolutions'
//! zero padding), packed weights, and the background skip of [`super::spans`].
//!
//! Every buffer always holds the exact values for the last input. At load the plan runs once
//! densely on an all-zero grid, so every buffer starts as its background. Per frame each op
//! computes its *changed* spans (its inputs' changed spans through its footprint) plus the spans
//! that were changed the frame before (they still hold that frame's values and must return to
//! the background); everything else is left as it is.
use super::kernels::{self, Job, Seg, Simd};
use super::plan::{BufInfo, TermKind, UnetPlan};
use super::spans::Spans;
use rayon::prelude::*;
use std::sync::Arc;

/// Per-op figures of the last run.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct OpStats {
    /// The fused ONNX nodes.
    pub nodes: Vec<String>,
    /// Share of the output grid that may differ from the background.
    pub changed_share: f64,
    /// Multiply-adds computed.
    pub macs: u64,
    /// Multiply-adds of a dense pass.
    pub dense_macs: u64,
}

struct PackedTerm {
    input: usize,
    kind: TermKind,
    /// Inner length per segment.
    k: usize,
    /// `[segments][k][cp]`.
    w: Vec<f32>,
    /// Multiply-adds per output voxel (per input voxel for `Up2`), real channels only.
    macs: usize,
}

struct PackedOp {
    terms: Vec<PackedTerm>,
    /// Output channels padded to 8.
    cp: usize,
    bias: Vec<f32>,
    out: usize,
    residual: Option<usize>,
    relu: bool,
    transpose: bool,
    nodes: Vec<String>,
}

/// A raw pointer shared by the worker threads; each writes disjoint voxels.
#[derive(Clone, Copy)]
struct Shared(*mut f32);
// SAFETY: the executor hands each thread disjoint output columns; inputs are only read.
unsafe impl Send for Shared {}
unsafe impl Sync for Shared {}

/// The U-Net plan with its buffers.
pub struct UnetExec {
    plan: UnetPlan,
    ops: Vec<PackedOp>,
    bufs: Vec<Vec<f32>>,
    /// Per buffer: where it holds values other than its background.
    prev: Vec<Spans>,
    simd: Simd,
    pool: Option<Arc<rayon::ThreadPool>>,
    stats: Vec<OpStats>,
}

impl std::fmt::Debug for UnetExec {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("UnetExec")
            .field("ops", &self.ops.len())
            .field("simd", &self.simd.name())
            .finish_non_exhaustive()
    }
}

/// Offset (in voxels) of `(x, y, z)` (each in `-1..=n`) in a halo-padded buffer of `dims`.
#[inline]
fn voxel(dims: [usize; 3], x: isize, y: isize, z: isize) -> usize {
    let (py, pz) = (dims[1] as isize + 2, dims[2] as isize + 2);
    (((x + 1) * py + y + 1) * pz + z + 1) as usize
}

fn padded_len(b: &BufInfo) -> usize {
    (b.dims[0] + 2) * (b.dims[1] + 2) * (b.dims[2] + 2) * b.stride
}

fn pack(plan: &UnetPlan, op_index: usize) -> PackedOp {
    let op = &plan.ops[op_index];
    let cp = op.cout.div_ceil(8) * 8;
    let mut bias = op.bias.clone();
    bias.resize(cp, 0.0);
    let terms = op
        .terms
        .iter()
        .map(|t| {
            let s = plan.bufs[t.input].stride;
            let (segs, k) = match t.kind {
                TermKind::K3 => (9, 3 * s),
                TermKind::K1 => (1, s),
                TermKind::Down2 => (4, 2 * s),
                TermKind::Up2 => (8, s),
            };
            let mut w = vec![0.0; segs * k * cp];
            for co in 0..op.cout {
                for ci in 0..t.cin {
                    match t.kind {
                        TermKind::K3 => {
                            for dx in 0..3 {
                                for dy in 0..3 {
                                    for dz in 0..3 {
                                        let src = (((co * t.cin + ci) * 3 + dx) * 3 + dy) * 3 + dz;
                                        let seg = dx * 3 + dy;
                                        w[(seg * k + dz * s + ci) * cp + co] = t.weights[src];
                                    }
                                }
                            }
                        }
                        TermKind::K1 => w[ci * cp + co] = t.weights[co * t.cin + ci],
                        TermKind::Down2 => {
                            for p in 0..8 {
                                let (a, b, c) = (p >> 2, (p >> 1) & 1, p & 1);
                                let src = (co * t.cin + ci) * 8 + p;
                                w[((a * 2 + b) * k + c * s + ci) * cp + co] = t.weights[src];
                            }
                        }
                        TermKind::Up2 => {
                            for p in 0..8 {
                                let src = (ci * op.cout + co) * 8 + p;
                                w[(p * k + ci) * cp + co] = t.weights[src];
                            }
                        }
                    }
                }
            }
            PackedTerm {
                input: t.input,
                kind: t.kind,
                k,
                w,
                macs: t.macs_per_output(op.cout),
            }
        })
        .collect();
    PackedOp {
        terms,
        cp,
        bias,
        out: op.out,
        residual: op.residual,
        relu: op.relu,
        transpose: op.is_transpose(),
        nodes: op.nodes.clone(),
    }
}

impl UnetExec {
    /// Packs `plan`, allocates its buffers and computes every buffer's background (one dense
    /// run on zeros). With a `pool`, the kernels run on its threads.
    pub fn new(plan: UnetPlan, pool: Option<Arc<rayon::ThreadPool>>, simd: Simd) -> Self {
        let ops = (0..plan.ops.len()).map(|i| pack(&plan, i)).collect();
        let bufs = plan.bufs.iter().map(|b| vec![0.0; padded_len(b)]).collect();
        let prev = plan.bufs.iter().map(|b| Spans::full(b.dims)).collect();
        let mut exec = Self {
            plan,
            ops,
            bufs,
            prev,
            simd,
            pool,
            stats: Vec::new(),
        };
        let b = exec.plan.bufs[0];
        let zeros = vec![0.0; b.channels * b.dims.iter().product::<usize>()];
        exec.run(&zeros);
        exec
    }

    /// The plan.
    pub fn plan(&self) -> &UnetPlan {
        &self.plan
    }

    /// Per-op figures of the last run.
    pub fn stats(&self) -> &[OpStats] {
        &self.stats
    }

    /// Runs the plan on a channel-major `[C, X, Y, Z]` input (length checked by the caller).
    pub fn run(&mut self, input: &[f32]) {
        let info = self.plan.bufs[0];
        let changed = Spans::nonzero(info.dims, info.channels, input);
        let write = changed.union(&self.prev[0]);
        self.write_input(input, &write);
        let mut cur: Vec<Option<Spans>> = vec![None; self.plan.bufs.len()];
        cur[0] = Some(changed.clone());
        self.prev[0] = changed;
        let mut stats = Vec::with_capacity(self.ops.len());
        for i in 0..self.ops.len() {
            let op = &self.ops[i];
            let mut changed: Option<Spans> = None;
            for t in &op.terms {
                let s = cur[t.input].as_ref().expect("inputs run before");
                let s = match t.kind {
                    TermKind::K3 => s.dilate3(),
                    TermKind::K1 => s.clone(),
                    TermKind::Down2 => s.down2(),
                    TermKind::Up2 => s.up2(),
                };
                changed = Some(match changed {
                    Some(c) => c.union(&s),
                    None => s,
                });
            }
            let out_dims = self.plan.bufs[op.out].dims;
            let mut changed = changed.unwrap_or_else(|| Spans::empty(out_dims));
            if let Some(r) = op.residual {
                changed = changed.union(cur[r].as_ref().expect("residual runs before"));
            }
            let compute = changed.union(&self.prev[op.out]);
            let per_voxel: usize = op.terms.iter().map(|t| t.macs).sum();
            let (macs, dense) = if op.transpose {
                let coarse = compute.down2();
                self.run_transpose(i, &coarse);
                let n: usize = out_dims.iter().product::<usize>() / 8;
                ((coarse.voxels() * per_voxel) as u64, (n * per_voxel) as u64)
            } else {
                self.run_conv(i, &compute);
                let n: usize = out_dims.iter().product();
                (
                    (compute.voxels() * per_voxel) as u64,
                    (n * per_voxel) as u64,
                )
            };
            let op = &self.ops[i];
            stats.push(OpStats {
                nodes: op.nodes.clone(),
                changed_share: changed.share(),
                macs,
                dense_macs: dense,
            });
            self.prev[op.out] = changed.clone();
            cur[op.out] = Some(changed);
        }
        self.stats = stats;
    }

    /// Copies the channel-major input into buffer 0 over `spans`.
    fn write_input(&mut self, input: &[f32], spans: &Spans) {
        let info = self.plan.bufs[0];
        let [nx, ny, nz] = info.dims;
        let plane = nx * ny * nz;
        let c = info.channels;
        let buf = &mut self.bufs[0];
        for x in 0..nx {
            for y in 0..ny {
                let Some((lo, hi)) = spans.col(x, y) else {
                    continue;
                };
                let base = voxel(info.dims, x as isize, y as isize, 0) * c;
                for z in lo..hi {
                    for ch in 0..c {
                        buf[base + z * c + ch] = input[ch * plane + (x * ny + y) * nz + z];
                    }
                }
            }
        }
    }

    fn for_each_x(&self, nx: usize, f: impl Fn(usize) + Sync + Send) {
        match &self.pool {
            Some(pool) => pool.install(|| (0..nx).into_par_iter().for_each(f)),
            None => (0..nx).for_each(f),
        }
    }

    fn run_conv(&mut self, i: usize, compute: &Spans) {
        let op = &self.ops[i];
        let out_info = self.plan.bufs[op.out];
        let dims = out_info.dims;
        let out = Shared(self.bufs[op.out].as_mut_ptr());
        let res = op
            .residual
            .map(|r| Shared(self.bufs[r].as_ptr() as *mut f32));
        let inputs: Vec<(Shared, BufInfo)> = op
            .terms
            .iter()
            .map(|t| {
                (
                    Shared(self.bufs[t.input].as_ptr() as *mut f32),
                    self.plan.bufs[t.input],
                )
            })
            .collect();
        let simd = self.simd;
        let work = |x: usize| {
            let (out, res) = (out, res);
            let mut segs: Vec<Seg> = Vec::with_capacity(op.terms.len() * 9);
            for y in 0..dims[1] {
                let Some((z0, z1)) = compute.col(x, y) else {
                    continue;
                };
                segs.clear();
                for (t, &(ptr, info)) in op.terms.iter().zip(&inputs) {
                    let s = info.stride;
                    let (xi, yi, zi) = (x as isize, y as isize, z0 as isize);
                    // SAFETY (all `add`s): offsets of voxels inside the padded input buffer.
                    match t.kind {
                        TermKind::K3 => {
                            for dx in 0..3 {
                                for dy in 0..3 {
                                    let v = voxel(info.dims, xi + dx - 1, yi + dy - 1, zi - 1);
                                    segs.push(Seg {
                                        a: unsafe { ptr.0.add(v * s) },
                                        k: t.k,
                                        tstride: s,
                                        w: unsafe {
                                            t.w.as_ptr().add(((dx * 3 + dy) as usize) * t.k * op.cp)
                                        },
                                    });
                                }
                            }
                        }
                        TermKind::K1 => segs.push(Seg {
                            a: unsafe { ptr.0.add(voxel(info.dims, xi, yi, zi) * s) },
                            k: t.k,
                            tstride: s,
                            w: t.w.as_ptr(),
                        }),
                        TermKind::Down2 => {
                            for a in 0..2 {
                                for b in 0..2 {
                                    let v = voxel(info.dims, 2 * xi + a, 2 * yi + b, 2 * zi);
                                    segs.push(Seg {
                                        a: unsafe { ptr.0.add(v * s) },
                                        k: t.k,
                                        tstride: 2 * s,
                                        w: unsafe {
                                            t.w.as_ptr().add(((a * 2 + b) as usize) * t.k * op.cp)
                                        },
                                    });
                                }
                            }
                        }
                        TermKind::Up2 => unreachable!("transposed terms run in run_transpose"),
                    }
                }
                let o = voxel(dims, x as isize, y as isize, z0 as isize) * out_info.stride;
                let job = Job {
                    segs: &segs,
                    wstride: op.cp,
                    bias: op.bias.as_ptr(),
                    res: res.map_or(std::ptr::null(), |r| unsafe { r.0.add(o) as *const f32 }),
                    out: unsafe { out.0.add(o) },
                    ostride: out_info.stride,
                    relu: op.relu,
                };
                // SAFETY: segments, residual and output lie inside their padded buffers for
                // z0..z1 (the halo covers the 3³ reads at the grid's faces); each x is
                // written by one thread.
                unsafe { kernels::run(simd, &job, z1 - z0) };
            }
        };
        self.for_each_x(dims[0], work);
    }

    fn run_transpose(&mut self, i: usize, coarse: &Spans) {
        let op = &self.ops[i];
        let out_info = self.plan.bufs[op.out];
        let out = Shared(self.bufs[op.out].as_mut_ptr());
        let res = op
            .residual
            .map(|r| Shared(self.bufs[r].as_ptr() as *mut f32));
        let inputs: Vec<(Shared, BufInfo)> = op
            .terms
            .iter()
            .map(|t| {
                (
                    Shared(self.bufs[t.input].as_ptr() as *mut f32),
                    self.plan.bufs[t.input],
                )
            })
            .collect();
        let simd = self.simd;
        let cdims = coarse.dims();
        let work = |x: usize| {
            let (out, res) = (out, res);
            let mut segs: Vec<Seg> = Vec::with_capacity(op.terms.len());
            for y in 0..cdims[1] {
                let Some((z0, z1)) = coarse.col(x, y) else {
                    continue;
                };
                for p in 0..8usize {
                    let (a, b, c) = ((p >> 2) as isize, ((p >> 1) & 1) as isize, (p & 1) as isize);
                    segs.clear();
                    for (t, &(ptr, info)) in op.terms.iter().zip(&inputs) {
                        let v = voxel(info.dims, x as isize, y as isize, z0 as isize);
                        segs.push(Seg {
                            // SAFETY: a voxel of the padded input buffer.
                            a: unsafe { ptr.0.add(v * info.stride) },
                            k: t.k,
                            tstride: info.stride,
                            w: unsafe { t.w.as_ptr().add(p * t.k * op.cp) },
                        });
                    }
                    let o = voxel(
                        out_info.dims,
                        2 * x as isize + a,
                        2 * y as isize + b,
                        2 * z0 as isize + c,
                    ) * out_info.stride;
                    let job = Job {
                        segs: &segs,
                        wstride: op.cp,
                        bias: op.bias.as_ptr(),
                        res: res.map_or(std::ptr::null(), |r| unsafe { r.0.add(o) as *const f32 }),
                        out: unsafe { out.0.add(o) },
                        ostride: 2 * out_info.stride,
                        relu: op.relu,
                    };
                    // SAFETY: fine voxels 2·z + c for z in z0..z1 lie inside the output grid;
                    // coarse x owns fine x 2x and 2x + 1.
                    unsafe { kernels::run(simd, &job, z1 - z0) };
                }
            }
        };
        self.for_each_x(cdims[0], work);
    }

    /// Output buffer `b` as a channel-major `[C, X, Y, Z]` vector.
    pub fn channel_major(&self, b: usize) -> Vec<f32> {
        let info = self.plan.bufs[b];
        let [nx, ny, nz] = info.dims;
        let plane = nx * ny * nz;
        let c = info.channels;
        let mut out = vec![0.0f32; c * plane];
        let dst = Shared(out.as_mut_ptr());
        let src = &self.bufs[b];
        let work = |x: usize| {
            let dst = dst;
            for y in 0..ny {
                let base = voxel(info.dims, x as isize, y as isize, 0) * info.stride;
                let col = (x * ny + y) * nz;
                for ch in 0..c {
                    // SAFETY: column (x, y) of channel ch; each x is written by one thread.
                    let row =
                        unsafe { std::slice::from_raw_parts_mut(dst.0.add(ch * plane + col), nz) };
                    for (z, v) in row.iter_mut().enumerate() {
                        *v = src[base + z * info.stride + ch];
                    }
                }
            }
        };
        self.for_each_x(nx, work);
        out
    }
}
