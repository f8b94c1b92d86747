//! Graph runtimes: tract (pure Rust, default) and ONNX Runtime (feature `ort`).
//!
//! A [`GraphRuntime`] runs the two graphs of a checked model directory ([`ModelFiles`]):
//! `unet.onnx` on the normal grid and `mlp.onnx` on a `[N, F]` feature matrix. Graph inputs and
//! outputs are found by their contract names and their shapes are checked at load (as far as
//! the runtime reports them) and on every run. The single-input graph wrapper used for the U-Net
//! also runs the VGN backend's network ([`crate::vgn`]).
use super::card::{ModelCard, ModelError, ModelFiles};
use super::decode::HeadOutputs;
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

/// Which graph runtime to use.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum RuntimeKind {
    /// tract (pure Rust, always available).
    #[default]
    Tract,
    /// ONNX Runtime through `ort` (needs the `ort` cargo feature and a `libonnxruntime.so`).
    Ort,
}

impl RuntimeKind {
    /// `"tract"` or `"ort"`.
    pub fn name(self) -> &'static str {
        match self {
            Self::Tract => "tract",
            Self::Ort => "ort",
        }
    }
}

/// A float tensor produced by a runtime, kept in the runtime's own storage (no copy).
pub struct OutputTensor {
    shape: Vec<usize>,
    storage: Storage,
}

enum Storage {
    Tract(TValue),
    #[cfg(feature = "ort")]
    Ort(ort::value::DynValue),
}

impl std::fmt::Debug for OutputTensor {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("OutputTensor")
            .field("shape", &self.shape)
            .finish_non_exhaustive()
    }
}

impl OutputTensor {
    fn from_tract(value: TValue, graph: &'static str, name: &str) -> Result<Self, ModelError> {
        let shape = value.shape().to_vec();
        let t = Self {
            shape,
            storage: Storage::Tract(value),
        };
        t.checked_data(graph, name)?;
        Ok(t)
    }

    #[cfg(feature = "ort")]
    fn from_ort(
        value: ort::value::DynValue,
        graph: &'static str,
        name: &str,
    ) -> Result<Self, ModelError> {
        let shape = value
            .try_extract_tensor::<f32>()
            .map_err(|e| ModelError::GraphInterface {
                graph,
                reason: format!("output `{name}` is not an f32 tensor: {e}"),
            })?
            .0
            .iter()
            .map(|&d| d.max(0) as usize)
            .collect();
        let t = Self {
            shape,
            storage: Storage::Ort(value),
        };
        t.checked_data(graph, name)?;
        Ok(t)
    }

    fn checked_data(&self, graph: &'static str, name: &str) -> Result<&[f32], ModelError> {
        let data: Result<&[f32], String> = match &self.storage {
            Storage::Tract(v) => v
                .try_as_plain_ram()
                .and_then(|p| p.as_slice::<f32>())
                .map_err(|e| e.to_string()),
            #[cfg(feature = "ort")]
            Storage::Ort(v) => v
                .try_extract_tensor::<f32>()
                .map(|(_, d)| d)
                .map_err(|e| e.to_string()),
        };
        let data = data.map_err(|reason| ModelError::GraphInterface {
            graph,
            reason: format!("output `{name}` is not a dense f32 tensor: {reason}"),
        })?;
        if data.len() != self.shape.iter().product::<usize>() {
            return Err(ModelError::GraphInterface {
                graph,
                reason: format!(
                    "output `{name}` has {} values for shape {:?}",
                    data.len(),
                    self.shape
                ),
            });
        }
        Ok(data)
    }

    /// Shape of the tensor.
    pub fn shape(&self) -> &[usize] {
        &self.shape
    }

    /// The values, row-major. (Checked at construction; empty only if the runtime's storage
    /// changed underneath, which none does.)
    pub fn data(&self) -> &[f32] {
        self.checked_data("unet", "").unwrap_or(&[])
    }
}

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
    /// `"tract"` or `"ort"`.
    fn name(&self) -> &'static str;
    /// Runs `unet.onnx` on `normals` (`[3, X, Y, Z]` channel-major, the fused grid's buffer).
    fn run_unet(&mut self, normals: &[f32]) -> Result<UnetOutputs, ModelError>;
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
fn expected_unet_names(card: &ModelCard) -> Vec<String> {
    std::iter::once(LABEL_LOGITS.to_string())
        .chain(card.unet.feature_outputs.iter().cloned())
        .collect()
}

/// Splits the U-Net outputs (in [`expected_unet_names`] order) and checks their shapes.
fn unet_outputs(card: &ModelCard, tensors: Vec<OutputTensor>) -> Result<UnetOutputs, ModelError> {
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
fn append_mlp(
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

/// Resolves the worker thread count: 0 → the machine's available parallelism.
pub fn resolve_threads(threads: usize) -> usize {
    if threads > 0 {
        threads
    } else {
        std::thread::available_parallelism()
            .map(|n| n.get())
            .unwrap_or(1)
    }
}

fn panic_message(p: Box<dyn std::any::Any + Send>) -> String {
    p.downcast_ref::<&str>()
        .map(|s| s.to_string())
        .or_else(|| p.downcast_ref::<String>().cloned())
        .unwrap_or_else(|| "unknown panic".into())
}

/// Runs `f`, turning a panic inside a runtime into an error (a corrupt graph must never abort
/// the process).
fn no_panic<T>(
    f: impl FnOnce() -> Result<T, ModelError>,
    on_panic: impl FnOnce(String) -> ModelError,
) -> Result<T, ModelError> {
    std::panic::catch_unwind(std::panic::AssertUnwindSafe(f))
        .unwrap_or_else(|p| Err(on_panic(panic_message(p))))
}

fn tract_err(graph: &'static str) -> impl Fn(TractError) -> ModelError {
    move |e| ModelError::Graph {
        graph,
        runtime: "tract",
        source: e.into(),
    }
}

/// The error of a graph whose loading panicked inside tract.
fn tract_load_panic(graph: &'static str) -> impl FnOnce(String) -> ModelError {
    move |m| ModelError::Graph {
        graph,
        runtime: "tract",
        source: Box::new(StringError(format!("tract panicked: {m}"))),
    }
}

#[derive(Debug)]
struct StringError(String);
impl std::fmt::Display for StringError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(&self.0)
    }
}
impl std::error::Error for StringError {}

/// The executor of tract's matrix products: the calling thread for `threads` = 1, else a private
/// pool of `threads` threads (0 = all cores).
fn tract_executor(threads: usize) -> Result<tract_linalg::multithread::Executor, ModelError> {
    let threads = resolve_threads(threads);
    if threads <= 1 {
        return Ok(tract_linalg::multithread::Executor::SingleThread);
    }
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .thread_name(|i| format!("psgrasp-tract-{i}"))
        .build()
        .map_err(|e| ModelError::RuntimeUnavailable {
            runtime: "tract",
            reason: format!("cannot start {threads} threads: {e}"),
        })?;
    Ok(tract_linalg::multithread::Executor::MultiThread(Arc::new(
        pool,
    )))
}

/// Runs a tract plan on `executor`, turning errors and panics into [`ModelError::Run`].
fn run_tract(
    plan: &Arc<TypedRunnableModel>,
    executor: &tract_linalg::multithread::Executor,
    graph: &'static str,
    input: Tensor,
) -> Result<TVec<TValue>, ModelError> {
    let executor = executor.clone();
    no_panic(
        || {
            tract_linalg::multithread::multithread_tract_scope(executor, || {
                plan.run(tvec!(input.into_tvalue()))
            })
            .map_err(|e| ModelError::Run {
                graph,
                runtime: "tract",
                source: e.into(),
            })
        },
        |m| ModelError::Run {
            graph,
            runtime: "tract",
            source: Box::new(StringError(format!("tract panicked: {m}"))),
        },
    )
}

/// The interface of a graph with one fixed-shape f32 input and named f32 outputs.
#[derive(Debug, Clone)]
pub(crate) struct GraphSpec {
    /// Graph name for errors (`"unet"`, `"vgn"`).
    pub graph: &'static str,
    /// Name of the single input.
    pub input_name: &'static str,
    /// Shape of the input.
    pub input_shape: Vec<usize>,
    /// Outputs to take, in the order [`FixedGraph::run`] returns them.
    pub output_names: Vec<String>,
}

/// A graph with one fixed-shape f32 input and named f32 outputs (the U-Net, the VGN network),
/// on tract or ONNX Runtime. The input name is checked at load, the outputs are found by name.
pub(crate) struct FixedGraph {
    spec: GraphSpec,
    engine: Engine,
}

enum Engine {
    Tract {
        plan: Arc<TypedRunnableModel>,
        /// Model output index of each of `spec.output_names`.
        outputs: Vec<usize>,
        executor: tract_linalg::multithread::Executor,
    },
    #[cfg(feature = "ort")]
    Ort(ort::session::Session),
}

impl FixedGraph {
    /// Loads `bytes` on the runtime `kind` (`ort_library` and `threads` as in the configs).
    pub(crate) fn load(
        kind: RuntimeKind,
        bytes: &[u8],
        spec: GraphSpec,
        ort_library: Option<&std::path::Path>,
        threads: usize,
    ) -> Result<Self, ModelError> {
        match kind {
            RuntimeKind::Tract => Self::tract(bytes, spec, tract_executor(threads)?),
            #[cfg(feature = "ort")]
            RuntimeKind::Ort => {
                let env = ort_runtime::environment(ort_library)?;
                Self::ort(&env, bytes, spec, threads)
            }
            #[cfg(not(feature = "ort"))]
            RuntimeKind::Ort => {
                let _ = (ort_library, spec);
                Err(ort_not_built())
            }
        }
    }

    /// Loads `bytes` with tract, optimised for the fixed input shape.
    fn tract(
        bytes: &[u8],
        spec: GraphSpec,
        executor: tract_linalg::multithread::Executor,
    ) -> Result<Self, ModelError> {
        let (plan, outputs) = no_panic(
            || {
                load_tract_graph(
                    bytes,
                    spec.graph,
                    spec.input_name,
                    |_| f32::fact(&spec.input_shape).into(),
                    &spec.output_names,
                )
            },
            tract_load_panic(spec.graph),
        )?;
        Ok(Self {
            spec,
            engine: Engine::Tract {
                plan,
                outputs,
                executor,
            },
        })
    }

    /// The runtime's name (`"tract"` or `"ort"`).
    pub(crate) fn runtime_name(&self) -> &'static str {
        match self.engine {
            Engine::Tract { .. } => "tract",
            #[cfg(feature = "ort")]
            Engine::Ort(_) => "ort",
        }
    }

    /// Runs the graph on `input` (the fixed shape, row-major); the outputs come in the order
    /// of the names given at load, their shapes unchecked.
    pub(crate) fn run(&mut self, input: &[f32]) -> Result<Vec<OutputTensor>, ModelError> {
        let spec = &self.spec;
        let graph = spec.graph;
        if input.len() != spec.input_shape.iter().product::<usize>() {
            return Err(ModelError::GraphInterface {
                graph,
                reason: format!(
                    "input of {} values for shape {:?}",
                    input.len(),
                    spec.input_shape
                ),
            });
        }
        match &mut self.engine {
            Engine::Tract {
                plan,
                outputs,
                executor,
            } => {
                let tensor = Tensor::from_shape(&spec.input_shape, input).map_err(|e| {
                    ModelError::GraphInterface {
                        graph,
                        reason: format!("input of {} values: {e}", input.len()),
                    }
                })?;
                let values = run_tract(plan, executor, graph, tensor)?;
                let mut taken: Vec<Option<TValue>> = values.into_iter().map(Some).collect();
                let mut tensors = Vec::with_capacity(spec.output_names.len());
                for (name, &ix) in spec.output_names.iter().zip(outputs.iter()) {
                    let v = taken.get_mut(ix).and_then(Option::take).ok_or_else(|| {
                        ModelError::GraphInterface {
                            graph,
                            reason: format!("output `{name}` missing"),
                        }
                    })?;
                    tensors.push(OutputTensor::from_tract(v, graph, name)?);
                }
                Ok(tensors)
            }
            #[cfg(feature = "ort")]
            Engine::Ort(session) => ort_runtime::run_fixed(session, spec, input),
        }
    }
}

/// The error for `runtime = "ort"` in a build without the `ort` feature.
#[cfg(not(feature = "ort"))]
pub(crate) fn ort_not_built() -> ModelError {
    ModelError::RuntimeUnavailable {
        runtime: "ort",
        reason: "this build has no ONNX Runtime support (cargo feature `ort`)".into(),
    }
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

/// Loads one ONNX graph with tract, checks its single input's name, finds the named outputs and
/// optimises it for `input_fact`.
fn load_tract_graph(
    bytes: &[u8],
    graph: &'static str,
    input_name: &str,
    input_fact: impl FnOnce(&InferenceModel) -> InferenceFact,
    output_names: &[String],
) -> Result<(Arc<TypedRunnableModel>, Vec<usize>), ModelError> {
    let err = tract_err(graph);
    let model = tract_onnx::onnx()
        .model_for_read(&mut &bytes[..])
        .map_err(&err)?;
    let inputs = model.input_outlets().map_err(&err)?;
    if inputs.len() != 1 || model.node(inputs[0].node).name != input_name {
        let names: Vec<&str> = inputs
            .iter()
            .map(|o| model.node(o.node).name.as_str())
            .collect();
        return Err(ModelError::GraphInterface {
            graph,
            reason: format!("inputs are {names:?}, expected [{input_name:?}]"),
        });
    }
    let outlets = model.output_outlets().map_err(&err)?.to_vec();
    let labels: Vec<String> = outlets
        .iter()
        .map(|o| model.outlet_label(*o).unwrap_or_default().to_string())
        .collect();
    let mut index = Vec::with_capacity(output_names.len());
    for name in output_names {
        match labels.iter().position(|l| l == name) {
            Some(i) => index.push(i),
            None => {
                return Err(ModelError::GraphInterface {
                    graph,
                    reason: format!("no output named `{name}` (outputs: {labels:?})"),
                })
            }
        }
    }
    let fact = input_fact(&model);
    let model = model
        .with_input_fact(0, fact)
        .map_err(&err)?
        .into_optimized()
        .map_err(&err)?
        .into_runnable()
        .map_err(&err)?;
    Ok((model, index))
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
    use ort::session::Session;
    use ort::value::TensorRef;
    use std::path::{Path, PathBuf};
    use std::sync::Mutex;

    /// Environment variable naming `libonnxruntime.so` when the config names none.
    pub const ORT_DYLIB_ENV: &str = "ORT_DYLIB_PATH";

    /// The library ONNX Runtime was loaded from and its environment (one per process).
    static LOADED: Mutex<Option<(PathBuf, ort::environment::Environment)>> = Mutex::new(None);

    fn unavailable(reason: impl Into<String>) -> ModelError {
        ModelError::RuntimeUnavailable {
            runtime: "ort",
            reason: reason.into(),
        }
    }

    /// Loads `libonnxruntime` from `library` (or `$ORT_DYLIB_PATH`) once per process and returns
    /// the process's ONNX Runtime environment.
    pub(super) fn environment(
        library: Option<&Path>,
    ) -> Result<ort::environment::Environment, ModelError> {
        let path = match library {
            Some(p) => p.to_owned(),
            None => std::env::var_os(ORT_DYLIB_ENV)
                .map(PathBuf::from)
                .ok_or_else(|| {
                    unavailable(format!(
                        "no ONNX Runtime library: set `ort_library` in the config or {ORT_DYLIB_ENV}"
                    ))
                })?,
        };
        let mut loaded = LOADED.lock().unwrap_or_else(|p| p.into_inner());
        if let Some((prev, env)) = loaded.as_ref() {
            if prev != &path {
                return Err(unavailable(format!(
                    "ONNX Runtime is already loaded from {} in this process, cannot switch to {}",
                    prev.display(),
                    path.display()
                )));
            }
            return Ok(env.clone());
        }
        if !path.is_file() {
            return Err(unavailable(format!("{} is not a file", path.display())));
        }
        let env = ort::init_from(&path)
            .map_err(|e| unavailable(format!("cannot load {}: {e}", path.display())))?
            .with_name("psgrasp")
            .build()
            .map_err(|e| unavailable(format!("cannot create the environment: {e}")))?;
        *loaded = Some((path, env.clone()));
        Ok(env)
    }

    fn ort_graph_err(graph: &'static str) -> impl Fn(ort::Error) -> ModelError {
        move |e| ModelError::Graph {
            graph,
            runtime: "ort",
            source: Box::new(e),
        }
    }

    fn ort_run_err(graph: &'static str) -> impl Fn(ort::Error) -> ModelError {
        move |e| ModelError::Run {
            graph,
            runtime: "ort",
            source: Box::new(e),
        }
    }

    impl FixedGraph {
        /// Creates an ONNX Runtime session for `bytes` and checks its input and output names.
        pub(super) fn ort(
            env: &ort::environment::Environment,
            bytes: &[u8],
            spec: GraphSpec,
            threads: usize,
        ) -> Result<Self, ModelError> {
            let session = session(env, bytes, spec.graph, resolve_threads(threads))?;
            check_names(&session, spec.graph, spec.input_name, &spec.output_names)?;
            Ok(Self {
                spec,
                engine: Engine::Ort(session),
            })
        }
    }

    /// Runs a single-input session on `input` (`spec.input_shape`, row-major) and takes the
    /// outputs `spec.output_names`, in that order.
    pub(super) fn run_fixed(
        session: &mut Session,
        spec: &GraphSpec,
        input: &[f32],
    ) -> Result<Vec<OutputTensor>, ModelError> {
        let graph = spec.graph;
        let dims: Vec<i64> = spec.input_shape.iter().map(|&v| v as i64).collect();
        let input = TensorRef::from_array_view((dims, input)).map_err(ort_run_err(graph))?;
        let mut outputs = session
            .run(ort::inputs![input])
            .map_err(ort_run_err(graph))?;
        let mut tensors = Vec::with_capacity(spec.output_names.len());
        for name in &spec.output_names {
            let v = outputs
                .remove(name)
                .ok_or_else(|| ModelError::GraphInterface {
                    graph,
                    reason: format!("output `{name}` missing"),
                })?;
            tensors.push(OutputTensor::from_ort(v, graph, name)?);
        }
        Ok(tensors)
    }

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

    fn session(
        env: &ort::environment::Environment,
        bytes: &[u8],
        graph: &'static str,
        threads: usize,
    ) -> Result<Session, ModelError> {
        let err = ort_graph_err(graph);
        let builder = Session::builder(env).map_err(&err)?;
        let builder = builder
            .with_intra_threads(threads)
            .map_err(|e| err(e.into()))?;
        let builder = builder.with_inter_threads(1).map_err(|e| err(e.into()))?;
        // No busy-waiting between operators: spinning threads of the U-Net session took the
        // cores from the MLP session and from the other pipeline processes (measured on 2 cores:
        // MLP 53 → 22 ms, total 319 → 250 ms; docs/benchmarks.md).
        let mut builder = builder
            .with_intra_op_spinning(false)
            .map_err(|e| err(e.into()))?;
        builder.commit_from_memory(bytes).map_err(&err)
    }

    fn check_names(
        session: &Session,
        graph: &'static str,
        input: &str,
        outputs: &[String],
    ) -> Result<(), ModelError> {
        let inputs: Vec<&str> = session.inputs().iter().map(|i| i.name()).collect();
        if inputs != [input] {
            return Err(ModelError::GraphInterface {
                graph,
                reason: format!("inputs are {inputs:?}, expected [{input:?}]"),
            });
        }
        let names: Vec<&str> = session.outputs().iter().map(|o| o.name()).collect();
        for name in outputs {
            if !names.contains(&name.as_str()) {
                return Err(ModelError::GraphInterface {
                    graph,
                    reason: format!("no output named `{name}` (outputs: {names:?})"),
                });
            }
        }
        Ok(())
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
