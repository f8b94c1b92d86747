//! Weight packing for the U-Net executor: each op's weights laid out as the kernel reads them
//! (segments of contiguous inputs × output channels padded to 8), and the segments one output
//! tile reads from a halo-padded channels-last buffer.

use super::kernels::Seg;
use super::plan::{BufInfo, TermKind, UnetPlan};

/// One input term of an op with its packed weights.
pub(super) struct PackedTerm {
    pub(super) input: usize,
    pub(super) kind: TermKind,
    /// Inner length per segment.
    pub(super) k: usize,
    /// `[segments][k][cp]`.
    pub(super) w: Vec<f32>,
    /// Multiply-adds per output voxel (per input voxel for `Up2`), real channels only.
    pub(super) macs: usize,
}

/// One fused op of the plan, packed for the kernel.
pub(super) struct PackedOp {
    pub(super) terms: Vec<PackedTerm>,
    /// Output channels padded to 8.
    pub(super) cp: usize,
    pub(super) bias: Vec<f32>,
    pub(super) out: usize,
    pub(super) residual: Option<usize>,
    pub(super) relu: bool,
    pub(super) transpose: bool,
    /// Whether the last term is a *field term*: the U-Net's skip connection from the encoder
    /// into a decoder convolution, whose input is background far from the surface while the
    /// up-sampled decoder input is not. Where the term's input window is all background, its
    /// contribution is the same as on the all-zero input: stored once (with the bias) in a
    /// field buffer and read instead of computed.
    pub(super) field: bool,
    pub(super) nodes: Vec<String>,
}

/// A raw pointer shared by the worker threads; each writes disjoint voxels.
#[derive(Clone, Copy)]
pub(super) struct Shared(pub(super) *mut f32);
// SAFETY: the executor hands each thread disjoint output columns; inputs are only read.
unsafe impl Send for Shared {}
unsafe impl Sync for Shared {}

impl Shared {
    /// The pointer (a method, so closures capture the whole `Shared`, which is `Send`).
    pub(super) fn ptr(self) -> *mut f32 {
        self.0
    }
}

/// Offset (in voxels) of `(x, y, z)` (each in `-1..=n`) in a halo-padded buffer of `dims`.
#[inline]
pub(super) fn voxel(dims: [usize; 3], x: isize, y: isize, z: isize) -> usize {
    let (py, pz) = (dims[1] as isize + 2, dims[2] as isize + 2);
    (((x + 1) * py + y + 1) * pz + z + 1) as usize
}

/// Length of a buffer with its one-voxel halo.
pub(super) fn padded_len(b: &BufInfo) -> usize {
    (b.dims[0] + 2) * (b.dims[1] + 2) * (b.dims[2] + 2) * b.stride
}

/// The weights of op `op_index` packed for the kernel (segments × inner length × channels
/// padded to 8).
pub(super) fn pack(plan: &UnetPlan, op_index: usize) -> PackedOp {
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
        field: op.terms.len() >= 2 && !op.is_transpose(),
        nodes: op.nodes.clone(),
    }
}

/// Appends the segments of term `t` for the outputs from `(x, y, z)` on.
#[allow(clippy::too_many_arguments)]
pub(super) fn push_segs(
    segs: &mut Vec<Seg>,
    t: &PackedTerm,
    ptr: Shared,
    info: BufInfo,
    cp: usize,
    x: usize,
    y: usize,
    z: usize,
) {
    let s = info.stride;
    let (xi, yi, zi) = (x as isize, y as isize, z as isize);
    // SAFETY (all `add`s): offsets of voxels inside the padded input buffer and of segments
    // inside the packed weights.
    match t.kind {
        TermKind::K3 => {
            for dx in 0..3 {
                for dy in 0..3 {
                    let v = voxel(info.dims, xi + dx - 1, yi + dy - 1, zi - 1);
                    segs.push(Seg {
                        a: unsafe { ptr.0.add(v * s) },
                        k: t.k,
                        tstride: s,
                        w: unsafe { t.w.as_ptr().add(((dx * 3 + dy) as usize) * t.k * cp) },
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
                        w: unsafe { t.w.as_ptr().add(((a * 2 + b) as usize) * t.k * cp) },
                    });
                }
            }
        }
        TermKind::Up2 => unreachable!("transposed terms run in run_transpose"),
    }
}
