//! Scene data and loaders: the triangle mesh, cameras, HDR or LDR views and ground-truth maps.
//!
//! Owns: file formats (OBJ, EXR, PNG/JPEG photos, `transforms.json`, `cam.txt`/`K_list.txt`,
//! `scene_meta.json`) turned into plain data (structs of arrays). Must not
//! touch: ray tracing (fipt-bake) or tensors.

pub mod camera;
pub mod dataset;
pub mod image;
pub mod insert;
pub mod jpeg;
pub mod ldr;
pub mod mesh;
pub mod meta;
pub mod procedural;
pub mod scene_box;

pub use camera::{Camera, Intrinsics};
pub use dataset::{Dataset, LoadOptions, MapKind, Split, View};
pub use image::Image;
pub use ldr::{LdrFrame, Response};
pub use mesh::Mesh;
pub use scene_box::SceneBox;
