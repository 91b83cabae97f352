//! fipt-core: the differentiable FIPT model and the scene data it learns from.
//!
//! Owns: scene data types and loaders (`scene`), the scalar BRDF (`brdf`), small shared utilities
//! (`io`, `rng`). The tensor model (encodings, fields, renderer, losses) lives here too.
//! Must not touch: ray tracing and baking (those are `fipt-bake`'s), the CLI (`fipt-train`).

pub mod brdf;
pub mod io;
pub mod model;
pub mod ranges;
pub mod rng;
pub mod scene;
pub mod shading;
