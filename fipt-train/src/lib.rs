//! fipt-train as a library: the pipeline (`pipeline`, one module per stage), the tools around
//! it (`check`, `bench`), the config schema, caches, reports and output writers, exposed so
//! integration tests and benches call them directly.
//!
//! Must not touch: model maths (fipt-core) or ray tracing (fipt-bake).

pub mod alloc;
pub mod bench;
pub mod cache;
pub mod check;
pub mod config;
pub mod demo;
pub mod export;
pub mod html_report;
pub mod image_metrics;
pub mod interrupt;
pub mod ldr;
pub mod learned;
pub mod lock;
pub mod output;
pub mod pipeline;
pub mod progress;
pub mod rerender;

pub mod scene_model;
pub mod suite;
pub mod union_find;
pub mod zoo;
