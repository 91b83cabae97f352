//! LDR photos (8-bit PNG or JPEG through an unknown camera response, lamps clipped), after
//! IRIS (`iris-reference.md`):
//!
//! - `twin`: the `ldr` command, which makes the LDR twin of an HDR scene;
//! - `calibrate`: the response and the per-frame exposures, and the photos linearised with
//!   them before the bake;
//! - `lights`: the HDR radiance of clipped emitters, solved from the unclipped pixels they
//!   light;
//! - `edges`: the camera response read from the pixels on the edges between surfaces;
//! - `response`: the camera response, estimated within that solve;
//! - `report`: the run's LDR figures (view synthesis scored in LDR).
//!
//! Owns: what LDR input changes in a run. Must not touch: the fit's losses (fipt-core), the
//! tracing (fipt-bake).

pub mod calibrate;
pub mod edges;
pub mod lights;
pub mod report;
pub mod response;
pub mod twin;

pub use calibrate::{Calibration, ResponseChoice, calibrate};
pub use twin::{TwinJob, TwinTruth, make_twin};
