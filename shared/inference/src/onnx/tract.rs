//! The tract engine: graphs parsed and optimised once at load, run on a private thread pool.
use super::{no_panic, FixedGraph, GraphSpec, OutputTensor, StringError};
use crate::model_error::ModelError;
use std::sync::Arc;
use tract_onnx::prelude::*;

fn tract_err(graph: &'static str) -> impl Fn(TractError) -> ModelError {
    move |e| ModelError::Graph {
        graph,
        runtime: "tract",
        source: e.into(),
    }
}

/// The error of a graph whose loading panicked inside tract.
pub(crate) fn tract_load_panic(graph: &'static str) -> impl FnOnce(String) -> ModelError {
    move |m| ModelError::Graph {
        graph,
        runtime: "tract",
        source: Box::new(StringError(format!("tract panicked: {m}"))),
    }
}

/// The executor of tract's matrix products: the calling thread for `threads` = 1, else a private
/// pool of `threads` threads (0 = all cores).
pub(crate) fn tract_executor(
    threads: usize,
) -> Result<tract_linalg::multithread::Executor, ModelError> {
    let threads = super::resolve_threads(threads);
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
pub(crate) fn run_tract(
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

/// Loads one ONNX graph with tract, checks its single input's name, finds the named outputs and
/// optimises it for `input_fact`.
pub(crate) fn load_tract_graph(
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

impl FixedGraph {
    /// Loads `bytes` with tract, optimised for the fixed input shape.
    pub(crate) fn tract(
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
            engine: super::Engine::Tract {
                plan,
                outputs,
                executor,
            },
        })
    }
}

/// Runs a fixed graph's tract plan on `input` (`spec.input_shape`, row-major; its length already
/// checked) and takes the outputs at `outputs` (the model indices of `spec.output_names`).
pub(super) fn run_fixed(
    plan: &Arc<TypedRunnableModel>,
    outputs: &[usize],
    executor: &tract_linalg::multithread::Executor,
    spec: &GraphSpec,
    input: &[f32],
) -> Result<Vec<OutputTensor>, ModelError> {
    let graph = spec.graph;
    let tensor =
        Tensor::from_shape(&spec.input_shape, input).map_err(|e| ModelError::GraphInterface {
            graph,
            reason: format!("input of {} values: {e}", input.len()),
        })?;
    let values = run_tract(plan, executor, graph, tensor)?;
    let mut taken: Vec<Option<TValue>> = values.into_iter().map(Some).collect();
    let mut tensors = Vec::with_capacity(spec.output_names.len());
    for (name, &ix) in spec.output_names.iter().zip(outputs.iter()) {
        let v =
            taken
                .get_mut(ix)
                .and_then(Option::take)
                .ok_or_else(|| ModelError::GraphInterface {
                    graph,
                    reason: format!("output `{name}` missing"),
                })?;
        tensors.push(OutputTensor::from_tract(v, graph, name)?);
    }
    Ok(tensors)
}
