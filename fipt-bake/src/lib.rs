//! fipt-bake: CPU ray tracing for FIPT on plain data (slices, glam types), never burn tensors.
//!
//! Owns: the BVH and ray casting (`accel`, `raycast`), segmentation fusion (`segfuse`).
//! Must not touch: the tensor model, the CLI.

pub mod accel;
pub mod bake;
pub mod emitters;
pub mod filter;
pub mod lightfield;
pub mod raycast;
mod sah;
pub mod segfuse;

pub use accel::{Accel, Hit};
pub use raycast::{ViewHits, cast_view, cast_views};
