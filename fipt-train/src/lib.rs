//! fipt-train as a library: the pipeline stages, tools and reports behind the `fipt-train` CLI,
//! exposed so integration tests and benches call them directly.
//!
//! Owns: the dataset doctor (`check`), benchmarks (`bench`). Must not touch: model maths.

pub mod bake_cmd;
pub mod bench;
pub mod cache;
pub mod check;
pub mod config;
pub mod eval;
pub mod maps;
pub mod metrics;
pub mod run_cmd;
pub mod stage1;
pub mod stage2;
