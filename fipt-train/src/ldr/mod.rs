//! LDR photos (8-bit PNG or JPEG through an unknown camera response, lamps clipped), after
//! IRIS (`iris-reference.md`):
//!
//! - `twin`: the `ldr` command, which makes the LDR twin of an HDR scene;
//! - `reconstruct_jpegs`: JPEG photos' code values reconstructed within their quantisation
//!   (`fipt_core::scene::jpeg`) before anything reads them;
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

use fipt_core::scene::Dataset;
use fipt_core::scene::jpeg::Reconstruction;
use rayon::prelude::*;

/// Reconstructs every JPEG photo of the train and val splits within its quantisation, with
/// `iterations` projected steps (`ldr.jpeg_iterations`); returns how many it reconstructed.
pub fn reconstruct_jpegs(ds: &mut Dataset, iterations: usize) -> usize {
    let how = Reconstruction {
        iterations,
        ..Reconstruction::default()
    };
    let mut views: Vec<_> = ds.train.views.iter_mut().collect();
    if let Some(v) = ds.val.as_mut() {
        views.extend(v.views.iter_mut());
    }
    views
        .into_par_iter()
        .filter_map(|v| v.ldr.as_mut())
        .map(|f| f.reconstruct_jpeg(&how) as usize)
        .sum()
}
