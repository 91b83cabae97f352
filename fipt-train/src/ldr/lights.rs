//! The HDR radiance of clipped emitters. An LDR photo records a lamp only as "at least the clip
//! level", so the emitters extracted from it carry that lower bound. Their radiance is solved
//! instead from the unclipped pixels they light (IRIS optimises it against the photos, §2 of
//! `iris-reference.md`; this solves it in closed form).
//!
//! For a rough dielectric pixel p of part P, the photo is I(p) ≈ k_P · (Σ_k Le_k·D_k(p) +
//! E(p)): D_k is the irradiance/π that emitter group k sends to p at unit radiance (Monte Carlo,
//! with visibility), E the diffuse shading from everything but the clipped groups (L′ over
//! cosine-sampled directions that do not end on a clipped lamp), and k_P the part's
//! diffuse albedo, one per part. Within a part the share of direct light varies from pixel to
//! pixel, which separates k_P from Le_k; the light that walls reflect onto each other (E,
//! recorded unclipped) fixes the scale. The two are alternated as least squares per channel,
//! with Le_k ≥ T_k (a clipped lamp emits at least its clip level). D_k and E are Monte Carlo
//! estimates, and noise in a regressor biases least squares (errors in variables: k_P low, Le_k
//! high): each is estimated twice, from two independent halves of its samples, and each half
//! serves as the instrument of the other (`alternate`; `ldr.solve_instruments`).
//!
//! With `ldr.estimate_response` (and clipped lamps, and 1,000 pixels or more), the same solve is
//! run for each response on a grid and the response chosen with it (`super::response`).
//!
//! Owns: grouping emitters into lamps, the solve. Must not touch: the extraction rule, the fit.

use crate::pipeline::pixels::PixelStore;
use fipt_bake::emitters::Emitter;
use fipt_bake::lightfield::LightField;
use fipt_bake::{Accel, ViewHits};
use fipt_core::model::Trainer;
use fipt_core::rng::Rng;
use fipt_core::scene::{Mesh, Split};
use glam::Vec3;
use serde::{Deserialize, Serialize};
use std::collections::HashMap;

/// What the solve did, per lamp (a group of edge- or vertex-connected emitter triangles).
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct LampReport {
    /// The lamp's triangles.
    pub triangles: Vec<u32>,
    /// Whether its radiance was solved (its pixels are mostly clipped).
    pub solved_clipped: bool,
    /// Photo pixels of the lamp, and the share of them with a clipped channel.
    pub pixels: usize,
    pub clipped_share: f64,
    /// The extracted (clipped) radiance, area-weighted, and the solved one.
    pub extracted: [f32; 3],
    pub solved: [f32; 3],
}

#[derive(Clone, Debug, Default, Serialize, Deserialize)]
pub struct LightSolve {
    pub lamps: Vec<LampReport>,
    /// Pixels the solve used, and parts they fell in.
    pub pixels: usize,
    pub parts: usize,
    /// The response estimated with the solve (`super::response`), where it was.
    #[serde(default)]
    pub response: Option<super::response::ResponseFit>,
    /// Surface pixels whose clipped channels the solve's L′ raised to the fit's render
    /// (`ldr.fill_clipped_surfaces`), where it did.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub surface_pixels_filled: Option<usize>,
}

/// Settings of the solve.
#[derive(Clone, Copy, Debug)]
pub struct SolveConfig {
    pub pixels: usize,
    pub light_samples: usize,
    pub seed: u64,
    /// Estimate the response's γ per channel with the radiance and albedos; else the photos'
    /// linearisation stands (γ = 1).
    pub estimate_response: bool,
    /// Whether the exposures were estimated (they then move with γ, `super::response`).
    pub exposures_estimated: bool,
    /// Estimate the light terms from two independent halves of their samples, each half the
    /// instrument of the other's (`alternate`); else ordinary least squares.
    pub instruments: bool,
}

/// One pixel of the solve: its photo codes and their linear values g(code) under the response
/// the photos are linearised with, its view's exposure, D_k per clipped lamp, the L′ samples of
/// E (zero where a direction ends on a clipped lamp or leaves the scene), and D_k from each half
/// of its light samples (empty: no instruments, and E's samples are not split either).
#[derive(Clone)]
pub struct SolvePixel {
    pub code: [f64; 3],
    pub value: [f64; 3],
    pub exposure: f64,
    pub part: usize,
    pub direct: Vec<f32>,
    pub lprime: Vec<[f32; 3]>,
    pub direct_half: Vec<[f32; 2]>,
}

impl SolvePixel {
    /// D_k from half `h` of its light samples, or the whole estimate where the pixel has no
    /// halves.
    pub fn direct_of(&self, k: usize, h: usize) -> f32 {
        self.direct_half.get(k).map_or(self.direct[k], |d| d[h])
    }
}

/// Groups emitters into lamps: triangles that share a vertex position.
fn lamps(mesh: &Mesh, emitters: &[Emitter]) -> Vec<Vec<usize>> {
    let key = |v: Vec3| (v * 1e4).round().as_ivec3();
    let mut sets = crate::union_find::UnionFind::new(emitters.len());
    let mut at: HashMap<glam::IVec3, usize> = HashMap::new();
    for (i, e) in emitters.iter().enumerate() {
        for v in mesh.corners(e.triangle as usize) {
            let j = *at.entry(key(v)).or_insert(i);
            sets.union(i as u32, j as u32);
        }
    }
    let mut groups: HashMap<u32, Vec<usize>> = HashMap::new();
    for i in 0..emitters.len() {
        groups.entry(sets.find(i as u32)).or_default().push(i);
    }
    let mut g: Vec<Vec<usize>> = groups.into_values().collect();
    g.sort();
    g
}

/// Solves the radiance of the clipped lamps among `emitters` and sets it; returns the report.
/// `store` holds the pixels with the baked shadings, `tr` a fit on them (which pixels are rough
/// dielectrics), `exposures` the train frames' (a clipped channel's lower bound is 1/e).
#[allow(clippy::too_many_arguments)]
pub fn solve_clipped(
    mesh: &Mesh,
    accel: &Accel,
    light_field: &LightField,
    train: &Split,
    exposures: &[f64],
    hits: &[ViewHits],
    store: &PixelStore,
    tr: &Trainer,
    emitters: &mut [Emitter],
    cfg: SolveConfig,
) -> LightSolve {
    let groups = lamps(mesh, emitters);
    let mut lamp_of_tri: HashMap<u32, usize> = HashMap::new();
    for (g, members) in groups.iter().enumerate() {
        for &i in members {
            lamp_of_tri.insert(emitters[i].triangle, g);
        }
    }
    // Each lamp's photo pixels: count, clipped count, mean linear value.
    let mut seen = vec![(0usize, 0usize, [0.0f64; 3]); groups.len()];
    for ((v, h), &e) in train.views.iter().zip(hits).zip(exposures) {
        let Some(f) = &v.ldr else { continue };
        for p in 0..h.num_pixels() {
            if let Some(&g) = u32::try_from(h.tri[p])
                .ok()
                .and_then(|t| lamp_of_tri.get(&t))
            {
                seen[g].0 += 1;
                seen[g].1 += f.pixel_clipped(p) as usize;
                for c in 0..3 {
                    // A clipped channel's clip level (its value before a fill).
                    seen[g].2[c] += if f.clipped(p, c) {
                        1.0 / e
                    } else {
                        v.image.data[3 * p + c] as f64
                    };
                }
            }
        }
    }
    let area_mean = |g: &[usize]| {
        let a: f32 = g.iter().map(|&i| emitters[i].area).sum();
        let mut m = [0.0f32; 3];
        for &i in g {
            for (c, mc) in m.iter_mut().enumerate() {
                *mc += emitters[i].radiance[c] * emitters[i].area / a.max(1e-12);
            }
        }
        m
    };
    let clipped: Vec<usize> = (0..groups.len())
        .filter(|&g| seen[g].0 > 0 && seen[g].1 * 2 >= seen[g].0)
        .collect();
    let mut report = LightSolve {
        lamps: groups
            .iter()
            .enumerate()
            .map(|(g, m)| LampReport {
                triangles: m.iter().map(|&i| emitters[i].triangle).collect(),
                solved_clipped: false,
                pixels: seen[g].0,
                clipped_share: seen[g].1 as f64 / seen[g].0.max(1) as f64,
                extracted: area_mean(m),
                solved: area_mean(m),
            })
            .collect(),
        ..Default::default()
    };
    if clipped.is_empty() {
        return report;
    }
    // T_k: the clip level the lamp's pixels read (what L′ holds there).
    let level: Vec<[f64; 3]> = clipped
        .iter()
        .map(|&g| seen[g].2.map(|s| s / seen[g].0 as f64))
        .collect();

    // The pixels of the solve: unclipped, not on an emitter, fitted rough dielectric.
    let mat = tr.model.material(&store.pixels.x_unit, &store.pixels.part);
    let cand: Vec<usize> = (0..store.len())
        .filter(|&i| {
            let (k, p) = store.origin[i];
            let v = &train.views[k as usize];
            let tri = hits[k as usize].tri[p as usize];
            mat.sigma[i] >= 0.6
                && mat.metallic[i] <= 0.2
                && !lamp_of_tri.contains_key(&(tri as u32))
                && v.ldr.as_ref().is_some_and(|f| !f.pixel_clipped(p as usize))
        })
        .collect();
    let stride = (cand.len() / cfg.pixels.max(1)).max(1);
    let chosen: Vec<usize> = cand.iter().step_by(stride).copied().collect();
    // Parts: the segment ids, else triangles.
    let seg = &store.pixels.seg;
    let has_parts = seg.iter().any(|&s| s != seg[0]);
    let part_key = |i: usize| {
        if has_parts {
            store.pixels.seg[i] as i64
        } else {
            let (k, p) = store.origin[i];
            (1 << 40) + hits[k as usize].tri[p as usize] as i64
        }
    };
    let mut part_ids: HashMap<i64, usize> = HashMap::new();
    let part: Vec<usize> = chosen
        .iter()
        .map(|&i| {
            let n = part_ids.len();
            *part_ids.entry(part_key(i)).or_insert(n)
        })
        .collect();
    let n_parts = part_ids.len();

    let lamp_tris: Vec<Vec<u32>> = clipped
        .iter()
        .map(|&g| groups[g].iter().map(|&i| emitters[i].triangle).collect())
        .collect();
    let terms = light_terms(
        mesh,
        accel,
        light_field,
        hits,
        store,
        &chosen,
        &lamp_tris,
        cfg,
    );
    let pixels: Vec<SolvePixel> = chosen
        .iter()
        .zip(part)
        .zip(terms)
        .map(|((&i, part), t)| {
            let (k, p) = store.origin[i];
            let f = train.views[k as usize].ldr.as_ref().expect("LDR views");
            let e = exposures[k as usize];
            SolvePixel {
                code: [0, 1, 2].map(|c| f.value(p as usize, c)),
                value: [0, 1, 2].map(|c| store.pixels.gt[3 * i + c] as f64 * e),
                exposure: e,
                part,
                direct: t.direct,
                lprime: t.lprime,
                // One light sample has no second half to be its instrument.
                direct_half: if cfg.instruments && cfg.light_samples >= 2 {
                    t.direct_half
                } else {
                    Vec::new()
                },
            }
        })
        .collect();
    // Too few pixels say nothing of the response: the linearisation stands.
    let solved =
        if cfg.estimate_response && !clipped.is_empty() && pixels.len() >= MIN_RESPONSE_PIXELS {
            let fit = super::response::estimate(&pixels, n_parts, &level, cfg.exposures_estimated);
            let le = fit.radiance.clone();
            report.response = Some(fit);
            le
        } else {
            super::response::solve_radiance(&pixels, n_parts, &level, [1.0; 3], false)
        };
    for (k, &g) in clipped.iter().enumerate() {
        let solved = solved[k].map(|x| x as f32);
        for &i in &groups[g] {
            emitters[i].radiance = solved;
        }
        report.lamps[g].solved = solved;
        report.lamps[g].solved_clipped = true;
    }
    report.pixels = pixels.len();
    report.parts = n_parts;
    report
}

/// The fewest solve pixels the response is estimated from.
const MIN_RESPONSE_PIXELS: usize = 1000;

/// Rounds of the alternation.
pub const ALTERNATIONS: usize = 200;

/// The light terms of one solve pixel (`SolvePixel`'s fields of the same names).
struct LightTerms {
    direct: Vec<f32>,
    direct_half: Vec<[f32; 2]>,
    lprime: Vec<[f32; 3]>,
}

/// Per chosen pixel: D_k for every lamp of `lamp_tris` (irradiance/π at unit radiance, area
/// sampling with visibility), D_k from each half of those samples, and the samples of E (L′ at
/// the ends of cosine-sampled directions, zero where one ends on one of those lamps or leaves
/// the scene; E is their mean).
#[allow(clippy::too_many_arguments)]
fn light_terms(
    mesh: &Mesh,
    accel: &Accel,
    light_field: &LightField,
    hits: &[ViewHits],
    store: &PixelStore,
    chosen: &[usize],
    lamp_tris: &[Vec<u32>],
    cfg: SolveConfig,
) -> Vec<LightTerms> {
    let lamp_cdf: Vec<(Vec<f32>, f32)> = lamp_tris
        .iter()
        .map(|ts| {
            let mut acc = 0.0;
            let cdf = ts
                .iter()
                .map(|&t| {
                    acc += mesh.area(t as usize);
                    acc
                })
                .collect();
            (cdf, acc)
        })
        .collect();
    use rayon::prelude::*;
    let clipped_tri: std::collections::HashSet<u32> = lamp_tris.iter().flatten().copied().collect();
    chosen
        .par_iter()
        .enumerate()
        .map(|(j, &i)| {
            let (k, p) = store.origin[i];
            let h = &hits[k as usize];
            let x = h.position[p as usize];
            let n = h.normal[p as usize];
            let mut rng = Rng::new(cfg.seed, j as u64);
            // E: cosine-weighted directions, L′ where they end on anything but a clipped lamp.
            let frame = fipt_core::brdf::Frame::new(n);
            let ne = 2 * cfg.light_samples;
            let mut e = vec![[0.0f32; 3]; ne];
            for es in e.iter_mut() {
                let w = frame.to_world(fipt_core::brdf::sample_cosine(
                    rng.next_f32(),
                    rng.next_f32(),
                ));
                let o = x + n * 1e-4;
                if let Some(hit) = accel.closest(o, w, 0.0, f32::INFINITY)
                    && !clipped_tri.contains(&hit.tri)
                {
                    let y = o + w * hit.t;
                    let l = light_field.query(y, accel.facing_normal(hit.tri, w));
                    *es = [l[0].max(0.0), l[1].max(0.0), l[2].max(0.0)];
                }
            }
            let (direct, direct_half): (Vec<f32>, Vec<[f32; 2]>) = lamp_tris
                .iter()
                .zip(&lamp_cdf)
                .map(|(ts, (cdf, total))| {
                    let mut sum = [0.0f32; 2];
                    for i in 0..cfg.light_samples {
                        let u = rng.next_f32() * total;
                        let t = ts[cdf.partition_point(|&c| c < u).min(ts.len() - 1)] as usize;
                        let (mut a, mut b) = (rng.next_f32(), rng.next_f32());
                        if a + b > 1.0 {
                            (a, b) = (1.0 - a, 1.0 - b);
                        }
                        let y = mesh.point_at(t, a, b);
                        let d = y - x;
                        let r2 = d.length_squared();
                        if r2 < 1e-10 {
                            continue;
                        }
                        let w = d / r2.sqrt();
                        let cos_x = n.dot(w);
                        let cos_l = mesh.normal(t).dot(-w).abs();
                        if cos_x <= 0.0 {
                            continue;
                        }
                        let eps = 1e-4 * r2.sqrt().max(1.0);
                        if accel.occluded(x + n * eps, w, 0.0, r2.sqrt() * (1.0 - 1e-3)) {
                            continue;
                        }
                        sum[usize::from(2 * i >= cfg.light_samples)] += cos_x * cos_l / r2;
                    }
                    // Samples i < n/2 form the first half.
                    let n = cfg.light_samples;
                    let counts = [n.div_ceil(2), n / 2];
                    let norm = |s: f32, count: usize| {
                        s * total / (std::f32::consts::PI * count.max(1) as f32)
                    };
                    (
                        norm(sum[0] + sum[1], n),
                        [0, 1].map(|h| norm(sum[h], counts[h])),
                    )
                })
                .unzip();
            LightTerms {
                direct,
                direct_half,
                lprime: e,
            }
        })
        .collect()
}

/// The alternating solve of one channel: the part albedos k_P for the current radiance, then
/// the radiance Le_k ≥ T_k for the current albedos (normal equations, projected), on relative
/// residuals with Cauchy weights; `rounds` rounds. Returns (Le_k, k_P).
///
/// Errors in variables: D_k and E are Monte Carlo estimates, and noise in a regressor x
/// biases least squares, whose Σ w·x² holds the noise's variance (k_P low, then Le_k high).
/// Where the pixels carry two independent halves of the estimates, each half is the instrument
/// z of the other half's x, Σ w·z·x in place of Σ w·x² (instrumental variables, symmetrised
/// over the halves). The Cauchy weights of the sums with instrument half h are read from half
/// h's residuals, and the light the lamps must explain from the other half's E, so that
/// neither depends on x's noise. Without halves both are the whole estimate: ordinary least
/// squares.
pub fn alternate(
    t: &super::response::ChannelTerms,
    pixels: &[SolvePixel],
    n_parts: usize,
    rounds: usize,
) -> (Vec<f64>, Vec<f64>) {
    let nk = t.level.len();
    let (obs, level) = (&t.obs, &t.level);
    let mut le: Vec<f64> = level.clone();
    let mut kd = vec![0.5f64; n_parts];
    let half = |j: usize, le: &[f64], h: usize| t.shading_half(j, &pixels[j], le, h);
    // Relative residuals, with Cauchy weights (scale 10 %) against outliers: highlights,
    // textures within a part. One set per half.
    let mut w = [vec![0.0f64; obs.len()], vec![0.0f64; obs.len()]];
    for it in 0..rounds {
        for (h, w) in w.iter_mut().enumerate() {
            for (j, wj) in w.iter_mut().enumerate() {
                let o = obs[j].max(1e-3);
                let rel = if it == 0 {
                    0.0
                } else {
                    (obs[j] - kd[pixels[j].part] * half(j, &le, h)) / o
                };
                *wj = 1.0 / (o * o * (1.0 + (rel / 0.1).powi(2)));
            }
        }
        // k_P for the current radiance: Σ w·z·I / Σ w·z·x.
        let (mut num, mut den) = (vec![0.0; n_parts], vec![0.0; n_parts]);
        for j in 0..obs.len() {
            let s = [half(j, &le, 0), half(j, &le, 1)];
            let q = pixels[j].part;
            for h in 0..2 {
                num[q] += w[h][j] * obs[j] * s[h];
                den[q] += w[h][j] * s[h] * s[1 - h];
            }
        }
        for q in 0..n_parts {
            if den[q] > 0.0 {
                kd[q] = (num[q] / den[q]).clamp(1e-3, 1.0);
            }
        }
        if nk == 0 {
            continue;
        }
        // Le for the current albedos: the normal equations, projected onto Le ≥ T. Lamp k's
        // column is k_P·D_k.
        let mut a = vec![vec![0.0f64; nk]; nk];
        let mut b = vec![0.0f64; nk];
        let mut col = [vec![0.0f64; nk], vec![0.0f64; nk]];
        for (j, px) in pixels.iter().enumerate() {
            let kq = kd[px.part];
            for (h, col) in col.iter_mut().enumerate() {
                for (k, ck) in col.iter_mut().enumerate() {
                    *ck = kq * px.direct_of(k, h) as f64;
                }
            }
            for h in 0..2 {
                let r = obs[j] - kq * t.rest_half[j][1 - h];
                for k in 0..nk {
                    b[k] += w[h][j] * col[h][k] * r;
                    for l in 0..nk {
                        a[k][l] += w[h][j] * col[h][k] * col[1 - h][l];
                    }
                }
            }
        }
        for _ in 0..20 {
            for k in 0..nk {
                if a[k][k] <= 0.0 {
                    continue;
                }
                let off: f64 = (0..nk).filter(|&l| l != k).map(|l| a[k][l] * le[l]).sum();
                le[k] = ((b[k] - off) / a[k][k]).max(level[k]);
            }
        }
    }
    (le, kd)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Pixels whose light terms are noisy Monte Carlo estimates: D_k from two halves of the
    /// samples, each the truth times (1 + noise) with the noise uniform in ±30 %, and E from
    /// 16 samples spread ±30 % about the truth. The photos hold the true terms.
    fn noisy_scene(seed: u64) -> (Vec<SolvePixel>, usize, Vec<[f64; 3]>) {
        let mut rng = Rng::new(seed, 0);
        let kd: Vec<[f64; 3]> = (0..5)
            .map(|_| [0, 1, 2].map(|_| 0.2 + 0.6 * rng.next_f32() as f64))
            .collect();
        let le = [[30.0, 20.0, 10.0], [8.0, 12.0, 20.0]];
        let mut noise = |x: f32| x * (1.0 + 0.6 * (rng.next_f32() - 0.5));
        let pixels = (0..6000)
            .map(|j| {
                let part = j % 5;
                let truth: Vec<f32> = (0..2)
                    .map(|k| 0.02 * ((j * 7 + k * 3) % 11) as f32 / 10.0)
                    .collect();
                let e_true = [0.2f32, 0.25, 0.3];
                let direct_half: Vec<[f32; 2]> =
                    truth.iter().map(|&d| [noise(d), noise(d)]).collect();
                let lprime: Vec<[f32; 3]> = (0..16).map(|_| e_true.map(&mut noise)).collect();
                let value = [0, 1, 2].map(|c| {
                    let s =
                        e_true[c] as f64 + (0..2).map(|k| le[k][c] * truth[k] as f64).sum::<f64>();
                    kd[part][c] * s
                });
                SolvePixel {
                    code: value,
                    value,
                    exposure: 1.0,
                    part,
                    direct: direct_half.iter().map(|d| 0.5 * (d[0] + d[1])).collect(),
                    lprime,
                    direct_half,
                }
            })
            .collect();
        (pixels, 5, le.to_vec())
    }

    #[test]
    fn instruments_remove_the_bias_of_noisy_light_terms() {
        let (pixels, parts, le) = noisy_scene(5);
        let level = vec![[0.1; 3]; 2];
        // The lamps' mean ratio to the truth over channels.
        let ratio = |px: &[SolvePixel]| {
            let fit = super::super::response::solve_radiance(px, parts, &level, [1.0; 3], false);
            let r: Vec<f64> = fit
                .iter()
                .zip(&le)
                .flat_map(|(f, t)| (0..3).map(move |c| f[c] / t[c]))
                .collect();
            r.iter().sum::<f64>() / r.len() as f64
        };
        // The same pixels without their halves: ordinary least squares on the whole estimates.
        let plain: Vec<SolvePixel> = pixels
            .iter()
            .map(|p| SolvePixel {
                direct_half: Vec::new(),
                ..p.clone()
            })
            .collect();
        let without = ratio(&plain);
        let with = ratio(&pixels);
        assert!(
            (with - 1.0).abs() < 0.02,
            "with instruments: {with} (without {without})"
        );
        assert!(
            (without - 1.0).abs() > 0.04,
            "ordinary least squares: {without}"
        );
    }
}
