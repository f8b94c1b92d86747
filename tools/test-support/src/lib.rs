//! Fixtures shared by the tests and benchmarks of several crates, so that none of them copies
//! scene → depth → grid scaffolding from another. A dev-dependency only: no pipeline or tool
//! crate depends on it.
#![warn(missing_docs)]

pub mod analytic;
pub mod grasps;
pub mod scenes;
pub mod synthetic;
