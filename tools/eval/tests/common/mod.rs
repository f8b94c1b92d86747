//! Helpers shared by the evaluation's integration tests.
use std::path::{Path, PathBuf};

/// Writes `dir/detectors.toml` with two detectors, `analytic` and `learned` (the shipped model,
/// `models/default`, on one thread), and returns its path.
pub fn analytic_and_shipped_detectors(dir: &Path) -> PathBuf {
    let list = dir.join("detectors.toml");
    let model = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../models/default");
    std::fs::write(
        &list,
        format!(
            "[[detector]]\nname = \"analytic\"\nbackend = {{ kind = \"analytic\" }}\n\n\
             [[detector]]\nname = \"learned\"\nbackend = {{ kind = \"learned\", model_dir = {:?}, threads = 1 }}\n",
            model.display().to_string()
        ),
    )
    .unwrap();
    list
}
