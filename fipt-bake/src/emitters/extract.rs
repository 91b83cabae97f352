//! Emitter extraction (paper §4.4, Eq. 13; reference §2.4): a triangle is an emitter when the mean of
//! the emission mask α over uniform samples on it exceeds a threshold; its radiance is the
//! per-channel (lower) median of the photo pixels whose pixel-centre ray first hit it; emitters
//! never seen with positive radiance are dropped.
//!
//! One addition to the reference: a candidate must also *emit* what its photos show. Where the
//! trained BRDF and the baked shadings already explain the photo pixels of a triangle (the
//! median share of the observed radiance left unexplained is below `min_unexplained`), the mask
//! only spilled onto it — a smooth PE mask does next to a lamp — and the triangle is rejected.
//! With `min_unexplained = 0` this is the reference rule.
//!
//! A second addition (`fill_unseen`): a candidate no photo saw (a lamp's face turned to the
//! wall) cannot have its radiance measured, and the reference drops it, so the wall beside it
//! goes dark in every refined shading. Here such a candidate that shares an edge with an
//! emitter takes the pixel-weighted mean radiance of its emitting edge neighbours, repeatedly,
//! so a hidden face of two triangles fills from the faces around it. Its sides are unknown: it
//! emits from both.
//!
//! A third (`interior`): a photo pixel is the mean of the radiance over its footprint, so a
//! pixel on a lamp's outline mixes the lamp with what lies behind it, and a small lamp seen a
//! few pixels wide is mostly outline. The median is then taken over a triangle's interior
//! pixels only, those whose eight neighbours' pixel-centre rays also hit candidates of the same
//! connected emitter (candidates joined through shared edges); a triangle seen at outline
//! pixels only takes the pixel-weighted mean radiance of its edge neighbours measured on
//! interior pixels (as `fill_unseen` spreads it). Where none is reached it keeps its own
//! median, unless every pixel of it borders another emitter's pixels: then what it shows is
//! that emitter's light (its outline, or its reflection in a glossy surface under a lamp), and
//! it is dropped.
//!
//! Owns: per-triangle sampling, the decision and the radiance statistics. Must not touch: the
//! mask itself (it is queried through a closure, a batch at a time).

use crate::accel::raycast::ViewHits;
use fipt_core::rng::Rng;
use fipt_core::scene::Mesh;
use glam::Vec3;

/// One emissive triangle.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Emitter {
    pub triangle: u32,
    pub radiance: [f32; 3],
    pub area: f32,
    /// Unit winding normal.
    pub normal: [f32; 3],
    pub vertices: [[f32; 3]; 3],
    /// Mean α over the samples.
    pub mean_alpha: f32,
    /// Photo pixels that saw the triangle.
    pub pixels: u32,
    /// Photo pixels that saw the triangle's front (winding-normal) side and its back side.
    #[serde(default)]
    pub seen_front: u32,
    #[serde(default)]
    pub seen_back: u32,
    /// Median over those pixels of the share of the observed radiance that reflection (the
    /// trained BRDF on the baked shadings) leaves unexplained; 1 where no prediction was given.
    pub unexplained: f32,
    /// Never seen: the radiance is its emitting neighbours' (`ExtractConfig::fill_unseen`).
    #[serde(default)]
    pub unseen: bool,
}

/// One training view as emitter extraction sees it.
#[derive(Clone, Copy, Debug)]
pub struct ObservedView<'a> {
    pub hits: &'a ViewHits,
    /// HDR photo, 3 floats per pixel.
    pub image: &'a [f32],
    /// Predicted reflected radiance, 3 floats per pixel (zeros where nothing is predicted);
    /// empty when unknown.
    pub reflected: &'a [f32],
}

/// The rule's parameters.
#[derive(Clone, Copy, Debug)]
pub struct ExtractConfig {
    pub samples_per_triangle: usize,
    /// Mean α above which a triangle is a candidate (reference: 0.01).
    pub threshold: f32,
    /// Minimum median unexplained share of a candidate's observed radiance.
    pub min_unexplained: f32,
    /// Give unseen candidates next to emitters their neighbours' radiance (false: dropped, the
    /// reference).
    pub fill_unseen: bool,
    /// Measure a triangle's radiance on its interior pixels, and drop one seen only beside
    /// another emitter that no measured neighbour reaches (false: every pixel that saw it
    /// counts, the reference).
    pub interior: bool,
    pub seed: u64,
}

/// Share of observed radiance `gt` that `reflected` does not explain, in [0, 1].
fn unexplained_share(gt: [f32; 3], reflected: [f32; 3]) -> f32 {
    let (g, r) = (gt.iter().sum::<f32>(), reflected.iter().sum::<f32>());
    if g <= 0.0 {
        0.0
    } else {
        (1.0 - r.max(0.0) / g).clamp(0.0, 1.0)
    }
}

/// Uniform point `k` of `n` on triangle `t` (b0 = 1 − √u, b1 = √u·v), deterministic per seed.
pub fn triangle_samples(mesh: &Mesh, n: usize, seed: u64) -> Vec<[f32; 3]> {
    let mut out = Vec::with_capacity(mesh.num_triangles() * n);
    for t in 0..mesh.num_triangles() {
        let [a, b, c] = mesh.corners(t);
        let mut r = Rng::new(seed, t as u64);
        for _ in 0..n {
            let (u, v) = (r.next_f32(), r.next_f32());
            let su = u.sqrt();
            let (b0, b1) = (1.0 - su, su * v);
            out.push((a * b0 + b * b1 + c * (1.0 - b0 - b1)).to_array());
        }
    }
    out
}

/// Extracts the emitters. `alpha` maps world points to mask values (called in chunks).
pub fn extract(
    mesh: &Mesh,
    alpha: &mut dyn FnMut(&[[f32; 3]]) -> Vec<f32>,
    views: &[ObservedView],
    cfg: &ExtractConfig,
) -> Vec<Emitter> {
    let (threshold, seed) = (cfg.threshold, cfg.seed);
    let n = cfg.samples_per_triangle.max(1);
    // Chunks of whole triangles keep memory bounded on big meshes.
    let tris_per_chunk = (1 << 18) / n + 1;
    let mut mean_alpha = vec![0f32; mesh.num_triangles()];
    let pts = triangle_samples(mesh, n, seed);
    for (c, chunk) in pts.chunks(tris_per_chunk * n).enumerate() {
        let a = alpha(chunk);
        for (i, tri_alpha) in a.chunks(n).enumerate() {
            mean_alpha[c * tris_per_chunk + i] = tri_alpha.iter().sum::<f32>() / n as f32;
        }
    }
    let candidate: Vec<bool> = mean_alpha.iter().map(|&a| a > threshold).collect();
    // With `interior`, the connected emitter of each candidate.
    let emitter_of = if cfg.interior {
        components(mesh, &candidate)
    } else {
        Vec::new()
    };
    // Per candidate: observed radiance and unexplained share of each pixel that saw it, the
    // observed radiance of its interior pixels, and how many of its pixels border another
    // emitter's.
    type Seen = (Vec<[f32; 3]>, Vec<f32>, [u32; 2], Vec<[f32; 3]>, usize);
    let mut seen: std::collections::HashMap<u32, Seen> = Default::default();
    for v in views {
        // The connected emitter that pixel `p`'s centre ray hits (`u32::MAX`: none).
        let emitter_at = |p: usize| {
            let t = v.hits.tri[p];
            if t >= 0 {
                emitter_of[t as usize]
            } else {
                u32::MAX
            }
        };
        for (p, &t) in v.hits.tri.iter().enumerate() {
            if t >= 0 && candidate[t as usize] {
                let gt = [v.image[3 * p], v.image[3 * p + 1], v.image[3 * p + 2]];
                let share = if v.reflected.is_empty() {
                    1.0
                } else {
                    let r = &v.reflected[3 * p..3 * p + 3];
                    unexplained_share(gt, [r[0], r[1], r[2]])
                };
                let e = seen.entry(t as u32).or_default();
                e.0.push(gt);
                e.1.push(share);
                if let Some(d) = v.hits.direction.get(p) {
                    let front = mesh.normal(t as usize).dot(*d) < 0.0;
                    e.2[usize::from(!front)] += 1;
                }
                if cfg.interior {
                    let own = emitter_of[t as usize];
                    if is_interior(v.hits, p, &|q| emitter_at(q) == own) {
                        e.3.push(gt);
                    }
                    let other = |q: usize| ![own, u32::MAX].contains(&emitter_at(q));
                    if neighbours(v.hits, p).any(other) {
                        e.4 += 1;
                    }
                }
            }
        }
    }
    let mut out = Vec::new();
    // Emitters measured on interior pixels (triangle, radiance, interior pixels), those seen at
    // outline pixels only, and those among them whose every pixel borders another emitter.
    let (mut measured, mut outline, mut mixed) = (Vec::new(), Vec::new(), Vec::new());
    for t in 0..mesh.num_triangles() {
        if !candidate[t] {
            continue;
        }
        let Some((px, shares, sides, inner, bordering)) = seen.get_mut(&(t as u32)) else {
            continue;
        };
        shares.sort_by(f32::total_cmp);
        let unexplained = shares[(shares.len() - 1) / 2];
        let all = lower_median(px);
        if unexplained < cfg.min_unexplained || all.iter().sum::<f32>() <= 0.0 {
            continue;
        }
        let radiance = if inner.is_empty() {
            all
        } else {
            lower_median(inner)
        };
        if radiance.iter().sum::<f32>() <= 0.0 {
            continue;
        }
        if cfg.interior {
            if inner.is_empty() {
                outline.push(t);
                if *bordering == px.len() {
                    mixed.push(t);
                }
            } else {
                measured.push((t, Vec3::from(radiance), inner.len() as f32));
            }
        }
        let [a, b, c] = mesh.corners(t);
        out.push(Emitter {
            triangle: t as u32,
            radiance,
            area: mesh.area(t),
            normal: mesh.normal(t).to_array(),
            vertices: [a.to_array(), b.to_array(), c.to_array()],
            mean_alpha: mean_alpha[t],
            pixels: px.len() as u32,
            seen_front: sides[0],
            seen_back: sides[1],
            unexplained,
            unseen: false,
        });
    }
    let reached = spread(mesh, &measured, &outline);
    for &(t, radiance) in &reached {
        if let Ok(i) = out.binary_search_by_key(&(t as u32), |e| e.triangle) {
            out[i].radiance = radiance.to_array();
        }
    }
    // A triangle seen only at pixels beside another emitter, and reached by no measured
    // neighbour, shows that emitter's light (its outline, or its reflection), not its own.
    out.retain(|e| {
        let t = e.triangle as usize;
        !mixed.contains(&t) || reached.iter().any(|r| r.0 == t)
    });
    if cfg.fill_unseen {
        let unseen: Vec<usize> = (0..mesh.num_triangles())
            .filter(|&t| candidate[t] && !seen.contains_key(&(t as u32)))
            .collect();
        let sources: Vec<(usize, Vec3, f32)> = out
            .iter()
            .map(|e| (e.triangle as usize, Vec3::from(e.radiance), e.pixels as f32))
            .collect();
        for (t, radiance) in spread(mesh, &sources, &unseen) {
            out.push(Emitter {
                mean_alpha: mean_alpha[t],
                unseen: true,
                ..Emitter::on_triangle(mesh, t, radiance.to_array())
            });
        }
        out.sort_by_key(|e| e.triangle);
    }
    out
}

/// Per channel, the lower median of `px` (not empty).
fn lower_median(px: &[[f32; 3]]) -> [f32; 3] {
    std::array::from_fn(|c| {
        let mut v: Vec<f32> = px.iter().map(|x| x[c]).collect();
        v.sort_by(f32::total_cmp);
        v[(v.len() - 1) / 2]
    })
}

/// The pixels around pixel `p` that lie inside the image (eight away from its border).
fn neighbours(hits: &ViewHits, p: usize) -> impl Iterator<Item = usize> {
    let (w, h) = (hits.width, hits.height);
    let (x, y) = (p % w, p / w);
    (y.saturating_sub(1)..(y + 2).min(h))
        .flat_map(move |yy| (x.saturating_sub(1)..(x + 2).min(w)).map(move |xx| yy * w + xx))
        .filter(move |&q| q != p)
}

/// Whether pixel `p` lies inside the image and its eight neighbours' pixel-centre rays all hit
/// what `hit` accepts.
fn is_interior(hits: &ViewHits, p: usize, hit: &dyn Fn(usize) -> bool) -> bool {
    let (x, y) = (p % hits.width, p / hits.width);
    let inside = x > 0 && y > 0 && x + 1 < hits.width && y + 1 < hits.height;
    inside && neighbours(hits, p).all(hit)
}

/// Edge keys of triangles with vertices matched by position, so faces with split vertices share
/// edges.
#[derive(Default)]
struct EdgeKeys(std::collections::HashMap<[u32; 3], u32>);

impl EdgeKeys {
    /// Triangle `t`'s three edges, each as an ordered pair of vertex ids.
    fn edges(&mut self, mesh: &Mesh, t: usize) -> [(u32, u32); 3] {
        let [a, b, c] = mesh.corners(t).map(|p| {
            let n = self.0.len() as u32;
            *self.0.entry(p.to_array().map(f32::to_bits)).or_insert(n)
        });
        [(a, b), (b, c), (c, a)].map(|(x, y)| (x.min(y), x.max(y)))
    }
}

/// Per triangle, the connected emitter it belongs to: candidates joined through shared edges
/// get one id (the smallest triangle index among them); non-candidates get `u32::MAX`.
fn components(mesh: &Mesh, candidate: &[bool]) -> Vec<u32> {
    fn root(parent: &mut [u32], mut t: u32) -> u32 {
        while parent[t as usize] != t {
            let up = parent[parent[t as usize] as usize];
            parent[t as usize] = up;
            t = up;
        }
        t
    }
    let mut parent: Vec<u32> = (0..candidate.len() as u32).collect();
    let mut keys = EdgeKeys::default();
    let mut owner: std::collections::HashMap<(u32, u32), u32> = Default::default();
    for t in (0..candidate.len()).filter(|&t| candidate[t]) {
        for k in keys.edges(mesh, t) {
            let other = *owner.entry(k).or_insert(t as u32);
            let (a, b) = (root(&mut parent, t as u32), root(&mut parent, other));
            parent[a.max(b) as usize] = a.min(b);
        }
    }
    (0..candidate.len() as u32)
        .map(|t| {
            if candidate[t as usize] {
                root(&mut parent, t)
            } else {
                u32::MAX
            }
        })
        .collect()
}

/// The radiance that the `targets` reach through shared edges from the `sources` (triangle,
/// radiance, weight): each target reached takes the weighted mean radiance of its emitting
/// edge neighbours (a weight of at least 1; targets reached, weight 1), in passes until none is
/// added. Edges are matched by vertex position, so faces with split vertices connect.
fn spread(mesh: &Mesh, sources: &[(usize, Vec3, f32)], targets: &[usize]) -> Vec<(usize, Vec3)> {
    use std::collections::HashMap;
    let mut reached = Vec::new();
    if targets.is_empty() || sources.is_empty() {
        return reached;
    }
    let mut keys = EdgeKeys::default();
    let mut edges = |t: usize| keys.edges(mesh, t);
    // Edge → (radiance sum, weight) of the emitters on it.
    let mut lit: HashMap<(u32, u32), (Vec3, f32)> = HashMap::new();
    let add = |lit: &mut HashMap<(u32, u32), (Vec3, f32)>, es: [(u32, u32); 3], r: Vec3, w: f32| {
        for k in es {
            let v = lit.entry(k).or_insert((Vec3::ZERO, 0.0));
            v.0 += r * w.max(1.0);
            v.1 += w.max(1.0);
        }
    };
    for &(t, r, w) in sources {
        add(&mut lit, edges(t), r, w);
    }
    let mut left: Vec<(usize, [(u32, u32); 3])> = targets.iter().map(|&t| (t, edges(t))).collect();
    loop {
        let mut found = Vec::new();
        left.retain(|&(t, es)| {
            let (sum, w) = es
                .iter()
                .filter_map(|k| lit.get(k))
                .fold((Vec3::ZERO, 0.0), |(s, w), v| (s + v.0, w + v.1));
            if w > 0.0 {
                found.push((t, es, sum / w));
                false
            } else {
                true
            }
        });
        if found.is_empty() {
            break;
        }
        for (t, es, radiance) in found {
            add(&mut lit, es, radiance, 1.0);
            reached.push((t, radiance));
        }
    }
    reached
}

impl Emitter {
    /// Triangle `t` of `mesh` emitting `radiance`, with its geometry from the mesh and the
    /// extraction's diagnostics neutral (mask α 1, seen from no pixel, nothing explained): an
    /// emitter placed by hand, or one that extraction fills in.
    pub fn on_triangle(mesh: &Mesh, t: usize, radiance: [f32; 3]) -> Self {
        let [a, b, c] = mesh.corners(t);
        Self {
            triangle: t as u32,
            radiance,
            area: mesh.area(t),
            normal: mesh.normal(t).to_array(),
            vertices: [a.to_array(), b.to_array(), c.to_array()],
            mean_alpha: 1.0,
            pixels: 0,
            seen_front: 0,
            seen_back: 0,
            unexplained: 1.0,
            unseen: false,
        }
    }

    /// The sides it emits from as observed: both where the photos saw both sides (or neither),
    /// else the one they saw.
    pub fn observed_sides(&self) -> EmitterSides {
        match (self.seen_front > 0, self.seen_back > 0) {
            (true, false) => EmitterSides::Front,
            (false, true) => EmitterSides::Back,
            _ => EmitterSides::Both,
        }
    }
}

/// Which sides of a triangle emit (front: along the winding normal).
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum EmitterSides {
    Front,
    Back,
    Both,
}

/// Emitted radiance per triangle (zero where none).
pub fn radiance_per_triangle(num_triangles: usize, emitters: &[Emitter]) -> Vec<Vec3> {
    let mut out = vec![Vec3::ZERO; num_triangles];
    for e in emitters {
        out[e.triangle as usize] = Vec3::from(e.radiance);
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The reference's threshold, the default `min_unexplained`, 4 samples per triangle.
    fn test_config(fill_unseen: bool, interior: bool) -> ExtractConfig {
        ExtractConfig {
            samples_per_triangle: 4,
            threshold: 0.01,
            min_unexplained: 0.5,
            fill_unseen,
            interior,
            seed: 0,
        }
    }

    #[test]
    fn picks_masked_seen_triangles_with_lower_median() {
        let mesh = Mesh::parse_obj("v 0 0 0\nv 1 0 0\nv 0 1 0\nv 5 0 0\nv 6 0 0\nv 5 1 0\nv 9 0 0\nv 9 1 0\nv 9 0 1\nf 1 2 3\nf 4 5 6\nf 7 8 9\n").unwrap();
        // α = 1 for x < 7 (triangles 0 and 1), 0 beyond.
        let mut alpha = |p: &[[f32; 3]]| {
            p.iter()
                .map(|x| if x[0] < 7.0 { 1.0 } else { 0.0 })
                .collect()
        };
        // Triangle 0's winding normal is +z: three pixels look at its front, one at its back.
        let (down, up) = (Vec3::NEG_Z, Vec3::Z);
        let hits = ViewHits {
            width: 5,
            height: 1,
            tri: vec![0, 0, 0, 0, 2],
            direction: vec![down, down, up, down, down],
            ..Default::default()
        };
        let img = [
            1.0, 1.0, 1.0, 4.0, 4.0, 4.0, 2.0, 2.0, 2.0, 3.0, 3.0, 3.0, 9.0, 9.0, 9.0,
        ];
        let cfg = test_config(false, false);
        let view = |reflected| ObservedView {
            hits: &hits,
            image: &img,
            reflected,
        };
        let e = extract(&mesh, &mut alpha, &[view(&[])], &cfg);
        // Triangle 1 is masked but never seen: dropped. Triangle 2 is seen but not masked.
        assert_eq!(e.len(), 1);
        assert_eq!(e[0].triangle, 0);
        assert_eq!(e[0].radiance, [2.0; 3]); // lower median of 1, 2, 3, 4
        assert!((e[0].area - 0.5).abs() < 1e-6);
        assert_eq!(e[0].pixels, 4);
        assert_eq!((e[0].seen_front, e[0].seen_back), (3, 1));
        assert_eq!(e[0].observed_sides(), EmitterSides::Both);
        let one = |f, b| Emitter {
            seen_front: f,
            seen_back: b,
            ..e[0].clone()
        };
        assert_eq!(one(5, 0).observed_sides(), EmitterSides::Front);
        assert_eq!(one(0, 2).observed_sides(), EmitterSides::Back);
        assert_eq!(one(0, 0).observed_sides(), EmitterSides::Both);
        assert_eq!(e[0].unexplained, 1.0);
        // Reflection explains 90 % of every pixel: the mask only spilled here, no emitter.
        let most = img.map(|v| 0.9 * v);
        let e = extract(&mesh, &mut alpha, &[view(&most)], &cfg);
        assert!(e.is_empty());
        // Reflection explains a tenth of each pixel: an emitter, unexplained share 0.9.
        let little = img.map(|v| 0.1 * v);
        let e = extract(&mesh, &mut alpha, &[view(&little)], &cfg);
        assert_eq!(e.len(), 1);
        assert!((e[0].unexplained - 0.9).abs() < 1e-6);
    }

    /// A hidden face next to an emitter takes its neighbours' radiance (through edges matched by
    /// position across split vertices, two steps deep); a masked triangle touching no emitter,
    /// or touching it at a vertex only, stays dropped; without `fill_unseen` all are dropped.
    #[test]
    fn unseen_candidates_fill_from_emitting_neighbours() {
        // 0: seen emitter; 1: shares 0's edge (1,0,0)-(0,1,0) through its own vertices; 2: shares
        // an edge with 1 only; 3: shares a vertex with 0 only; 4: isolated; all masked.
        let mesh = Mesh::parse_obj(
            "v 0 0 0\nv 1 0 0\nv 0 1 0\n\
             v 1 0 0\nv 1 1 0\nv 0 1 0\n\
             v 1 1 0\nv 2 1 0\nv 1 0 0\n\
             v 0 0 0\nv -1 0 0\nv 0 -1 0\n\
             v 5 5 0\nv 6 5 0\nv 5 6 0\n\
             f 1 2 3\nf 4 5 6\nf 7 8 9\nf 10 11 12\nf 13 14 15\n",
        )
        .unwrap();
        let mut alpha = |p: &[[f32; 3]]| vec![1.0; p.len()];
        let hits = ViewHits {
            width: 2,
            height: 1,
            tri: vec![0, 0],
            direction: vec![Vec3::NEG_Z; 2],
            ..Default::default()
        };
        let img = [2.0, 4.0, 6.0, 2.0, 4.0, 6.0];
        let view = ObservedView {
            hits: &hits,
            image: &img,
            reflected: &[],
        };
        let mut cfg = test_config(false, false);
        let dropped = extract(&mesh, &mut alpha, &[view], &cfg);
        assert_eq!(dropped.iter().map(|e| e.triangle).collect::<Vec<_>>(), [0]);
        cfg.fill_unseen = true;
        let e = extract(&mesh, &mut alpha, &[view], &cfg);
        assert_eq!(e.iter().map(|e| e.triangle).collect::<Vec<_>>(), [0, 1, 2]);
        assert!(!e[0].unseen && e[1].unseen && e[2].unseen);
        for f in &e[1..] {
            assert_eq!(f.radiance, [2.0, 4.0, 6.0]);
            assert_eq!((f.pixels, f.observed_sides()), (0, EmitterSides::Both));
        }
    }

    /// With `interior`, a triangle's radiance is the median of its interior pixels (all eight
    /// neighbours on the same connected emitter), one seen at outline pixels only takes that of
    /// its measured edge neighbour, one with no measured neighbour keeps its own median, and one
    /// seen only beside another emitter's pixels is dropped; without it, every pixel counts (the
    /// outline pulls the lamp's median down).
    #[test]
    fn interior_pixels_measure_a_lamp_past_its_outline() {
        // 0 and 1: a quad (shared edge (0,0,0)-(1,1,0)); 2 and 3: apart.
        let mesh = Mesh::parse_obj(
            "v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nv 5 0 0\nv 6 0 0\nv 5 1 0\n\
             v 9 0 0\nv 10 0 0\nv 9 1 0\n\
             f 1 2 3\nf 1 3 4\nf 5 6 7\nf 8 9 10\n",
        )
        .unwrap();
        let mut alpha = |p: &[[f32; 3]]| vec![1.0; p.len()];
        #[rustfmt::skip]
        let tri = vec![
            -1, -1, -1, -1, 3, -1, 2,
            -1, 0, 0, 0, -1, -1, -1,
            -1, 0, 0, 0, -1, -1, -1,
            -1, 0, 0, 1, -1, -1, -1,
            -1, -1, -1, -1, -1, -1, -1,
        ];
        // Outline pixels of the lamp read 4 (triangle 0) and 3 (triangle 1), its one interior
        // pixel (2, 2) reads 10; triangle 2's pixel, away from the lamp, 7; triangle 3's,
        // diagonal to the lamp's corner, 6.
        let img: Vec<f32> = (0..35)
            .flat_map(|p| {
                let v = match (p, tri[p]) {
                    (16, _) => 10.0,
                    (_, 0) => 4.0,
                    (_, 1) => 3.0,
                    (_, 2) => 7.0,
                    (_, 3) => 6.0,
                    _ => 0.5,
                };
                [v; 3]
            })
            .collect();
        let hits = ViewHits {
            width: 7,
            height: 5,
            tri,
            direction: vec![Vec3::NEG_Z; 35],
            ..Default::default()
        };
        let view = ObservedView {
            hits: &hits,
            image: &img,
            reflected: &[],
        };
        let mut cfg = test_config(true, false);
        let mut radiance = |cfg: &ExtractConfig| -> Vec<(u32, f32)> {
            extract(&mesh, &mut alpha, &[view], cfg)
                .iter()
                .map(|e| (e.triangle, e.radiance[0]))
                .collect()
        };
        assert_eq!(radiance(&cfg), [(0, 4.0), (1, 3.0), (2, 7.0), (3, 6.0)]);
        cfg.interior = true;
        assert_eq!(radiance(&cfg), [(0, 10.0), (1, 10.0), (2, 7.0)]);
    }
}
