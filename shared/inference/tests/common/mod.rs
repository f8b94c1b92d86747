//! Helpers shared by the model tests (`learned_model.rs`, `vgn_model.rs`): the PyTorch reference
//! tensors exported with a model directory and the agreement check against them.
use psgrasp_geometry::{GripperModel, Workspace};
use psgrasp_inference::learned::ModelError;
use psgrasp_inference::{
    backend_for_workspace, backend_from_config, BackendConfig, InferenceError,
};
use safetensors::SafeTensors;
use std::collections::HashMap;
use std::path::Path;

/// Largest allowed difference to the PyTorch reference.
pub const TOLERANCE: f32 = 1e-4;

/// The tensors of a `reference.safetensors` as (shape, values).
pub struct Reference {
    tensors: HashMap<String, (Vec<usize>, Vec<f32>)>,
}

impl Reference {
    /// Reads `dir/reference.safetensors` (all tensors must be f32).
    pub fn load(dir: &Path) -> Self {
        let bytes = std::fs::read(dir.join("reference.safetensors")).expect("reference");
        let st = SafeTensors::deserialize(&bytes).expect("valid safetensors");
        let mut tensors = HashMap::new();
        for (name, view) in st.tensors() {
            assert_eq!(view.dtype(), safetensors::Dtype::F32, "{name}");
            let values = view
                .data()
                .chunks_exact(4)
                .map(|b| f32::from_le_bytes([b[0], b[1], b[2], b[3]]))
                .collect();
            tensors.insert(name.to_string(), (view.shape().to_vec(), values));
        }
        Self { tensors }
    }

    /// The values of tensor `name`.
    pub fn get(&self, name: &str) -> &[f32] {
        &self
            .tensors
            .get(name)
            .unwrap_or_else(|| panic!("reference has no `{name}`"))
            .1
    }

    /// Whether the file holds tensor `name`.
    #[allow(dead_code)]
    pub fn has(&self, name: &str) -> bool {
        self.tensors.contains_key(name)
    }

    /// The shape of tensor `name`.
    #[allow(dead_code)]
    pub fn shape(&self, name: &str) -> &[usize] {
        &self.tensors[name].0
    }
}

/// Asserts that `ours` matches `reference` within [`TOLERANCE`] everywhere (NaN fails).
pub fn assert_close(name: &str, ours: &[f32], reference: &[f32]) {
    assert_eq!(ours.len(), reference.len(), "{name}: length");
    let (mut worst, mut at) = (0.0f32, 0);
    for (i, (a, b)) in ours.iter().zip(reference).enumerate() {
        let d = (a - b).abs();
        if d > worst || d.is_nan() {
            worst = d;
            at = i;
        }
    }
    eprintln!(
        "{name}: {} values, max abs difference {worst:.3e}",
        ours.len()
    );
    assert!(
        worst <= TOLERANCE,
        "{name}: max abs difference {worst} at {at} ({} vs {})",
        ours[at],
        reference[at]
    );
}

/// Asserts that `cfg` (whose model was exported for `workspace` and `gripper`) is refused at
/// start-up, naming the card field, when the pipeline's grid dims, voxel size, maximum opening or
/// approach depth differ from the card.
pub fn assert_card_mismatches_are_refused(
    cfg: &BackendConfig,
    workspace: Workspace,
    gripper: GripperModel,
) {
    let refused = |result: Result<_, InferenceError>, expected: &str| match result {
        Err(InferenceError::Model(ModelError::Mismatch { field, .. })) => {
            assert_eq!(field, expected)
        }
        Err(e) => panic!("{expected}: expected a card mismatch, got {e}"),
        Ok(_) => panic!("{expected}: a mismatching pipeline was accepted"),
    };
    let [x, y, z] = workspace.dims;
    let other = Workspace {
        dims: [x * 2, y, z],
        ..workspace
    };
    refused(backend_for_workspace(cfg, &other, gripper), "grid.dims");
    let finer = Workspace {
        voxel_size_m: 0.008,
        ..workspace
    };
    refused(
        backend_for_workspace(cfg, &finer, gripper),
        "grid.voxel_size_m",
    );
    let wide = GripperModel {
        max_opening_m: 0.1,
        ..gripper
    };
    refused(backend_from_config(cfg, wide), "gripper.max_opening_m");
    let long = GripperModel {
        finger_size_m: [0.021, 0.026, 0.06],
        ..gripper
    };
    refused(
        backend_for_workspace(cfg, &workspace, long),
        "gripper.approach_depth_m",
    );
}
