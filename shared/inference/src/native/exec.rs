//! Runs a [`UnetPlan`]: channels-last buffers with a one-voxel zero halo (the convolutions'
//! zero padding), packed weights, and the background skip of [`super::spans`].
//!
//! Every buffer always holds the exact values for the last input. At load the plan runs once
//! densely on an all-zero grid, so every buffer starts as its background. Per frame each op
//! computes its *changed* spans (its inputs' changed spans through its footprint) plus the spans
//! that were changed the frame before (they still hold that frame's values and must return to
//! the background); everything else is left as it is.
use super::kernels::{self, Job, Seg, Simd};
use super::pack::{pack, padded_len, push_segs, voxel, PackedOp, Shared};
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
    /// Wall time of the op.
    pub time: std::time::Duration,
}

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
    /// Whether to skip the background (off: every op computes its whole grid).
    skip: bool,
    /// Wall time of the input's conversion (spans and channels-last copy) in the last run.
    input_time: std::time::Duration,
    /// Per op with a field term: bias + the term's background contribution, laid out like the
    /// output (computed during the first run, on the all-zero input).
    fields: Vec<Option<Vec<f32>>>,
    fields_ready: Vec<bool>,
    /// The plan's outputs, channel-major, handed out shared and updated in place where they
    /// changed (a copy is made only while a caller still holds the previous frame's).
    outputs_cm: Vec<Arc<Vec<f32>>>,
    /// Per output: where it holds values other than its background.
    outputs_changed: Vec<Spans>,
    /// Per op: the output it writes straight into, channel-major (an output no other op reads,
    /// e.g. the head's label logits), skipping its channels-last buffer.
    direct: Vec<Option<usize>>,
    /// Wall time of the last run's output conversion.
    output_time: std::time::Duration,
    /// Approximate mode (0 = off, exact): every op computes only within this many voxels
    /// (level-0 voxels, halved per level) of the non-zero input; elsewhere its output is taken
    /// as its background.
    band: usize,
    /// Background copies of every buffer and of the direct outputs (approximate mode only:
    /// voxels that leave the band are reset from them).
    background: Option<BackgroundCopies>,
}

/// Background copies of the buffers and of the direct outputs (approximate mode).
struct BackgroundCopies {
    /// Per buffer, channels-last with its halo.
    bufs: Vec<Vec<f32>>,
    /// Per op writing an output directly, that output channel-major.
    direct: Vec<Option<Vec<f32>>>,
}

impl std::fmt::Debug for UnetExec {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("UnetExec")
            .field("ops", &self.ops.len())
            .field("simd", &self.simd.name())
            .finish_non_exhaustive()
    }
}

/// What [`UnetExec::run_conv`] writes.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum ConvMode {
    /// The op's output.
    Output,
    /// The op's field: bias + the field term on the background.
    Field,
}

impl UnetExec {
    /// Packs `plan`, allocates its buffers and computes every buffer's background (one dense
    /// run on zeros). With a `pool`, the kernels run on its threads.
    pub fn new(plan: UnetPlan, pool: Option<Arc<rayon::ThreadPool>>, simd: Simd) -> Self {
        let ops: Vec<PackedOp> = (0..plan.ops.len()).map(|i| pack(&plan, i)).collect();
        let fields = ops
            .iter()
            .map(|op| op.field.then(|| vec![0.0; padded_len(&plan.bufs[op.out])]))
            .collect();
        let bufs = plan.bufs.iter().map(|b| vec![0.0; padded_len(b)]).collect();
        let prev = plan.bufs.iter().map(|b| Spans::full(b.dims)).collect();
        let n_ops = ops.len();
        let read = |b: usize| {
            ops.iter()
                .any(|op| op.residual == Some(b) || op.terms.iter().any(|t| t.input == b))
        };
        let direct = ops
            .iter()
            .map(|op| {
                let j = plan.outputs.iter().position(|&o| o == op.out)?;
                let plain = !op.transpose && !op.field && op.residual.is_none();
                (plain && !read(op.out)).then_some(j)
            })
            .collect();
        let outputs_cm = plan
            .outputs
            .iter()
            .map(|&b| {
                let info = plan.bufs[b];
                Arc::new(vec![
                    0.0;
                    info.channels * info.dims.iter().product::<usize>()
                ])
            })
            .collect();
        let outputs_changed = plan
            .outputs
            .iter()
            .map(|&b| Spans::full(plan.bufs[b].dims))
            .collect();
        let mut exec = Self {
            plan,
            ops,
            bufs,
            prev,
            simd,
            pool,
            stats: Vec::new(),
            skip: true,
            input_time: Default::default(),
            fields,
            fields_ready: vec![false; n_ops],
            outputs_cm,
            outputs_changed,
            direct,
            output_time: Default::default(),
            band: 0,
            background: None,
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

    /// Wall time of the last run's input conversion.
    pub fn input_time(&self) -> std::time::Duration {
        self.input_time
    }

    /// Approximate mode: with `band` > 0, every op computes only within `band` voxels (at the
    /// input's resolution, halved per level) of the input's non-zero voxels and takes its
    /// background value elsewhere — exact in the encoder near the surface, an approximation of
    /// the decoder far from it (docs/benchmarks.md measures the effect). 0 (default): exact.
    pub fn set_band(&mut self, band: usize) {
        if band > 0 && self.background.is_none() {
            self.band = 0;
            let b = self.plan.bufs[0];
            self.run(&vec![0.0; b.channels * b.dims.iter().product::<usize>()]);
            let outputs = (0..self.outputs_cm.len())
                .map(|j| {
                    self.direct
                        .contains(&Some(j))
                        .then(|| self.outputs_cm[j].as_ref().clone())
                })
                .collect();
            self.background = Some(BackgroundCopies {
                bufs: self.bufs.clone(),
                direct: outputs,
            });
        }
        self.band = band;
    }

    /// Resets buffer `b` (or direct output `j`) to its background over `prev` outside `cur`.
    fn restore(&mut self, b: usize, direct: Option<usize>, prev: &Spans, cur: &Spans) {
        let Some(BackgroundCopies {
            bufs,
            direct: outputs,
        }) = &self.background
        else {
            return;
        };
        let info = self.plan.bufs[b];
        let [_, ny, nz] = info.dims;
        let plane = info.dims.iter().product::<usize>();
        match direct {
            Some(j) => {
                let bg = outputs[j]
                    .as_ref()
                    .expect("direct outputs have a background copy");
                let dst = Arc::make_mut(&mut self.outputs_cm[j]);
                prev.for_each_outside(cur, |x, y, lo, hi| {
                    for c in 0..info.channels {
                        let r = c * plane + (x * ny + y) * nz;
                        dst[r + lo..r + hi].copy_from_slice(&bg[r + lo..r + hi]);
                    }
                });
            }
            None => {
                let (bg, dst) = (&bufs[b], &mut self.bufs[b]);
                prev.for_each_outside(cur, |x, y, lo, hi| {
                    let a = voxel(info.dims, x as isize, y as isize, lo as isize) * info.stride;
                    let e = a + (hi - lo) * info.stride;
                    dst[a..e].copy_from_slice(&bg[a..e]);
                });
            }
        }
    }

    /// Turns the background skip on (default) or off (every op computes its whole grid; for
    /// measuring what the skip saves).
    pub fn set_background_skip(&mut self, on: bool) {
        self.skip = on;
    }

    /// Runs the plan on a channel-major `[C, X, Y, Z]` input (length checked by the caller).
    pub fn run(&mut self, input: &[f32]) {
        let start = std::time::Instant::now();
        let info = self.plan.bufs[0];
        let mut changed = Spans::nonzero(info.dims, info.channels, input);
        if !self.skip {
            changed = Spans::full(info.dims);
        }
        let write = changed.union(&self.prev[0]);
        self.write_input(input, &write);
        let mut cur: Vec<Option<Spans>> = vec![None; self.plan.bufs.len()];
        // Approximate mode: the band around the non-zero input, per level.
        let mut bands: Vec<Spans> = Vec::new();
        if self.band > 0 {
            bands.push(changed.dilate(self.band));
        }
        cur[0] = Some(changed.clone());
        self.prev[0] = changed;
        self.input_time = start.elapsed();
        let mut stats = Vec::with_capacity(self.ops.len());
        for i in 0..self.ops.len() {
            let op = &self.ops[i];
            let mut changed: Option<Spans> = None;
            let mut last_term = None;
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
                    None => s.clone(),
                });
                last_term = Some(s);
            }
            let out_dims = self.plan.bufs[op.out].dims;
            let mut changed = changed.unwrap_or_else(|| Spans::empty(out_dims));
            if let Some(r) = op.residual {
                changed = changed.union(cur[r].as_ref().expect("residual runs before"));
            }
            let approximate = !bands.is_empty();
            if approximate {
                while bands.last().is_some_and(|b| b.dims()[0] > out_dims[0]) {
                    let next = bands.last().expect("non-empty").down2();
                    bands.push(next);
                }
                if let Some(band) = bands.iter().find(|b| b.dims() == out_dims) {
                    changed = changed.intersect(band);
                }
                if op.transpose {
                    // Everything written (whole 2³ blocks) counts as changed.
                    changed = changed.down2().up2();
                }
            }
            let compute = if approximate {
                changed.clone()
            } else {
                changed.union(&self.prev[op.out])
            };
            let start = std::time::Instant::now();
            let per_voxel: usize = op.terms.iter().map(|t| t.macs).sum();
            let (macs, dense) = if op.transpose {
                let coarse = compute.down2();
                self.run_transpose(i, &coarse);
                let n: usize = out_dims.iter().product::<usize>() / 8;
                ((coarse.voxels() * per_voxel) as u64, (n * per_voxel) as u64)
            } else if op.field {
                let region = last_term.expect("a field op has terms");
                let term_macs = op.terms.last().map_or(0, |t| t.macs);
                if !self.fields_ready[i] {
                    let full = Spans::full(out_dims);
                    self.run_conv(i, &full, None, ConvMode::Field);
                    self.fields_ready[i] = true;
                }
                self.run_conv(i, &compute, Some(&region), ConvMode::Output);
                let n: usize = out_dims.iter().product();
                let with_term = compute.intersection_voxels(&region);
                (
                    (compute.voxels() * (per_voxel - term_macs) + with_term * term_macs) as u64,
                    (n * per_voxel) as u64,
                )
            } else {
                self.run_conv(i, &compute, None, ConvMode::Output);
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
                time: start.elapsed(),
            });
            let out = op.out;
            if approximate {
                let prev = std::mem::replace(&mut self.prev[out], Spans::empty(out_dims));
                self.restore(out, self.direct[i], &prev, &changed);
            }
            self.prev[out] = changed.clone();
            cur[out] = Some(changed);
        }
        self.stats = stats;
        let start = std::time::Instant::now();
        for j in 0..self.outputs_cm.len() {
            if self.direct.contains(&Some(j)) {
                continue;
            }
            let b = self.plan.outputs[j];
            let region = self.prev[b].union(&self.outputs_changed[j]);
            let mut data = std::mem::take(&mut self.outputs_cm[j]);
            let dst: &mut Vec<f32> = Arc::make_mut(&mut data);
            self.write_channel_major(b, &region, dst);
            self.outputs_cm[j] = data;
            self.outputs_changed[j] = self.prev[b].clone();
        }
        self.output_time = start.elapsed();
    }

    /// The plan's outputs after the last run, channel-major `[C, X, Y, Z]`, in plan order.
    pub fn outputs(&self) -> &[Arc<Vec<f32>>] {
        &self.outputs_cm
    }

    /// Wall time of the last run's output conversion.
    pub fn output_time(&self) -> std::time::Duration {
        self.output_time
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

    /// Runs op `i` over `compute`. With a field term (see [`PackedOp::field`]), the term is
    /// computed only inside `field_region`; elsewhere its background contribution, stored with
    /// the bias in the op's field buffer, stands in for it. `mode` picks what is written.
    fn run_conv(
        &mut self,
        i: usize,
        compute: &Spans,
        field_region: Option<&Spans>,
        mode: ConvMode,
    ) {
        let op = &self.ops[i];
        let out_info = self.plan.bufs[op.out];
        let dims = out_info.dims;
        let direct = match mode {
            ConvMode::Output => self.direct[i],
            ConvMode::Field => None,
        };
        let plane = dims.iter().product::<usize>();
        let out = match mode {
            ConvMode::Output if direct.is_some() => {
                let j = direct.expect("checked");
                Shared(Arc::make_mut(&mut self.outputs_cm[j]).as_mut_ptr())
            }
            ConvMode::Output => Shared(self.bufs[op.out].as_mut_ptr()),
            ConvMode::Field => Shared(
                self.fields[i]
                    .as_mut()
                    .expect("an op with a field term has a field buffer")
                    .as_mut_ptr(),
            ),
        };
        let field = match (mode, &self.fields[i], field_region) {
            (ConvMode::Output, Some(f), Some(r)) => Some((Shared(f.as_ptr() as *mut f32), r)),
            _ => None,
        };
        let res = match mode {
            ConvMode::Output => op
                .residual
                .map(|r| Shared(self.bufs[r].as_ptr() as *mut f32)),
            ConvMode::Field => None,
        };
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
        // Terms taking part: all of them, or only the field term when computing the field.
        let first_term = match mode {
            ConvMode::Output => 0,
            ConvMode::Field => op.terms.len() - 1,
        };
        let simd = self.simd;
        let relu = op.relu && mode == ConvMode::Output;
        let op_cout = out_info.channels;
        let work = |x: usize| {
            let (out, res, field) = (out, res, field);
            let mut segs: Vec<Seg> = Vec::with_capacity(op.terms.len() * 9);
            for y in 0..dims[1] {
                let Some((z0, z1)) = compute.col(x, y) else {
                    continue;
                };
                // Sub-ranges of z0..z1: (start, end, with the field term).
                let mut ranges = [(z0, z1, true); 3];
                let mut n_ranges = 1;
                if let Some((_, region)) = field {
                    let (t0, t1) = region.col(x, y).unwrap_or((z0, z0));
                    let (a, b) = (t0.clamp(z0, z1), t1.clamp(z0, z1).max(t0.clamp(z0, z1)));
                    ranges = [(z0, a, false), (a, b, true), (b, z1, false)];
                    n_ranges = 3;
                }
                for &(za, zb, with_field) in &ranges[..n_ranges] {
                    if za >= zb {
                        continue;
                    }
                    segs.clear();
                    let terms = op.terms.iter().zip(&inputs).skip(first_term);
                    for (ti, (t, &(ptr, info))) in terms.enumerate() {
                        let is_field_term = first_term + ti == op.terms.len() - 1;
                        if field.is_some() && is_field_term && !with_field {
                            continue;
                        }
                        push_segs(&mut segs, t, ptr, info, op.cp, x, y, za);
                    }
                    let o = voxel(dims, x as isize, y as isize, za as isize) * out_info.stride;
                    let (o_out, ostride, out_plane) = match direct {
                        Some(_) => ((x * dims[1] + y) * dims[2] + za, 1, plane),
                        None => (o, out_info.stride, 0),
                    };
                    let (bias, bias_stride) = match field {
                        Some((f, _)) if !with_field => {
                            (unsafe { f.0.add(o) as *const f32 }, out_info.stride)
                        }
                        _ => (op.bias.as_ptr(), 0),
                    };
                    let job = Job {
                        segs: &segs,
                        wstride: op.cp,
                        bias,
                        bias_stride,
                        res: res.map_or(std::ptr::null(), |r| unsafe { r.0.add(o) as *const f32 }),
                        out: unsafe { out.0.add(o_out) },
                        ostride,
                        out_plane,
                        out_channels: op_cout,
                        relu,
                    };
                    // SAFETY: segments, bias field, residual and output lie inside their padded
                    // buffers for za..zb (the halo covers the 3³ reads at the grid's faces);
                    // each x is written by one thread.
                    unsafe { kernels::run(simd, &job, zb - za) };
                }
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
                        bias_stride: 0,
                        res: res.map_or(std::ptr::null(), |r| unsafe { r.0.add(o) as *const f32 }),
                        out: unsafe { out.0.add(o) },
                        ostride: 2 * out_info.stride,
                        out_plane: 0,
                        out_channels: 0,
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

    /// Copies buffer `b` over `spans` into `dst`, a channel-major `[C, X, Y, Z]` grid.
    fn write_channel_major(&self, b: usize, spans: &Spans, dst: &mut [f32]) {
        let info = self.plan.bufs[b];
        let [nx, ny, nz] = info.dims;
        let plane = nx * ny * nz;
        let (c, stride) = (info.channels, info.stride);
        assert_eq!(dst.len(), c * plane, "channel-major buffer size");
        let dst = Shared(dst.as_mut_ptr());
        let src = &self.bufs[b];
        let work = |x: usize| {
            for y in 0..ny {
                let Some((lo, hi)) = spans.col(x, y) else {
                    continue;
                };
                let base = voxel(info.dims, x as isize, y as isize, 0) * stride;
                let col = (x * ny + y) * nz;
                assert!(base + hi * stride <= src.len());
                // Channel by channel: each channel's z-run is written contiguously (writing all
                // channels of one voxel at a time hits planes a power of two apart, which share
                // one L1 set).
                for ch in 0..c {
                    for z in lo..hi {
                        // SAFETY: voxel z of the column lies in `src` (asserted above); channel
                        // ch, voxel (x, y, z) of the `c × plane` destination; each x is written
                        // by one thread.
                        unsafe {
                            *dst.ptr().add(ch * plane + col + z) =
                                *src.as_ptr().add(base + z * stride + ch)
                        };
                    }
                }
            }
        };
        self.for_each_x(nx, work);
    }
}
