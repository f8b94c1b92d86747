//! The native runtime (`runtime = "native"`): the learned backend's two graphs run by our own
//! kernels, with the weights read from the ONNX files themselves.
//!
//! * [`graph`]: the ONNX protobuf (tract-onnx's generated types) → nodes and decoded constants.
//! * [`plan`]: the U-Net as a handful of fused convolution passes (batch norm folded, residual
//!   additions, skip convolutions and ReLU in the kernels' epilogues, concatenations as split
//!   weights); a node outside the supported subset is refused at load, naming the node.
//! * [`kernels`]: one register-blocked kernel for every convolution and dense layer
//!   (channels-last grids, AVX2 + FMA through `pulp`, a scalar path elsewhere).
//! * [`spans`] and [`exec`]: the background skip — the input is zero in free space, so every
//!   layer equals its all-zero-input output (computed at load) wherever its receptive field
//!   sees only zeros; each layer computes just the column intervals that may differ.
//! * [`mlp`]: the MLP head as blocked matrix products (`matrixmultiply`) with the element-wise
//!   tail.
//!
//! Results equal the ONNX graph up to float rounding (tested against tract within 1e-4 on the
//! shipped model and the fixture model). Both graphs use one private thread pool.
pub mod exec;
pub mod graph;
pub mod kernels;
pub mod mlp;
mod pack;
pub mod plan;
pub mod spans;

use crate::learned::card::{ModelCard, ModelError, ModelFiles};
use crate::learned::decode::HeadOutputs;
use crate::learned::runtime::{
    append_mlp, expected_unet_names, unet_outputs, GraphRuntime, OutputTensor, UnetOutputs,
    LABEL_LOGITS, MLP_INPUT, MLP_OUTPUTS, UNET_INPUT,
};
use crate::onnx::{no_panic, resolve_threads, StringError};
use exec::{OpStats, UnetExec};
use graph::{Graph, Unsupported};
use kernels::Simd;
use mlp::{MlpPlan, Scratch};
use plan::UnetPlan;
use rayon::prelude::*;
use std::sync::Arc;

const RUNTIME: &str = "native";

fn load_err(graph: &'static str) -> impl Fn(Unsupported) -> ModelError {
    move |e| {
        if e.interface {
            ModelError::GraphInterface {
                graph,
                reason: e.reason,
            }
        } else {
            ModelError::Graph {
                graph,
                runtime: RUNTIME,
                source: Box::new(e),
            }
        }
    }
}

fn panic_err(graph: &'static str, load: bool) -> impl FnOnce(String) -> ModelError {
    move |m| {
        let source = Box::new(StringError(format!("native runtime panicked: {m}")));
        if load {
            ModelError::Graph {
                graph,
                runtime: RUNTIME,
                source,
            }
        } else {
            ModelError::Run {
                graph,
                runtime: RUNTIME,
                source,
            }
        }
    }
}

/// Plans `unet.onnx` bytes for the card's grid (what [`NativeRuntime::new`] does for the U-Net).
pub fn plan_unet(bytes: &[u8], card: &ModelCard) -> Result<UnetPlan, ModelError> {
    let d = card.dims();
    let graph = Graph::parse(bytes).map_err(load_err("unet"))?;
    UnetPlan::build(
        &graph,
        UNET_INPUT,
        &[1, card.grid.input_channels as usize, d[0], d[1], d[2]],
        &expected_unet_names(card),
    )
    .map_err(load_err("unet"))
}

/// Plans `mlp.onnx` bytes for the card's feature size.
pub fn plan_mlp(bytes: &[u8], card: &ModelCard) -> Result<MlpPlan, ModelError> {
    let graph = Graph::parse(bytes).map_err(load_err("mlp"))?;
    MlpPlan::build(&graph, MLP_INPUT, card.feature_dim(), &MLP_OUTPUTS).map_err(load_err("mlp"))
}

/// The native runtime of one model (see the module docs).
pub struct NativeRuntime {
    unet: UnetExec,
    mlp: MlpPlan,
    card: ModelCard,
    simd: Simd,
    pool: Option<Arc<rayon::ThreadPool>>,
}

impl std::fmt::Debug for NativeRuntime {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("NativeRuntime")
            .field("model", &self.card.name)
            .field("simd", &self.simd.name())
            .finish_non_exhaustive()
    }
}

impl NativeRuntime {
    /// Plans both graphs of `files` and computes the U-Net's background, on `threads` threads
    /// (0 = all cores).
    pub fn new(files: &ModelFiles, threads: usize) -> Result<Self, ModelError> {
        Self::with_simd(files, threads, Simd::detect())
    }

    /// [`NativeRuntime::new`] with the kernels forced to `simd` (tests of the scalar path).
    pub fn with_simd(files: &ModelFiles, threads: usize, simd: Simd) -> Result<Self, ModelError> {
        let card = files.card.clone();
        let threads = resolve_threads(threads);
        let pool = if threads > 1 {
            Some(Arc::new(
                rayon::ThreadPoolBuilder::new()
                    .num_threads(threads)
                    .thread_name(|i| format!("psgrasp-native-{i}"))
                    .build()
                    .map_err(|e| ModelError::RuntimeUnavailable {
                        runtime: RUNTIME,
                        reason: format!("cannot start {threads} threads: {e}"),
                    })?,
            ))
        } else {
            None
        };
        let plan = no_panic(
            || plan_unet(&files.unet_onnx, &card),
            panic_err("unet", true),
        )?;
        let mlp = no_panic(|| plan_mlp(&files.mlp_onnx, &card), panic_err("mlp", true))?;
        let unet = no_panic(
            || Ok(UnetExec::new(plan, pool.clone(), simd)),
            panic_err("unet", true),
        )?;
        Ok(Self {
            unet,
            mlp,
            card,
            simd,
            pool,
        })
    }

    /// Per-op figures of the last U-Net run (changed share, multiply-adds computed and dense).
    pub fn unet_stats(&self) -> &[OpStats] {
        self.unet.stats()
    }

    /// The runtime's thread pool (none with one thread), for work around it on the same threads.
    pub fn thread_pool(&self) -> Option<Arc<rayon::ThreadPool>> {
        self.pool.clone()
    }

    /// Approximate mode of the U-Net ([`UnetExec::set_band`]): 0 (default) exact; `band` > 0
    /// computes only within `band` voxels of the non-zero input.
    pub fn set_band(&mut self, band: usize) {
        self.unet.set_band(band);
    }

    /// Wall times of the last U-Net run outside the ops: input conversion, output conversion.
    pub fn unet_io_times(&self) -> (std::time::Duration, std::time::Duration) {
        (self.unet.input_time(), self.unet.output_time())
    }

    /// Turns the U-Net's background skip on (default) or off (for measurements).
    pub fn set_background_skip(&mut self, on: bool) {
        self.unet.set_background_skip(on);
    }

    /// Multiply-adds per MLP row.
    pub fn mlp_macs_per_row(&self) -> usize {
        self.mlp.macs_per_row()
    }

    /// The kernels in use (`"avx2+fma"` or `"scalar"`).
    pub fn simd_name(&self) -> &'static str {
        self.simd.name()
    }

    /// The last run's outputs as tensors (shared with the runtime, no copy).
    fn unet_tensors(&self) -> Result<Vec<OutputTensor>, ModelError> {
        let names = expected_unet_names(&self.card);
        let plan = self.unet.plan();
        let mut tensors = Vec::with_capacity(plan.outputs.len());
        for ((&b, name), data) in plan.outputs.iter().zip(&names).zip(self.unet.outputs()) {
            let info = plan.bufs[b];
            let shape = vec![1, info.channels, info.dims[0], info.dims[1], info.dims[2]];
            tensors.push(OutputTensor::from_shared(
                shape,
                data.clone(),
                "unet",
                name,
            )?);
        }
        Ok(tensors)
    }
}

impl GraphRuntime for NativeRuntime {
    fn name(&self) -> &'static str {
        RUNTIME
    }

    fn as_native(&mut self) -> Option<&mut NativeRuntime> {
        Some(self)
    }

    fn run_unet(&mut self, normals: &[f32]) -> Result<UnetOutputs, ModelError> {
        let info = self.unet.plan().bufs[0];
        let expected = info.channels * info.dims.iter().product::<usize>();
        if normals.len() != expected {
            return Err(ModelError::GraphInterface {
                graph: "unet",
                reason: format!(
                    "input `{UNET_INPUT}` of {} values, expected {expected}",
                    normals.len()
                ),
            });
        }
        let tensors = no_panic(
            || {
                self.unet.run(normals);
                self.unet_tensors()
            },
            panic_err("unet", false),
        )?;
        debug_assert_eq!(expected_unet_names(&self.card)[0], LABEL_LOGITS);
        unet_outputs(&self.card, tensors)
    }

    fn run_mlp(
        &mut self,
        features: &[f32],
        n: usize,
        out: &mut HeadOutputs,
    ) -> Result<(), ModelError> {
        let f = self.mlp.in_dim();
        if features.len() != n * f {
            return Err(ModelError::GraphInterface {
                graph: "mlp",
                reason: format!("input of {} values for {n} rows", features.len()),
            });
        }
        let mlp = &self.mlp;
        let cols: Vec<usize> = (0..MLP_OUTPUTS.len()).map(|i| mlp.output_cols(i)).collect();
        let mut outputs: Vec<Vec<f32>> = cols.iter().map(|&c| vec![0.0; n * c]).collect();
        no_panic(
            || {
                let block = mlp::BLOCK_ROWS;
                // Each block's rows of every output, in block order.
                let mut parts: Vec<Vec<&mut [f32]>> =
                    (0..n.div_ceil(block)).map(|_| Vec::new()).collect();
                for (o, &c) in outputs.iter_mut().zip(&cols) {
                    for (p, chunk) in parts.iter_mut().zip(o.chunks_mut(block * c.max(1))) {
                        p.push(chunk);
                    }
                }
                let work = |s: &mut Scratch, (i, mut outs): (usize, Vec<&mut [f32]>)| {
                    let rows = block.min(n - i * block);
                    let x = &features[i * block * f..(i * block + rows) * f];
                    mlp.run_block(x, rows, s, &mut outs);
                };
                match &self.pool {
                    Some(pool) => pool.install(|| {
                        parts
                            .into_par_iter()
                            .enumerate()
                            .for_each_init(Scratch::default, work)
                    }),
                    None => {
                        let mut s = Scratch::default();
                        parts.into_iter().enumerate().for_each(|p| work(&mut s, p));
                    }
                }
                Ok(())
            },
            panic_err("mlp", false),
        )?;
        let shapes: Vec<Vec<usize>> = (0..MLP_OUTPUTS.len())
            .map(|i| mlp.output_shape(i, n))
            .collect();
        let data: [&[f32]; 5] = std::array::from_fn(|i| outputs[i].as_slice());
        let shapes: [&[usize]; 5] = std::array::from_fn(|i| shapes[i].as_slice());
        append_mlp(data, shapes, n, out)
    }
}
