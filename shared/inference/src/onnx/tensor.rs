//! [`OutputTensor`]: a graph output kept in the runtime's own storage.
use crate::model_error::ModelError;
use tract_onnx::prelude::*;

/// A float tensor produced by a runtime, kept in the runtime's own storage (no copy).
pub struct OutputTensor {
    shape: Vec<usize>,
    storage: Storage,
}

enum Storage {
    Tract(TValue),
    Shared(std::sync::Arc<Vec<f32>>),
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
    /// Wraps a tract output, checking that it is a dense f32 tensor (`graph`, `name` for errors).
    pub(crate) fn from_tract(
        value: TValue,
        graph: &'static str,
        name: &str,
    ) -> Result<Self, ModelError> {
        let shape = value.shape().to_vec();
        let t = Self {
            shape,
            storage: Storage::Tract(value),
        };
        t.checked_data(graph, name)?;
        Ok(t)
    }

    /// Wraps values shared with the runtime that computed them (the native runtime updates
    /// its output grids in place between frames), checking their count.
    pub(crate) fn from_shared(
        shape: Vec<usize>,
        data: std::sync::Arc<Vec<f32>>,
        graph: &'static str,
        name: &str,
    ) -> Result<Self, ModelError> {
        let t = Self {
            shape,
            storage: Storage::Shared(data),
        };
        t.checked_data(graph, name)?;
        Ok(t)
    }

    /// Wraps an ONNX Runtime output, checking that it is a dense f32 tensor.
    #[cfg(feature = "ort")]
    pub(crate) fn from_ort(
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
            Storage::Shared(v) => Ok(v.as_slice()),
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
