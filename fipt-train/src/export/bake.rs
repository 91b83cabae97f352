//! The material field and the emitters baked into the atlas's texels.
//!
//! Every texel whose centre lies inside a triangle's UV image takes the material at the world
//! point with the same barycentric coordinates; a sliver that holds no texel centre takes the
//! texels under its corners and centroid. Texels around each chart, up to the atlas's
//! padding, take the material of the nearest covered texel's triangle at the point of that
//! triangle closest in barycentric terms, so that bilinear filtering at a chart's edge reads no
//! texel of another chart or of the empty background.
//!
//! Owns: texel ownership, padding, the batched material queries. Must not touch: file formats.

use super::atlas::{Atlas, barycentric, for_texels_inside};
use fipt_bake::materials::{MaterialSource, SurfaceMaterial};
use fipt_core::scene::Mesh;
use glam::Vec3;

/// No triangle.
pub const EMPTY: u32 = u32::MAX;

/// The baked maps, row-major, `size`² texels each, row 0 at the top (v = 0).
#[derive(Clone, Debug)]
pub struct Textures {
    pub size: usize,
    /// Base colour a, linear.
    pub base_color: Vec<Vec3>,
    /// Roughness σ (fipt's; GGX α = σ²).
    pub roughness: Vec<f32>,
    pub metallic: Vec<f32>,
    /// Emitted radiance divided by its material's emission strength.
    pub emission: Vec<Vec3>,
    /// The triangle each texel samples (`EMPTY` outside every chart and its padding).
    pub owner: Vec<u32>,
}

/// Material queries per batch.
const QUERY_BATCH: usize = 1 << 16;

/// Bakes `materials` and the per-triangle `emission` (already divided by its material's
/// strength) into `atlas`'s texels.
pub fn bake(
    mesh: &Mesh,
    atlas: &Atlas,
    materials: &dyn MaterialSource,
    emission: &[Vec3],
) -> Textures {
    let size = atlas.size;
    let mut owner = vec![EMPTY; size * size];
    let mut bary = vec![[0.0f32; 3]; size * size];
    for t in 0..mesh.num_triangles() {
        for_texels_inside(&atlas.texel_corners(t), size, |x, y, b| {
            owner[y * size + x] = t as u32;
            bary[y * size + x] = b;
        });
    }
    // Slivers that contain no texel centre still own the texels under their corners and
    // centroid, so that every triangle reads its own material.
    for t in 0..mesh.num_triangles() {
        let c = atlas.texel_corners(t);
        for p in [(c[0] + c[1] + c[2]) / 3.0, c[0], c[1], c[2]] {
            let (x, y) = (p.x.floor(), p.y.floor());
            if x < 0.0 || y < 0.0 || x >= size as f32 || y >= size as f32 {
                continue;
            }
            let i = y as usize * size + x as usize;
            if owner[i] == EMPTY {
                owner[i] = t as u32;
                let centre = glam::Vec2::new(x + 0.5, y + 0.5);
                bary[i] = clamp_bary(barycentric(&c, centre).unwrap_or([1.0 / 3.0; 3]));
            }
        }
    }
    // Padding: rings of 8-neighbours, each taking the first covered neighbour's triangle.
    let mut front: Vec<usize> = (0..size * size).filter(|&i| owner[i] != EMPTY).collect();
    for _ in 0..atlas.pad + 1 {
        let mut next = Vec::new();
        for &i in &front {
            let (x, y) = ((i % size) as i64, (i / size) as i64);
            for (dx, dy) in [
                (-1, 0),
                (1, 0),
                (0, -1),
                (0, 1),
                (-1, -1),
                (1, -1),
                (-1, 1),
                (1, 1),
            ] {
                let (nx, ny) = (x + dx, y + dy);
                if nx < 0 || ny < 0 || nx >= size as i64 || ny >= size as i64 {
                    continue;
                }
                let j = ny as usize * size + nx as usize;
                if owner[j] == EMPTY {
                    let t = owner[i] as usize;
                    owner[j] = t as u32;
                    let p = glam::Vec2::new(nx as f32 + 0.5, ny as f32 + 0.5);
                    bary[j] = clamp_bary(
                        barycentric(&atlas.texel_corners(t), p).unwrap_or([1.0 / 3.0; 3]),
                    );
                    next.push(j);
                }
            }
        }
        front = next;
    }
    let texels: Vec<usize> = (0..size * size).filter(|&i| owner[i] != EMPTY).collect();
    let mut tex = Textures {
        size,
        base_color: vec![Vec3::ZERO; size * size],
        roughness: vec![0.0; size * size],
        metallic: vec![0.0; size * size],
        emission: vec![Vec3::ZERO; size * size],
        owner,
    };
    let mut points = Vec::with_capacity(QUERY_BATCH);
    let mut tris = Vec::with_capacity(QUERY_BATCH);
    let mut out: Vec<SurfaceMaterial> = Vec::with_capacity(QUERY_BATCH);
    for batch in texels.chunks(QUERY_BATCH) {
        points.clear();
        tris.clear();
        for &i in batch {
            let t = tex.owner[i];
            let c = mesh.corners(t as usize);
            let b = bary[i];
            points.push(c[0] * b[0] + c[1] * b[1] + c[2] * b[2]);
            tris.push(t);
        }
        materials.query(&points, &tris, &mut out);
        for (&i, m) in batch.iter().zip(&out) {
            tex.base_color[i] = m.base_color;
            tex.roughness[i] = m.roughness;
            tex.metallic[i] = m.metallic;
            tex.emission[i] = emission[tex.owner[i] as usize];
        }
    }
    tex
}

/// Barycentric coordinates moved into the triangle: negative weights cut to zero, then
/// normalised.
fn clamp_bary(b: [f32; 3]) -> [f32; 3] {
    let c = b.map(|w| w.max(0.0));
    let s: f32 = c.iter().sum();
    if s > 0.0 {
        c.map(|w| w / s)
    } else {
        [1.0 / 3.0; 3]
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::export::atlas;

    /// Materials that vary linearly in space: a = p / 4, σ = x / 4, m = z / 3.
    struct Linear;
    impl MaterialSource for Linear {
        fn query(&self, points: &[Vec3], _tris: &[u32], out: &mut Vec<SurfaceMaterial>) {
            out.clear();
            out.extend(points.iter().map(|p| SurfaceMaterial {
                base_color: *p / 4.0,
                roughness: p.x / 4.0,
                metallic: p.z / 3.0,
            }));
        }
    }

    /// Each covered texel holds the field at its world point: sampling the baked maps at a
    /// triangle's UV centroid (nearest texel) gives the field at its world centroid, within
    /// the texel's footprint; emission is the triangle's own.
    #[test]
    fn texels_hold_the_field_at_their_world_points() {
        let mesh = fipt_core::scene::procedural::room(Vec3::new(4.0, 2.5, 3.0), 1).mesh;
        let n = mesh.num_triangles();
        let a = atlas::build(&mesh, &vec![0; n], 512, 2).unwrap();
        let emission: Vec<Vec3> = (0..n).map(|t| Vec3::splat((t % 5) as f32 / 4.0)).collect();
        let tex = bake(&mesh, &a, &Linear, &emission);
        // One texel spans 1/density world units, √3 more along a projected slope.
        let tol = 3f32.sqrt() / a.density / 4.0 * 1.5;
        let mut checked = 0;
        for (t, e) in emission.iter().enumerate() {
            let c = a.texel_corners(t);
            let uv = (c[0] + c[1] + c[2]) / 3.0;
            let i = uv.y as usize * a.size + uv.x as usize;
            if tex.owner[i] != t as u32 {
                continue; // a sliver whose centroid texel belongs to a neighbour
            }
            let w = mesh.corners(t);
            let p = (w[0] + w[1] + w[2]) / 3.0;
            assert!(
                (tex.base_color[i] - p / 4.0).abs().max_element() < tol,
                "triangle {t}"
            );
            assert!((tex.roughness[i] - p.x / 4.0).abs() < tol);
            assert_eq!(tex.emission[i], *e);
            checked += 1;
        }
        assert!(checked * 2 > n, "{checked} of {n} triangles checked");
        // Padding: the texels around every covered texel are owned too.
        let s = a.size as i64;
        for t in 0..n {
            atlas::for_texels_inside(&a.texel_corners(t), a.size, |x, y, _| {
                for (dx, dy) in [(-1, 0), (1, 0), (0, -1), (0, 1), (2, 2), (-2, -2)] {
                    let (nx, ny) = (x as i64 + dx, y as i64 + dy);
                    if (0..s).contains(&nx) && (0..s).contains(&ny) {
                        assert_ne!(tex.owner[(ny * s + nx) as usize], EMPTY);
                    }
                }
            });
        }
    }
}
