//! Emitters: extraction of emissive triangles from the trained emission mask (paper §4.4), and
//! the area lights the path tracer samples.
//!
//! Owns: `extract`, `lights`. Must not touch: training.

pub mod extract;
pub mod lights;

pub use extract::{
    Emitter, EmitterSides, ExtractConfig, ObservedView, extract, radiance_per_triangle,
};
pub use lights::{AreaLight, EmitterSet, LightSample, LightSelection};
