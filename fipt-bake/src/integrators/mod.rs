//! Estimators of light-transport integrals over the scene mesh.
//!
//! Owns: `bake`, the shading estimators of Eq. 9; `path`, the wavefront path tracer; `refine`,
//! the path-traced shadings of Eq. 10–11. Must not touch: files, tensors.

pub mod bake;
pub mod path;
pub mod refine;
