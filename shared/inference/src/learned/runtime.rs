//! The learned backend's graph runtimes: `unet.onnx` and `mlp.onnx` of one checked model directory
//! ([`ModelFiles`]) on tract (default) or ONNX Runtime (feature `ort`).
//!
//! A [`GraphRuntime`] runs `unet.onnx` on the normal grid and `mlp.onnx` on a `[N, F]` feature
//! matrix. Graph inputs and outputs are found by their contract names and their shapes are checked
//! at load (as far as the runtime reports them) and on every run. The engines themselves — the
//! single-input graph wrapper that also runs the U-Net and the VGN network, tract's loader and
//! thread pool, ONNX Runtime's sessions — are in [`crate::onnx`]; [`RuntimeKind`],
//! [`OutputTensor`] and [`resolve_threads`] are re-exported here.
use super::card::{ModelCard, ModelError, ModelFiles};
use super::decode::HeadOutputs;
use crate::onnx::tract::{load_tract_graph, run_tract, tract_executor, tract_load_panic};
use crate::onnx::{no_panic, FixedGraph, GraphSpec};
pub use crate::onnx::{resolve_threads, OutputTensor, RuntimeKind};
use std::sync::Arc;
use tract_onnx::prelude::*;

/// Input name of `unet.onnx`.
pub const UNET_INPUT: &str = "normal_grid";
/// Output name of the label logits in `unet.onnx`.
pub const LABEL_LOGITS: &str = "label_logits";
/// Input name of `mlp.onnx`.
pub const MLP_INPUT: &str = "features";
/// Output names of `mlp.onnx`, in contract order.
pub const MLP_OUTPUTS: [&str; 5] = [
    "baseline",
    "kappa",
    "width",
    "quality_prior",
    "collision_prior",
];

/// The outputs of `unet.onnx` for one grid.
#[derive(Debug)]
pub struct UnetOutputs {
    /// `[1, 3, X, Y, Z]` label logits.
    pub label_logits: OutputTensor,
    /// `enc0..enc{L-1}`, `[1, C_l, X/2^l, Y/2^l, Z/2^l]`.
    pub features: Vec<OutputTensor>,
}

/// A runtime that executes the two graphs of one model.
pub trait GraphRuntime: Send {
    /// `"tract"`, `"ort"` or `"native"`.
    fn name(&self) -> &'static str;
    /// Runs `unet.onnx` on `normals` (`[3, X, Y, Z]` channel-major, the fused grid's buffer).
    fn run_unet(&mut self, normals: &[f32]) -> Result<UnetOutputs, ModelError>;
    /// The native runtime, if this is it (default: none).
    fn as_native(&mut self) -> Option<&mut crate::native::NativeRuntime> {
        None
    }
    /// Runs `mlp.onnx` on `features` (`[n, F]` row-major) and appends the `n` rows of outputs to
    /// `out`.
    fn run_mlp(
        &mut self,
        features: &[f32],
        n: usize,
        out: &mut HeadOutputs,
    ) -> Result<(), ModelError>;
}

/// Expected shapes of the U-Net outputs: label logits then the encoder levels.
pub fn expected_unet_shapes(card: &ModelCard) -> Vec<Vec<usize>> {
    let mut v = vec![[vec![1, 3], card.dims().to_vec()].concat()];
    for (l, &c) in card.unet.channels.iter().enumerate() {
        v.push([vec![1, c as usize], card.level_dims(l).to_vec()].concat());
    }
    v
}

/// Expected output names of the U-Net: `label_logits`, then `unet.feature_outputs`.
pub(crate) fn expected_unet_names(card: &ModelCard) -> Vec<String> {
    std::iter::once(LABEL_LOGITS.to_string())
        .chain(card.unet.feature_outputs.iter().cloned())
        .collect()
}

/// Splits the U-Net outputs (in [`expected_unet_names`] order) and checks their shapes.
pub(crate) fn unet_outputs(
    card: &ModelCard,
    tensors: Vec<OutputTensor>,
) -> Result<UnetOutputs, ModelError> {
    let mut it = tensors.into_iter();
    let label_logits = it.next().ok_or_else(|| ModelError::GraphInterface {
        graph: "unet",
        reason: "no outputs".into(),
    })?;
    let out = UnetOutputs {
        label_logits,
        features: it.collect(),
    };
    check_unet_outputs(card, &out)?;
    Ok(out)
}

fn check_unet_outputs(card: &ModelCard, out: &UnetOutputs) -> Result<(), ModelError> {
    let shapes = expected_unet_shapes(card);
    let names = expected_unet_names(card);
    let got = std::iter::once(&out.label_logits).chain(out.features.iter());
    if out.features.len() + 1 != shapes.len() {
        return Err(ModelError::GraphInterface {
            graph: "unet",
            reason: format!(
                "{} feature outputs, the card has {}",
                out.features.len(),
                shapes.len() - 1
            ),
        });
    }
    for ((t, s), name) in got.zip(&shapes).zip(&names) {
        if t.shape() != s.as_slice() {
            return Err(ModelError::GraphInterface {
                graph: "unet",
                reason: format!("output `{name}` has shape {:?}, expected {s:?}", t.shape()),
            });
        }
    }
    Ok(())
}

/// Appends one MLP batch (`outputs` in [`MLP_OUTPUTS`] order) to `out`, checking the shapes.
pub(crate) fn append_mlp(
    outputs: [&[f32]; 5],
    shapes: [&[usize]; 5],
    n: usize,
    out: &mut HeadOutputs,
) -> Result<(), ModelError> {
    let widths = [3usize, 1, 1, 1, psgrasp_geometry::N_APPROACHES];
    for i in 0..5 {
        let numel: usize = shapes[i].iter().product();
        let ok = shapes[i].first() == Some(&n) && numel == n * widths[i];
        if !ok {
            return Err(ModelError::GraphInterface {
                graph: "mlp",
                reason: format!(
                    "output `{}` has shape {:?}, expected [{n}{}]",
                    MLP_OUTPUTS[i],
                    shapes[i],
                    if widths[i] > 1 {
                        format!(", {}", widths[i])
                    } else {
                        String::new()
                    }
                ),
            });
        }
    }
    out.baseline.extend_from_slice(outputs[0]);
    out.kappa.extend_from_slice(outputs[1]);
    out.width.extend_from_slice(outputs[2]);
    out.quality_prior.extend_from_slice(outputs[3]);
    out.collision_prior.extend_from_slice(outputs[4]);
    Ok(())
}

/// The tract runtime: both graphs made runnable once at load (static 64³ U-Net input, symbolic
/// MLP batch), matrix products on a private thread pool.
pub struct TractRuntime {
    unet: FixedGraph,
    mlp: Arc<TypedRunnableModel>,
    /// Model output index of each of [`MLP_OUTPUTS`].
    mlp_outputs: [usize; 5],
    feature_dim: usize,
    card: ModelCard,
    executor: tract_linalg::multithread::Executor,
}

impl std::fmt::Debug for TractRuntime {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("TractRuntime")
            .field("model", &self.card.name)
            .finish_non_exhaustive()
    }
}

impl TractRuntime {
    /// Parses and optimises both graphs of `files` for `threads` worker threads (0 = all cores).
    pub fn new(files: &ModelFiles, threads: usize) -> Result<Self, ModelError> {
        let card = files.card.clone();
        let executor = tract_executor(threads)?;
        let unet = FixedGraph::tract(&files.unet_onnx, unet_spec(&card), executor.clone())?;
        let feature_dim = card.feature_dim();
        let mlp_names: Vec<String> = MLP_OUTPUTS.iter().map(|s| s.to_string()).collect();
        let (mlp, mlp_index) = no_panic(
            || {
                load_tract_graph(
                    &files.mlp_onnx,
                    "mlp",
                    MLP_INPUT,
                    |m| {
                        let n = m.sym("N");
                        f32::fact([n.to_dim(), feature_dim.to_dim()]).into()
                    },
                    &mlp_names,
                )
            },
            tract_load_panic("mlp"),
        )?;
        Ok(Self {
            unet,
            mlp,
            mlp_outputs: [
                mlp_index[0],
                mlp_index[1],
                mlp_index[2],
                mlp_index[3],
                mlp_index[4],
            ],
            feature_dim,
            card,
            executor,
        })
    }
}

/// The U-Net's interface: input `[1, 3, X, Y, Z]`, outputs in [`expected_unet_names`] order.
fn unet_spec(card: &ModelCard) -> GraphSpec {
    let d = card.dims();
    GraphSpec {
        graph: "unet",
        input_name: UNET_INPUT,
        input_shape: vec![1, 3, d[0], d[1], d[2]],
        output_names: expected_unet_names(card),
    }
}

impl GraphRuntime for TractRuntime {
    fn name(&self) -> &'static str {
        "tract"
    }

    fn run_unet(&mut self, normals: &[f32]) -> Result<UnetOutputs, ModelError> {
        unet_outputs(&self.card, self.unet.run(normals)?)
    }

    fn run_mlp(
        &mut self,
        features: &[f32],
        n: usize,
        out: &mut HeadOutputs,
    ) -> Result<(), ModelError> {
        let input = Tensor::from_shape(&[n, self.feature_dim], features).map_err(|e| {
            ModelError::GraphInterface {
                graph: "mlp",
                reason: format!("input of {} values for {n} rows: {e}", features.len()),
            }
        })?;
        let outputs = run_tract(&self.mlp, &self.executor, "mlp", input)?;
        let mut data: [&[f32]; 5] = [&[]; 5];
        let mut shapes: [&[usize]; 5] = [&[]; 5];
        let mut tensors = Vec::with_capacity(5);
        for (i, &ix) in self.mlp_outputs.iter().enumerate() {
            let v = outputs
                .get(ix)
                .cloned()
                .ok_or_else(|| ModelError::GraphInterface {
                    graph: "mlp",
                    reason: format!("output `{}` missing", MLP_OUTPUTS[i]),
                })?;
            tensors.push(OutputTensor::from_tract(v, "mlp", MLP_OUTPUTS[i])?);
        }
        for (i, t) in tensors.iter().enumerate() {
            data[i] = t.data();
            shapes[i] = t.shape();
        }
        append_mlp(data, shapes, n, out)
    }
}

#[cfg(feature = "ort")]
pub use self::ort_runtime::OrtRuntime;

#[cfg(feature = "ort")]
mod ort_runtime {
    use super::*;
    use crate::onnx::ort::{check_names, environment, ort_run_err, session};
    use ort::session::Session;
    use ort::value::TensorRef;
    use std::path::Path;

    /// The ONNX Runtime runtime: one session per graph with `threads` intra-op threads.
    pub struct OrtRuntime {
        unet: FixedGraph,
        mlp: Session,
        card: ModelCard,
        feature_dim: usize,
    }

    impl std::fmt::Debug for OrtRuntime {
        fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
            f.debug_struct("OrtRuntime")
                .field("model", &self.card.name)
                .finish_non_exhaustive()
        }
    }

    impl OrtRuntime {
        /// Loads ONNX Runtime (from `library` or `$ORT_DYLIB_PATH`) and creates both sessions.
        pub fn new(
            files: &ModelFiles,
            library: Option<&Path>,
            threads: usize,
        ) -> Result<Self, ModelError> {
            let env = environment(library)?;
            let unet = FixedGraph::ort(&env, &files.unet_onnx, unet_spec(&files.card), threads)?;
            let mlp = session(&env, &files.mlp_onnx, "mlp", resolve_threads(threads))?;
            let mlp_names: Vec<String> = MLP_OUTPUTS.iter().map(|s| s.to_string()).collect();
            check_names(&mlp, "mlp", MLP_INPUT, &mlp_names)?;
            Ok(Self {
                unet,
                mlp,
                feature_dim: files.card.feature_dim(),
                card: files.card.clone(),
            })
        }
    }

    impl GraphRuntime for OrtRuntime {
        fn name(&self) -> &'static str {
            "ort"
        }

        fn run_unet(&mut self, normals: &[f32]) -> Result<UnetOutputs, ModelError> {
            unet_outputs(&self.card, self.unet.run(normals)?)
        }

        fn run_mlp(
            &mut self,
            features: &[f32],
            n: usize,
            out: &mut HeadOutputs,
        ) -> Result<(), ModelError> {
            if features.len() != n * self.feature_dim {
                return Err(ModelError::GraphInterface {
                    graph: "mlp",
                    reason: format!("input of {} values for {n} rows", features.len()),
                });
            }
            let input = TensorRef::from_array_view(([n as i64, self.feature_dim as i64], features))
                .map_err(ort_run_err("mlp"))?;
            let mut outputs = self
                .mlp
                .run(ort::inputs![MLP_INPUT => input])
                .map_err(ort_run_err("mlp"))?;
            let mut tensors = Vec::with_capacity(5);
            for name in MLP_OUTPUTS {
                let v = outputs
                    .remove(name)
                    .ok_or_else(|| ModelError::GraphInterface {
                        graph: "mlp",
                        reason: format!("output `{name}` missing"),
                    })?;
                tensors.push(OutputTensor::from_ort(v, "mlp", name)?);
            }
            drop(outputs);
            let data: [&[f32]; 5] = std::array::from_fn(|i| tensors[i].data());
            let shapes: [&[usize]; 5] = std::array::from_fn(|i| tensors[i].shape());
            append_mlp(data, shapes, n, out)
        }
    }
}
