//! fipt-bake: CPU ray tracing for FIPT on plain data (slices, glam types), never burn tensors.
//! Folders by role, as Mitsuba's:
//!
//! - `accel/`: the SAH BVH (obvhs CWBVH), closest-hit queries and pixel-centre ray casting;
//! - `integrators/`: estimators of light-transport integrals (the shading bake, Eq. 9; the
//!   wavefront path tracer);
//! - `materials/`: the batched material query the path tracer reads (the true scene here, the
//!   learned model in fipt-train);
//! - `emitters/`: emitter extraction from the emission mask (§4.4) and the area lights;
//! - `lightfield`: the voxel surface light field L′; `filter`: the shading filter;
//!   `segfuse`: segmentation fusion onto triangles.
//!
//! Must not touch: the tensor model, the CLI.

pub mod accel;
pub mod emitters;
pub mod filter;
pub mod integrators;
pub mod lightfield;
pub mod materials;
pub mod segfuse;

pub use accel::raycast::{ViewHits, cast_view, cast_views};
pub use accel::{Accel, Hit};
