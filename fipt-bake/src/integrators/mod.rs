//! Estimators of light-transport integrals over the scene mesh.
//!
//! Owns: `bake`, the shading estimators of Eq. 9. Must not touch: files, tensors.

pub mod bake;
