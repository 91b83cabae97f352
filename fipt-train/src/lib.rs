//! fipt-train as a library: the pipeline stages, tools and reports behind the `fipt-train` CLI,
//! exposed so integration tests and benches call them directly.
//!
//! Owns: the dataset doctor (`check`), benchmarks (`bench`). Must not touch: model maths.

pub mod bake_cmd;
pub mod bench;
pub mod cache;
pub mod check;
pub mod config;
pub mod metrics;
pub mod stage1;
