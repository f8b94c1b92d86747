//! The harness of psgrasp's fuzz targets (docs/testing.md, "Fuzzing").
//!
//! Every parser that reads outside input has a fuzz target: a `#[test]` in its crate's
//! `tests/fuzz.rs` that runs under plain `cargo test` on stable Rust through [`bolero`]. Each
//! target comes in two checks:
//!
//! * the raw check (`bolero::check!(name = ...)`) replays the committed seed corpus
//!   (`tests/__fuzz__/<name>/corpus/`: small real files, valid and broken, and the inputs that
//!   once broke a parser) and then feeds random bytes;
//! * the mutated check takes a seed and applies a few random [`Mutation`]s to it (bit flips,
//!   interesting integers, tokens of the seeds' own vocabulary, cuts and splices): without a
//!   coverage-guided engine random bytes rarely get past a format's magic number or syntax,
//!   mutated seeds do.
//!
//! Both run the parser through [`Target::run`], which fails the test on a panic and on an
//! allocation larger than the target's bound ([`TrackingAllocator`]), and writes the failing
//! input to a file to be added to the corpus as a regression.
//!
//! Each check runs for bolero's default of one second; `BOLERO_RANDOM_TEST_TIME_MS` (or
//! `BOLERO_RANDOM_ITERATIONS`) raises it for a longer run, `BOLERO_RANDOM_SEED` replays one
//! random input.
#![warn(missing_docs)]

mod alloc;
mod mutate;

pub use alloc::{largest_allocation, TrackingAllocator};
pub use bolero;
pub use mutate::{Dictionary, Mutated, Mutation, MAX_MUTATIONS};

use std::panic::{catch_unwind, AssertUnwindSafe};
use std::path::{Path, PathBuf};

/// Largest single allocation a target may make for one input unless it sets its own bound
/// ([`Target::max_alloc`]): 16 MiB, far above what a parser needs for the ≤ 4 KiB inputs of
/// the fuzzer and far below what an unchecked size field asks for.
pub const DEFAULT_MAX_ALLOC: usize = 16 << 20;

/// One fuzz target: its name (the corpus folder) and its allocation bound.
#[derive(Debug, Clone)]
pub struct Target {
    /// The name, e.g. `depth_png`: the raw check's corpus is `tests/__fuzz__/<name>/corpus/`.
    pub name: &'static str,
    /// The seed corpus folder.
    pub corpus: PathBuf,
    /// Largest single allocation allowed while parsing one input, bytes.
    pub max_alloc: usize,
}

impl Target {
    /// The target `name` of the crate at `manifest_dir` (pass `env!("CARGO_MANIFEST_DIR")`),
    /// with its corpus under `tests/__fuzz__/<name>/corpus/`, where bolero's `check!(name = ..)`
    /// in `tests/fuzz.rs` looks for it.
    pub fn new(manifest_dir: &str, name: &'static str) -> Self {
        Self {
            name,
            corpus: Path::new(manifest_dir)
                .join("tests/__fuzz__")
                .join(name)
                .join("corpus"),
            max_alloc: DEFAULT_MAX_ALLOC,
        }
    }

    /// The same target with another allocation bound.
    pub fn max_alloc(mut self, bytes: usize) -> Self {
        self.max_alloc = bytes;
        self
    }

    /// The seed corpus: every file of [`Target::corpus`], sorted by name. Panics if there is
    /// none: a mutated check needs seeds.
    pub fn seeds(&self) -> Vec<Vec<u8>> {
        let mut paths: Vec<PathBuf> = std::fs::read_dir(&self.corpus)
            .unwrap_or_else(|e| panic!("seed corpus {}: {e}", self.corpus.display()))
            .filter_map(|e| e.ok().map(|e| e.path()))
            .filter(|p| p.is_file())
            .collect();
        paths.sort();
        let seeds: Vec<Vec<u8>> = paths
            .iter()
            .map(|p| std::fs::read(p).unwrap_or_else(|e| panic!("{}: {e}", p.display())))
            .collect();
        assert!(!seeds.is_empty(), "{} has no seeds", self.corpus.display());
        seeds
    }

    /// Runs `parse` on `input`. A panic, or a single allocation above [`Target::max_alloc`],
    /// fails the test: the input is written to the system's temporary folder and the message
    /// names the file, to be copied into the corpus as a regression once fixed.
    pub fn run(&self, input: &[u8], parse: impl FnOnce(&[u8])) {
        let (outcome, largest) =
            largest_allocation(|| catch_unwind(AssertUnwindSafe(|| parse(input))));
        let failure = match outcome {
            Err(payload) => format!("panicked: {}", panic_message(payload.as_ref())),
            Ok(()) if largest > self.max_alloc => format!(
                "allocated {largest} bytes at once (bound {} bytes)",
                self.max_alloc
            ),
            Ok(()) => return,
        };
        let saved = self.save_artifact(input);
        panic!(
            "fuzz target `{}` {failure} on a {}-byte input (saved to {saved}; once fixed, add it \
             to {} as a regression)",
            self.name,
            input.len(),
            self.corpus.display()
        );
    }

    fn save_artifact(&self, input: &[u8]) -> String {
        let dir = std::env::temp_dir().join("psgrasp-fuzz");
        let path = dir.join(format!("{}-{:016x}", self.name, fnv1a(input)));
        match std::fs::create_dir_all(&dir).and_then(|()| std::fs::write(&path, input)) {
            Ok(()) => path.display().to_string(),
            Err(e) => format!("nowhere: {e}"),
        }
    }
}

/// The text of a panic payload.
fn panic_message(payload: &(dyn std::any::Any + Send)) -> String {
    if let Some(s) = payload.downcast_ref::<&str>() {
        (*s).to_string()
    } else if let Some(s) = payload.downcast_ref::<String>() {
        s.clone()
    } else {
        "(non-text panic payload)".into()
    }
}

/// 64-bit FNV-1a, naming saved inputs by content.
fn fnv1a(bytes: &[u8]) -> u64 {
    bytes.iter().fold(0xcbf2_9ce4_8422_2325, |h, &b| {
        (h ^ u64::from(b)).wrapping_mul(0x0100_0000_01b3)
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn run_passes_quiet_inputs_and_fails_panics_and_large_allocations() {
        let t = Target::new(env!("CARGO_MANIFEST_DIR"), "self-test").max_alloc(1 << 20);
        t.run(b"ok", |b| assert_eq!(b, b"ok"));
        let panicked = catch_unwind(|| t.run(b"boom", |_| panic!("parser bug"))).unwrap_err();
        let msg = panic_message(panicked.as_ref());
        assert!(msg.contains("panicked: parser bug"), "{msg}");
        assert!(msg.contains("self-test"), "{msg}");
        let big = catch_unwind(|| {
            t.run(b"x", |_| {
                std::hint::black_box(vec![0u8; 4 << 20]);
            })
        })
        .unwrap_err();
        let msg = panic_message(big.as_ref());
        assert!(msg.contains("allocated 4194304 bytes"), "{msg}");
    }

    #[global_allocator]
    static ALLOC: TrackingAllocator = TrackingAllocator;
}
