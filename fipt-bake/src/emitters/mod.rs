//! Emitters: extraction of emissive triangles from the trained emission mask (paper §4.4).
//!
//! Owns: `extract`. Must not touch: training.

pub mod extract;

pub use extract::{Emitter, ExtractConfig, ObservedView, extract, radiance_per_triangle};
