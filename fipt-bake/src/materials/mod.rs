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

/// `src`'s materials at the entries `idx` of a query (`points`, `tris`), in the order of `idx`,
/// in one batched query; none asked when `idx` is empty. The sources that answer part of a
/// query themselves forward the rest through it.
fn query_at(
    src: &dyn MaterialSource,
    points: &[Vec3],
    tris: &[u32],
    idx: &[usize],
) -> Vec<SurfaceMaterial> {
    let mut out = Vec::with_capacity(idx.len());
    if !idx.is_empty() {
        let pts: Vec<Vec3> = idx.iter().map(|&i| points[i]).collect();
        let ts: Vec<u32> = idx.iter().map(|&i| tris[i]).collect();
        src.query(&pts, &ts, &mut out);
    }
    out
}

/// A running sum of materials (in f64) for their mean.
#[derive(Clone, Copy, Default)]
struct MaterialSum {
    sum: [f64; 5],
    n: u32,
}

impl MaterialSum {
    fn add(&mut self, m: &SurfaceMaterial) {
        let v = [
            m.base_color.x,
            m.base_color.y,
            m.base_color.z,
            m.roughness,
            m.metallic,
        ];
        for (a, x) in self.sum.iter_mut().zip(v) {
            *a += x as f64;
        }
        self.n += 1;
    }

    /// The mean of what was added (at least one material).
    fn mean(&self) -> SurfaceMaterial {
        let f = |c: usize| (self.sum[c] / self.n as f64) as f32;
        SurfaceMaterial {
            base_color: Vec3::new(f(0), f(1), f(2)),
            roughness: f(3),
            metallic: f(4),
        }
    }
}
