//! A UV atlas for a mesh that has none: box-projected charts packed into one square texture.
//!
//! - **Charts.** Each triangle is assigned the axis (±x, ±y, ±z) its normal leans on most.
//!   Edge-connected triangles (vertices welded by position) with the same axis and the same
//!   group (material) form a chart, projected onto the plane across that axis. The projection
//!   shrinks a triangle by its normal's cosine to the axis, at least 1/√3, so the texel density
//!   varies by at most √3 across the mesh. A chart whose projected triangles overlap (a folded
//!   surface) falls back to one chart per triangle.
//! - **Packing.** Charts are scaled by one texel density (texels per world unit), padded by
//!   `pad` texels on each side, and packed in shelves, tallest first. The density is the largest
//!   that fits, found by bisection.
//!
//! UVs are in glTF's convention: (0, 0) is the image's top-left corner, v grows downwards
//! (Mitsuba's PLY reads them the same way).
//!
//! Owns: charts, packing, per-corner UVs. Must not touch: what the texels hold (`bake`).

use anyhow::{Result, bail};
use fipt_core::scene::Mesh;
use glam::{Vec2, Vec3};
use std::collections::HashMap;

/// A packed atlas: per-corner UVs of every triangle.
#[derive(Clone, Debug)]
pub struct Atlas {
    /// Side of the square texture, in texels.
    pub size: usize,
    /// UVs of each triangle's three corners, in [0, 1]².
    pub uv: Vec<[Vec2; 3]>,
    /// Chart of each triangle.
    pub chart: Vec<u32>,
    pub charts: usize,
    /// Texels per world unit.
    pub density: f32,
    /// Padding around each chart, in texels.
    pub pad: usize,
}

impl Atlas {
    /// Texel-space corners of triangle `t` (UV × size).
    pub fn texel_corners(&self, t: usize) -> [Vec2; 3] {
        self.uv[t].map(|p| p * self.size as f32)
    }
}

/// The six projection axes: 0..3 = +x, +y, +z, 3..6 = −x, −y, −z.
fn axis_of(n: Vec3) -> u8 {
    let a = n.abs();
    let k = if a.x >= a.y && a.x >= a.z {
        0
    } else if a.y >= a.z {
        1
    } else {
        2
    };
    if n[k] >= 0.0 { k as u8 } else { k as u8 + 3 }
}

/// Coordinates of `p` in the plane across `axis`, oriented so that a triangle facing the axis
/// keeps its winding.
fn project(p: Vec3, axis: u8) -> Vec2 {
    match axis {
        0 => Vec2::new(p.y, p.z),
        1 => Vec2::new(p.z, p.x),
        2 => Vec2::new(p.x, p.y),
        3 => Vec2::new(p.z, p.y),
        4 => Vec2::new(p.x, p.z),
        _ => Vec2::new(p.y, p.x),
    }
}

/// One chart before packing: its triangles and their projected corners (world units).
struct Chart {
    tris: Vec<u32>,
    corners: Vec<[Vec2; 3]>,
    min: Vec2,
    max: Vec2,
}

impl Chart {
    fn new(tris: Vec<u32>, corners: Vec<[Vec2; 3]>) -> Self {
        let mut min = Vec2::splat(f32::INFINITY);
        let mut max = Vec2::splat(f32::NEG_INFINITY);
        for c in corners.iter().flatten() {
            min = min.min(*c);
            max = max.max(*c);
        }
        Self {
            tris,
            corners,
            min,
            max,
        }
    }
}

/// Edge function of `p` against the directed edge a→b (twice the signed area).
#[inline]
fn edge(a: Vec2, b: Vec2, p: Vec2) -> f32 {
    (b - a).perp_dot(p - a)
}

/// Barycentric coordinates of `p` in triangle `c` (None for a degenerate triangle).
pub fn barycentric(c: &[Vec2; 3], p: Vec2) -> Option<[f32; 3]> {
    let area = edge(c[0], c[1], c[2]);
    if area.abs() < 1e-12 {
        return None;
    }
    let w0 = edge(c[1], c[2], p) / area;
    let w1 = edge(c[2], c[0], p) / area;
    Some([w0, w1, 1.0 - w0 - w1])
}

/// Texel centres strictly inside triangle `c` (texel units): calls `f(x, y, barycentrics)`.
pub fn for_texels_inside(c: &[Vec2; 3], size: usize, mut f: impl FnMut(usize, usize, [f32; 3])) {
    let min = c[0].min(c[1]).min(c[2]);
    let max = c[0].max(c[1]).max(c[2]);
    let x0 = (min.x - 0.5).ceil().max(0.0) as usize;
    let y0 = (min.y - 0.5).ceil().max(0.0) as usize;
    let x1 = ((max.x - 0.5).floor() as i64).min(size as i64 - 1);
    let y1 = ((max.y - 0.5).floor() as i64).min(size as i64 - 1);
    if x1 < x0 as i64 || y1 < y0 as i64 {
        return;
    }
    for y in y0..=y1 as usize {
        for x in x0..=x1 as usize {
            let p = Vec2::new(x as f32 + 0.5, y as f32 + 0.5);
            if let Some(b) = barycentric(c, p)
                && b.iter().all(|&w| w > 1e-5)
            {
                f(x, y, b);
            }
        }
    }
}

/// Whether the chart's triangles overlap once scaled by `density`: some texel centre strictly
/// inside two of them.
fn overlaps(chart: &Chart, density: f32) -> bool {
    let ext = (chart.max - chart.min) * density;
    let (w, h) = (ext.x.ceil() as usize + 1, ext.y.ceil() as usize + 1);
    if w.saturating_mul(h) > 1 << 26 {
        return false;
    }
    let mut seen = vec![false; w * h];
    for c in &chart.corners {
        let c = c.map(|p| (p - chart.min) * density);
        let mut clash = false;
        for_texels_inside(&c, w.max(h), |x, y, _| {
            if x < w && y < h {
                clash |= std::mem::replace(&mut seen[y * w + x], true);
            }
        });
        if clash {
            return true;
        }
    }
    false
}

/// Shelf packing of padded chart sizes (texels) into a `size`² square: each chart's top-left
/// corner, or None if they do not fit.
fn pack(sizes: &[(usize, usize)], order: &[usize], size: usize) -> Option<Vec<(usize, usize)>> {
    let mut at = vec![(0, 0); sizes.len()];
    let (mut x, mut y, mut shelf) = (0usize, 0usize, 0usize);
    for &k in order {
        let (w, h) = sizes[k];
        if w > size {
            return None;
        }
        if x + w > size {
            y += shelf;
            x = 0;
            shelf = 0;
        }
        if y + h > size {
            return None;
        }
        at[k] = (x, y);
        x += w;
        shelf = shelf.max(h);
    }
    Some(at)
}

/// Builds the atlas of `mesh` in a `size`² texture with `pad` texels around each chart;
/// `group[t]` is triangle t's material: charts never cross groups.
pub fn build(mesh: &Mesh, group: &[u32], size: usize, pad: usize) -> Result<Atlas> {
    let n = mesh.num_triangles();
    if group.len() != n {
        bail!("atlas: {} group ids for {n} triangles", group.len());
    }
    // Weld vertices by position.
    let mut weld: HashMap<[u32; 3], u32> = HashMap::new();
    let welded: Vec<u32> = mesh
        .vertices
        .iter()
        .map(|v| {
            let key = [v.x.to_bits(), v.y.to_bits(), v.z.to_bits()];
            let next = weld.len() as u32;
            *weld.entry(key).or_insert(next)
        })
        .collect();
    let axis: Vec<u8> = (0..n).map(|t| axis_of(mesh.cross(t))).collect();
    let mut uf = crate::union_find::UnionFind::new(n);
    let mut edges: HashMap<(u32, u32), u32> = HashMap::new();
    for t in 0..n {
        if mesh.area(t) <= 0.0 {
            continue;
        }
        let tri = mesh.triangles[t];
        for k in 0..3 {
            let (a, b) = (welded[tri[k] as usize], welded[tri[(k + 1) % 3] as usize]);
            let key = (a.min(b), a.max(b));
            match edges.get(&key) {
                Some(&o) if axis[o as usize] == axis[t] && group[o as usize] == group[t] => {
                    uf.union(o, t as u32)
                }
                Some(_) => {}
                None => {
                    edges.insert(key, t as u32);
                }
            }
        }
    }
    let mut members: HashMap<u32, Vec<u32>> = HashMap::new();
    for t in 0..n as u32 {
        members.entry(uf.find(t)).or_default().push(t);
    }
    let mut roots: Vec<u32> = members.keys().copied().collect();
    roots.sort_unstable();
    let projected = |t: u32| {
        mesh.corners(t as usize)
            .map(|p| project(p, axis[t as usize]))
    };
    let mut charts: Vec<Chart> = roots
        .iter()
        .map(|r| {
            let tris = members.remove(r).expect("root");
            let corners = tris.iter().map(|&t| projected(t)).collect();
            Chart::new(tris, corners)
        })
        .collect();

    let total: f32 = charts
        .iter()
        .map(|c| {
            let e = c.max - c.min;
            (e.x * e.y).max(1e-12)
        })
        .sum();
    let mut density = (size as f32 * size as f32 * 0.5 / total).sqrt();
    // Split overlapping charts at the first density tried (overlap does not depend on scale
    // beyond rounding).
    let mut split = Vec::new();
    for c in charts.drain(..) {
        if c.tris.len() > 1 && overlaps(&c, density) {
            for (t, k) in c.tris.iter().zip(&c.corners) {
                split.push(Chart::new(vec![*t], vec![*k]));
            }
        } else {
            split.push(c);
        }
    }
    let charts = split;
    let padded = |d: f32| -> Vec<(usize, usize)> {
        charts
            .iter()
            .map(|c| {
                let e = (c.max - c.min) * d;
                (
                    e.x.ceil() as usize + 1 + 2 * pad,
                    e.y.ceil() as usize + 1 + 2 * pad,
                )
            })
            .collect()
    };
    let mut order: Vec<usize> = (0..charts.len()).collect();
    let place = |d: f32, order: &mut Vec<usize>| {
        let sizes = padded(d);
        order.sort_by_key(|&k| (std::cmp::Reverse(sizes[k].1), k));
        pack(&sizes, order, size)
    };
    // Bisection on the density: the largest that packs.
    let (mut lo, mut hi) = (0.0f32, density);
    while place(hi, &mut order).is_some() {
        lo = hi;
        hi *= 2.0;
    }
    for _ in 0..24 {
        let mid = 0.5 * (lo + hi);
        if place(mid, &mut order).is_some() {
            lo = mid;
        } else {
            hi = mid;
        }
    }
    density = lo;
    let Some(at) = (density > 0.0)
        .then(|| place(density, &mut order))
        .flatten()
    else {
        bail!(
            "{} charts ({n} triangles) do not fit a {size}² atlas with {pad} texels of padding: raise --texels",
            charts.len()
        );
    };
    let mut uv = vec![[Vec2::ZERO; 3]; n];
    let mut chart_of = vec![0u32; n];
    let inv = 1.0 / size as f32;
    for (k, c) in charts.iter().enumerate() {
        let origin = Vec2::new((at[k].0 + pad) as f32, (at[k].1 + pad) as f32) + Vec2::splat(0.5);
        for (t, corners) in c.tris.iter().zip(&c.corners) {
            uv[*t as usize] = corners.map(|p| (origin + (p - c.min) * density) * inv);
            chart_of[*t as usize] = k as u32;
        }
    }
    Ok(Atlas {
        size,
        uv,
        chart: chart_of,
        charts: charts.len(),
        density,
        pad,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn room() -> Mesh {
        fipt_core::scene::procedural::room(Vec3::new(4.0, 2.5, 3.0), 1).mesh
    }

    /// Every corner lies in the texture, inside its chart's padded box, and no texel centre
    /// lies inside two triangles.
    #[test]
    fn charts_are_inside_and_disjoint() {
        let mesh = room();
        let n = mesh.num_triangles();
        let group: Vec<u32> = (0..n as u32).map(|t| t % 3).collect();
        let size = 256;
        let a = build(&mesh, &group, size, 2).unwrap();
        assert!(a.charts > 1 && a.charts <= n);
        let mut owner = vec![u32::MAX; size * size];
        for t in 0..n {
            for p in a.uv[t] {
                assert!(
                    (0.0..=1.0).contains(&p.x) && (0.0..=1.0).contains(&p.y),
                    "{p}"
                );
            }
            for_texels_inside(&a.texel_corners(t), size, |x, y, _| {
                let o = &mut owner[y * size + x];
                assert_eq!(*o, u32::MAX, "texel ({x}, {y}) in triangles {} and {t}", *o);
                *o = t as u32;
            });
        }
        // With whole walls as charts, the packing leaves little unused: over 40 % of the
        // texels lie inside a triangle (the rest is padding and shelf ends).
        let a = build(&mesh, &vec![0; n], size, 2).unwrap();
        let mut covered = 0;
        for t in 0..n {
            for_texels_inside(&a.texel_corners(t), size, |_, _, _| covered += 1);
        }
        assert!(covered * 5 > size * size * 2, "{covered} texels covered");
    }

    /// The UV map preserves shape: each triangle's UV area is its world area times the
    /// density², shrunk by the projection by at most √3; charts never mix groups.
    #[test]
    fn uv_areas_follow_world_areas() {
        let mesh = room();
        let n = mesh.num_triangles();
        let group: Vec<u32> = (0..n as u32).map(|t| t % 2).collect();
        let a = build(&mesh, &group, 512, 2).unwrap();
        for t in 0..n {
            let c = a.texel_corners(t);
            let uv_area = 0.5 * edge(c[0], c[1], c[2]).abs();
            let world = mesh.area(t) * a.density * a.density;
            assert!(
                uv_area <= world * 1.0001 && uv_area >= world / 3f32.sqrt() * 0.9999,
                "triangle {t}: {uv_area} vs {world}"
            );
        }
        let mut chart_group = HashMap::new();
        for (t, g) in group.iter().enumerate() {
            assert_eq!(chart_group.entry(a.chart[t]).or_insert(*g), g);
        }
    }

    /// A spiral ramp (1.5 turns, every triangle facing +z, edge-connected) projects onto
    /// itself: it is split, and no texel lies in two triangles.
    #[test]
    fn overlapping_projection_is_split() {
        let steps = 24;
        let mut vertices = Vec::new();
        for i in 0..=steps {
            let th = i as f32 * std::f32::consts::TAU / 16.0;
            let z = 0.01 * i as f32;
            vertices.push(Vec3::new(0.2 * th.cos(), 0.2 * th.sin(), z));
            vertices.push(Vec3::new(th.cos(), th.sin(), z));
        }
        let mut triangles = Vec::new();
        for i in 0..steps as u32 {
            let (a, b, c, d) = (2 * i, 2 * i + 1, 2 * i + 3, 2 * i + 2);
            triangles.push([a, b, c]);
            triangles.push([a, c, d]);
        }
        let mesh = Mesh {
            vertices,
            triangles,
        };
        let n = mesh.num_triangles();
        assert!((0..n).all(|t| axis_of(mesh.cross(t)) == 2));
        let a = build(&mesh, &vec![0; n], 256, 1).unwrap();
        assert_eq!(a.charts, n);
        let mut owner = vec![false; 256 * 256];
        for t in 0..n {
            for_texels_inside(&a.texel_corners(t), 256, |x, y, _| {
                assert!(!std::mem::replace(&mut owner[y * 256 + x], true));
            });
        }
    }

    /// Too small a texture for the charts is an error that says what to change.
    #[test]
    fn too_small_an_atlas_is_an_error() {
        let mesh = room();
        let group = vec![0; mesh.num_triangles()];
        let e = build(&mesh, &group, 8, 4).unwrap_err().to_string();
        assert!(e.contains("--texels"), "{e}");
    }
}
