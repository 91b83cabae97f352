//! fipt-bake: CPU ray tracing for FIPT on plain data (slices, glam types), never burn tensors.
//! Folders by role, as Mitsuba's:
//!
//! - `accel/`: the SAH BVH (obvhs CWBVH), closest-hit queries and pixel-centre ray casting;
//! - `integrators/`: estimators of light-transport integrals (the shading bake, Eq. 9);
//! - `emitters/`: emitter extraction from the emission mask (§4.4);
//! - `lightfield`: the voxel surface light field L′; `filter`: the shading filter;
//!   `segfuse`: segmentation fusion onto triangles.
//!
//! Must not touch: the tensor model, the CLI.

pub mod accel;
pub mod emitters;
pub mod filter;
pub mod integrators;
pub mod lightfield;
pub mod segfuse;

pub use accel::raycast::{ViewHits, cast_view, cast_views};
pub use accel::{Accel, Hit};
