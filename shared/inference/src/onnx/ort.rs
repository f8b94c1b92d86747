//! The ONNX Runtime engine (cargo feature `ort`): `libonnxruntime` loaded once per process, one
//! session per graph.
use super::{resolve_threads, Engine, FixedGraph, GraphSpec, OutputTensor};
use crate::model_error::ModelError;
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
pub(crate) fn environment(
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

/// The error of a failed run of `graph`.
pub(crate) fn ort_run_err(graph: &'static str) -> impl Fn(ort::Error) -> ModelError {
    move |e| ModelError::Run {
        graph,
        runtime: "ort",
        source: Box::new(e),
    }
}

impl FixedGraph {
    /// Creates an ONNX Runtime session for `bytes` and checks its input and output names.
    pub(crate) fn ort(
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

/// A session for `bytes` with `threads` intra-op threads, one inter-op thread and no spinning.
pub(crate) fn session(
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

/// Checks that `session` has the single input `input` and every output of `outputs`.
pub(crate) fn check_names(
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
