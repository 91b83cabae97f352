//! Materials at surface points, behind one batched query: the path tracer asks for a whole
//! wavefront of hit points at once (positions + triangle ids → base colour a, roughness σ,
//! metallic m). Implementations: the true scene of a `scene_meta.json` (`scene_meta`); a voxel
//! cache of per-voxel means in front of another source (`voxel`); appended geometry over another
//! source (`overlay`); two sources split by triangle (`split`); part means where no photo saw the
//! surface (`unseen`); a memo of points already answered (`memo`); the learned model lives in
//! fipt-train (burn inference), behind the same trait.
//!
//! Owns: the trait and the true-scene source. Must not touch: light transport.

pub mod memo;
pub mod overlay;
pub mod scene_meta;
pub mod split;
pub mod unseen;
pub mod voxel;

use glam::Vec3;

pub use memo::Memo;
pub use overlay::Overlay;
pub use scene_meta::TrueMaterials;
pub use split::Split;
pub use unseen::Unseen;
pub use voxel::VoxelMaterials;

/// The FIPT BRDF parameters at one surface point (paper Eq. 1).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SurfaceMaterial {
    pub base_color: Vec3,
    pub roughness: f32,
    pub metallic: f32,
}

impl SurfaceMaterial {
    /// A black surface (no reflection at all): a = 0, m = 1, so k_d = k_s = 0.
    pub const BLACK: Self = Self {
        base_color: Vec3::ZERO,
        roughness: 1.0,
        metallic: 1.0,
    };
}

/// A batched material query.
pub trait MaterialSource: Sync {
    /// The materials at world points `points` on triangles `tris`, in order, into `out`
    /// (cleared first).
    fn query(&self, points: &[Vec3], tris: &[u32], out: &mut Vec<SurfaceMaterial>);
}
