//! The ONNX graph runtimes both model backends run on: tract (pure Rust, default) and ONNX Runtime
//! (cargo feature `ort`, the library loaded at run time).
//!
//! [`RuntimeKind`] selects one. A fixed graph — one fixed-shape f32 input and named f32 outputs
//! (the learned U-Net, the VGN network) — is loaded with its input name checked and its outputs
//! found by name, and run into [`OutputTensor`]s that keep the runtime's own storage. The learned
//! backend's two-graph runtimes ([`crate::learned::runtime`]) are built from the same pieces
//! ([`tract`]'s loader and executor, the `ort` module's sessions). A panic inside a runtime
//! becomes a [`ModelError`], never an abort of the process.
//!
//! Matrix products of tract run on a private thread pool per model ([`resolve_threads`]: 0 = all
//! cores); ONNX Runtime sessions use that many intra-op threads and never spin between operators.
use crate::model_error::ModelError;
use std::sync::Arc;
use tract_onnx::prelude::TypedRunnableModel;

#[cfg(feature = "ort")]
pub(crate) mod ort;
mod tensor;
pub(crate) mod tract;

pub use tensor::OutputTensor;

/// Which graph runtime to use.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum RuntimeKind {
    /// tract (pure Rust, always available).
    #[default]
    Tract,
    /// ONNX Runtime through `ort` (needs the `ort` cargo feature and a `libonnxruntime.so`).
    Ort,
    /// psgrasp's own kernels for the learned backend's U-Net and MLP ([`crate::native`]).
    Native,
}

impl RuntimeKind {
    /// `"tract"`, `"ort"` or `"native"`.
    pub fn name(self) -> &'static str {
        match self {
            Self::Tract => "tract",
            Self::Ort => "ort",
            Self::Native => "native",
        }
    }
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
pub(crate) fn no_panic<T>(
    f: impl FnOnce() -> Result<T, ModelError>,
    on_panic: impl FnOnce(String) -> ModelError,
) -> Result<T, ModelError> {
    std::panic::catch_unwind(std::panic::AssertUnwindSafe(f))
        .unwrap_or_else(|p| Err(on_panic(panic_message(p))))
}

/// An error carrying only a message (a runtime's panic).
#[derive(Debug)]
pub(crate) struct StringError(pub(crate) String);
impl std::fmt::Display for StringError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(&self.0)
    }
}
impl std::error::Error for StringError {}

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
    Ort(::ort::session::Session),
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
            RuntimeKind::Tract => Self::tract(bytes, spec, tract::tract_executor(threads)?),
            #[cfg(feature = "ort")]
            RuntimeKind::Ort => {
                let env = ort::environment(ort_library)?;
                Self::ort(&env, bytes, spec, threads)
            }
            #[cfg(not(feature = "ort"))]
            RuntimeKind::Ort => {
                let _ = (ort_library, spec);
                Err(ort_not_built())
            }
            RuntimeKind::Native => Err(native_single_graph(spec.graph)),
        }
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
            } => tract::run_fixed(plan, outputs, executor, spec, input),
            #[cfg(feature = "ort")]
            Engine::Ort(session) => ort::run_fixed(session, spec, input),
        }
    }
}

/// The error for `runtime = "native"` on a graph other than the learned backend's two.
pub(crate) fn native_single_graph(graph: &'static str) -> ModelError {
    ModelError::RuntimeUnavailable {
        runtime: "native",
        reason: format!(
            "the native runtime runs the learned backend's U-Net and MLP only, not `{graph}`; \
             use runtime = \"tract\" or \"ort\""
        ),
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
