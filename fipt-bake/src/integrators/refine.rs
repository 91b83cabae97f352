//! Shading refinement (paper §4.3, Eq. 10–11; reference §2.5): the shadings of every training
//! pixel re-estimated by path tracing with the current BRDF estimate and the extracted emitters,
//! in place of the bake's one-bounce L′ lookups (Eq. 9).
//!
//! Per pixel, from its pixel-centre first hit x (or its footprint's points, `footprint`):
//! cosine-sampled rays for L_d and GGX-sampled rays at each roughness level σ_j with the
//! weights g0, g1 for L_s0, L_s1 (exactly the bake's estimators); the radiance arriving along
//! each ray is a path traced through the scene (`PathScene::trace_paths` from segment 2):
//! emitters end paths and do not reflect, a hit on a surface rougher than the cache threshold
//! returns L′ there, every other hit continues with next-event estimation (MIS) and BRDF
//! sampling until `max_depth`. At x itself the reference samples the BRDF only; with
//! `light_samples` > 0 the emitters are also sampled there, each estimator's two strategies
//! combined by the power heuristic. The result is filtered as the bake's. The oracle shadings
//! (true materials and emitters) go through the same estimators and config.
//!
//! Random numbers come from (seed, view, pixel, sample): bit-identical for any thread count.
//!
//! Owns: the refined estimators and their configuration. Must not touch: where the materials
//! and emitters come from, files.

use super::bake::{BakeSamples, RAY_EPS, filter_groups};
use super::path::{PathConfig, PathScene, PathStart, PathStats, power_heuristic};
use crate::accel::footprint::{SurfacePoint, ViewFootprint, point_of_sample};
use crate::accel::raycast::ViewHits;
use fipt_core::brdf::{
    Frame, LobeChoice, cosine_pdf, fresnel_split, g_schlick_over, ggx_d, ggx_reflection_pdf,
    roughness_levels, sample_cosine, sample_specular,
};
use fipt_core::rng::Rng;
use fipt_core::shading::ShadingLayout;
use glam::Vec3;
use rayon::prelude::*;

/// Refinement settings; the defaults are the reference's.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct RefineConfig {
    /// Rays per pixel for L_d and per roughness level (reference: 128 and 64).
    pub samples: BakeSamples,
    /// Path length in segments, counting the camera segment (reference: 2 + indir_depth 5).
    pub max_depth: usize,
    /// Secondary hits rougher than this return L′ (reference: 0.6; > 1 turns the cache off).
    pub cache_roughness: f32,
    /// The training pixels within this many pixels (the 8-neighbourhood, repeated) of one
    /// that shows an emitter, and those that show one, leave L′ before it serves as the
    /// radiance cache (0: every pixel, the reference). The ring's footprint takes in part of
    /// the emitter, so it would light the scene as a ring of emitter around each one. Applied
    /// by the caller that builds L′.
    pub cache_margin: usize,
    /// L′, as the radiance cache, holds the photos less the specular radiance that the last
    /// fit predicts at each pixel (k_s·L_s0(σ) + L_s1(σ) on its shadings), rebuilt for every
    /// refinement (false: the photos, the reference). A photo's specular part belongs to its
    /// camera's direction, and a path reads the cache from another. Applied by the caller
    /// that builds L′.
    #[serde(default)]
    pub cache_diffuse: bool,
    /// BRDF sampling at path vertices (reference: `half`).
    pub lobe: LobeChoice,
    /// Light samples per pixel at the first hit x, shared by all 13 estimators and combined
    /// with their BRDF samples by the power heuristic (0: the reference, BRDF sampling only at
    /// x). A departure: a small emitter that cosine or GGX samples rarely find is then
    /// sampled directly, which removes most of the noise of the shadings next to it.
    pub light_samples: usize,
    /// Emitters emit from both sides (`false`: the reference) or only from the sides the
    /// photos saw them from (`true`).
    pub observed_sides: bool,
    /// Shadings over the pixel's footprint, as the bake's `footprint` (0: at the pixel-centre
    /// hit, the reference): the n of the n×n grid whose hits on the centre's part the
    /// estimators' samples start from.
    #[serde(default)]
    pub footprint: usize,
    /// A part seen in n < `small_parts` training pixels (over all views) has its pixels
    /// estimated ⌈`small_parts` / n⌉ times, at most `SMALL_PART_PASSES`, with fresh random
    /// streams, and averaged (0: once, the reference). A part's σ is decided over its pixels,
    /// and the noise of a few pixels' sharp levels, which the filter cannot average within a
    /// small surface, decides it for a small part. Applied by the caller (`refine_view`'s
    /// `passes`).
    #[serde(default)]
    pub small_parts: u32,
    /// Path vertices where no photo saw the surface read their part's mean fitted material
    /// (`materials::Unseen`) instead of the field, which nothing constrained there: "seen" is
    /// a cell of about this many L′ voxels a side (⌈res / c⌉ cells across the scene box) that
    /// holds a training pixel's first hit (0: the field everywhere, the reference). Applied by
    /// the caller that builds the materials; the oracle ignores it.
    #[serde(default)]
    pub unseen_cell: usize,
    /// More paths on the sharp levels for the pixels whose last fit is sharp there (None: the
    /// same paths for every pixel, the reference). The unfiltered sharp levels' noise decides
    /// a glossy part's σ, and only the pixels fitted glossy read those levels much. Applied by
    /// the caller (`refine_view`'s `sharp`).
    #[serde(default)]
    pub sharp: Option<SharpSamples>,
    /// The filter on the result (the reference denoises all 13 images).
    pub filter: crate::filter::FilterConfig,
    /// Paths per wavefront (memory bound only).
    pub wave: usize,
    /// Random seed (set from the run's seed and round, not read from config files).
    #[serde(skip)]
    pub seed: u64,
}

impl Default for RefineConfig {
    fn default() -> Self {
        Self {
            samples: BakeSamples {
                diffuse: 128,
                specular: [64; 6],
            },
            max_depth: 7,
            cache_roughness: 0.6,
            cache_margin: 0,
            cache_diffuse: false,
            lobe: LobeChoice::Half,
            light_samples: 0,
            observed_sides: false,
            footprint: 0,
            small_parts: 0,
            unseen_cell: 0,
            sharp: None,
            filter: crate::filter::FilterConfig {
                specular_levels: (0..6).collect(),
                ..Default::default()
            },
            wave: 1 << 18,
            seed: 0,
        }
    }
}

/// The GGX paths per roughness level of a sharp pixel (`RefineConfig::sharp`).
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SharpSamples {
    /// A pixel whose last fit has σ below this at its first hit is sharp.
    pub below: f32,
    /// GGX paths per roughness level for a sharp pixel, in place of `samples.specular`.
    pub specular: [usize; fipt_core::brdf::ROUGHNESS_LEVELS],
}

/// The most estimates a pixel of a small part gets (`RefineConfig::small_parts`).
pub const SMALL_PART_PASSES: u32 = 16;

impl RefineConfig {
    /// How many estimates a pixel of a part seen in `n` training pixels gets.
    pub fn passes_for(&self, n: usize) -> u32 {
        if self.small_parts == 0 || n == 0 || n >= self.small_parts as usize {
            return 1;
        }
        (self.small_parts as usize)
            .div_ceil(n)
            .min(SMALL_PART_PASSES as usize) as u32
    }

    fn path_config(&self) -> PathConfig {
        PathConfig {
            spp: 1,
            max_depth: self.max_depth,
            rr_depth: None,
            emitters_reflect: false,
            lobe: self.lobe,
            wave: self.wave,
            seed: self.seed,
            pixel_positions: 0,
        }
    }
}

/// Which shading a first-bounce ray feeds and with what weights.
#[derive(Clone, Copy)]
enum Slot {
    Diffuse,
    /// Level j, weights g0 and g1.
    Specular(usize, f32, f32),
}

/// The first-bounce ray of a sample of L_d (`level` None) or of level j's L_s0, L_s1
/// (`Some(j)`) at a point (frame about the facing normal, outgoing direction in the local
/// frame): its slot, world direction and solid-angle pdf, or None below the horizon.
fn first_bounce(
    level: Option<usize>,
    frame: &Frame,
    wo_l: Vec3,
    rng: &mut Rng,
) -> Option<(Slot, Vec3, f32)> {
    let (u1, u2) = (rng.next_f32(), rng.next_f32());
    let Some(j) = level else {
        let wi = sample_cosine(u1, u2);
        return Some((Slot::Diffuse, frame.to_world(wi), cosine_pdf(wi.z)));
    };
    let sigma = roughness_levels()[j];
    let (wi, g0, g1) = sample_specular(wo_l, sigma, u1, u2)?;
    let pdf = ggx_reflection_pdf(wo_l, wi, sigma);
    Some((
        Slot::Specular(j, g0, g1),
        frame.to_world(wi).normalize(),
        pdf,
    ))
}

/// The estimator that sample `s` of a pixel feeds (L_d's samples first, then each level's:
/// None for L_d, `Some(j)` for level j), the sample's index within it and its sample count.
fn estimator_of(samples: &BakeSamples, s: usize) -> (Option<usize>, usize, usize) {
    if s < samples.diffuse {
        return (None, s, samples.diffuse);
    }
    let mut k = s - samples.diffuse;
    for (j, &n) in samples.specular.iter().enumerate() {
        if k < n {
            return (Some(j), k, n);
        }
        k -= n;
    }
    unreachable!("sample {s} beyond the pixel's {}", samples.rays_per_pixel())
}

/// The integrands of L_s0 and L_s1 at roughness σ for a direction ω_i (local frame), per unit
/// incoming radiance: D·G_s·F0·(n·l)/4 and D·G_s·F1·(n·l)/4 (Eq. 7–8).
fn specular_integrands(wo: Vec3, wi: Vec3, sigma: f32) -> (f32, f32) {
    if wi.z <= 0.0 || wo.z <= 0.0 {
        return (0.0, 0.0);
    }
    let h = (wo + wi).normalize();
    let base = ggx_d(h.z, sigma) * g_schlick_over(wo.z, wi.z, sigma) * wi.z / 4.0;
    let (f0, f1) = fresnel_split(wo.dot(h));
    (base * f0, base * f1)
}

/// The light samples taken at one pixel's footprint: its points (shared equally,
/// `point_of_sample`), how many light samples (`count`), and the estimators' BRDF sample counts
/// (`samples`) that the power heuristic weighs them against.
#[derive(Clone, Copy)]
struct LightQuery<'a> {
    pts: &'a [SurfacePoint],
    samples: &'a BakeSamples,
    count: usize,
}

/// The light-sampled part of every estimator at one pixel (`q`): each light sample weighted by
/// the power heuristic against the estimator's BRDF samples; added to `acc`. Returns the
/// shadow rays cast.
fn light_sampled(
    scene: &PathScene,
    q: &LightQuery,
    rng: &mut Rng,
    acc: &mut [f32; ShadingLayout::DIM],
) -> u64 {
    let LightQuery {
        pts,
        samples,
        count,
    } = *q;
    let nl = count as f32;
    let mut rays = 0;
    for i in 0..count {
        let SurfacePoint { x, n, wo } = pts[point_of_sample(i, count, pts.len())];
        let frame = Frame::new(n);
        let wo_l = frame.to_local(wo);
        let u = (rng.next_f32(), rng.next_f32(), rng.next_f32());
        let (sample, shadow) = scene.sample_light(x, n, u);
        rays += shadow;
        let Some(s) = sample else {
            continue;
        };
        let wi_l = frame.to_local(s.wi);
        let p_light = s.pdf;
        let l = s.radiance / (p_light * nl);
        // L_d: integrand cos/π, BRDF pdf cos/π.
        let pd = cosine_pdf(wi_l.z);
        let w = power_heuristic(nl * p_light, samples.diffuse as f32 * pd);
        for c in 0..3 {
            acc[ShadingLayout::LD.start + c] += l[c] * pd * w;
        }
        for (j, sigma) in roughness_levels().into_iter().enumerate() {
            let (f0, f1) = specular_integrands(wo_l, wi_l, sigma);
            if f0 + f1 <= 0.0 {
                continue;
            }
            let pj = ggx_reflection_pdf(wo_l, wi_l, sigma);
            let w = power_heuristic(nl * p_light, samples.specular[j] as f32 * pj);
            let (s0, s1) = (ShadingLayout::ls0(j).start, ShadingLayout::ls1(j).start);
            for c in 0..3 {
                acc[s0 + c] += l[c] * f0 * w;
                acc[s1 + c] += l[c] * f1 * w;
            }
        }
    }
    rays
}

/// How `refine_view` spends its paths per pixel of a view (None: as on every other pixel).
#[derive(Clone, Copy, Default)]
pub struct PixelPaths<'a> {
    /// Estimates averaged, one count per pixel (`RefineConfig::small_parts`; None: 1 each).
    pub passes: Option<&'a [u32]>,
    /// The pixels that take `RefineConfig::sharp`'s paths per level (ignored while that is
    /// None).
    pub sharp: Option<&'a [bool]>,
}

/// Refines the shadings of one view (`ShadingLayout::DIM` values per pixel, zeros where the
/// pixel-centre ray missed), filtered; each pixel's samples start from the points of its
/// footprint `fp`, each estimator's shared equally (`point_of_sample`;
/// `ViewFootprint::centres` for the reference). `view_key` separates views in the random
/// streams and `focal` is the view's focal length in pixels (for the filter). `per_pixel`'s
/// `passes` repeats a pixel's estimators with fresh random streams and averages them: that
/// many times the samples, for the pixels of small parts (`RefineConfig::small_parts`); its
/// `sharp` flags give a pixel `RefineConfig::sharp`'s paths per level.
pub fn refine_view(
    scene: &PathScene,
    hits: &ViewHits,
    fp: &ViewFootprint,
    focal: f32,
    cfg: &RefineConfig,
    view_key: u64,
    per_pixel: PixelPaths,
) -> (Vec<f32>, PathStats) {
    let PixelPaths { passes, sharp } = per_pixel;
    let dim = ShadingLayout::DIM;
    let mut out = vec![0f32; hits.num_pixels() * dim];
    let mut stats = PathStats::default();
    let count = |p: usize| passes.map_or(1, |n| n[p].max(1));
    let most = (0..hits.num_pixels()).map(count).max().unwrap_or(1);
    // A sharp pixel's estimators take `cfg.sharp`'s paths per level (`RefineConfig::sharp`).
    let sharp_samples = cfg.sharp.as_ref().zip(sharp).map(|(s, _)| BakeSamples {
        specular: s.specular,
        ..cfg.samples
    });
    let is_sharp = |p: usize| sharp_samples.is_some() && sharp.is_some_and(|f| f[p]);
    for pass in 0..most {
        let (plain, sharp_px): (Vec<usize>, Vec<usize>) = (0..hits.num_pixels())
            .filter(|&p| hits.tri[p] >= 0 && count(p) > pass)
            .partition(|&p| !is_sharp(p));
        // Pass 0 draws the streams of a run without passes.
        let seed = cfg
            .seed
            .wrapping_add((pass as u64).wrapping_mul(0x9e37_79b9_7f4a_7c15));
        let pcfg = RefineConfig {
            seed,
            ..cfg.clone()
        };
        accumulate(scene, fp, &pcfg, view_key, &plain, &mut out, &mut stats);
        if let Some(samples) = sharp_samples.clone().filter(|_| !sharp_px.is_empty()) {
            let scfg = RefineConfig { samples, ..pcfg };
            accumulate(scene, fp, &scfg, view_key, &sharp_px, &mut out, &mut stats);
        }
    }
    if most > 1 {
        for (p, px) in out.chunks_mut(dim).enumerate() {
            let inv = 1.0 / count(p) as f32;
            px.iter_mut().for_each(|v| *v *= inv);
        }
    }
    crate::filter::filter_view(
        &cfg.filter,
        hits,
        focal,
        &mut out,
        dim,
        &filter_groups(&cfg.filter),
    );
    (out, stats)
}

/// Adds one estimate of the shadings of `pixels` to `out` (`ShadingLayout::DIM` per pixel), with
/// `cfg`'s samples and random streams.
fn accumulate(
    scene: &PathScene,
    fp: &ViewFootprint,
    cfg: &RefineConfig,
    view_key: u64,
    pixels: &[usize],
    out: &mut [f32],
    stats: &mut PathStats,
) {
    let dim = ShadingLayout::DIM;
    let per_pixel = cfg.samples.rays_per_pixel();
    let pcfg = cfg.path_config();
    let nl = if scene.emitters.is_empty() {
        0
    } else {
        cfg.light_samples
    };
    let chunk = (cfg.wave / per_pixel.max(1)).max(1);
    let inv_d = 1.0 / cfg.samples.diffuse.max(1) as f32;
    let inv_s: Vec<f32> = cfg
        .samples
        .specular
        .iter()
        .map(|&n| 1.0 / n.max(1) as f32)
        .collect();
    for px in pixels.chunks(chunk) {
        let (slots, starts): (Vec<Option<Slot>>, Vec<Option<PathStart>>) = (0..px.len()
            * per_pixel)
            .into_par_iter()
            .map(|i| {
                let (p, s) = (px[i / per_pixel], i % per_pixel);
                let mut rng = Rng::new(cfg.seed, (view_key << 44) | ((p as u64) << 20) | s as u64);
                let pts = fp.of(p);
                let (level, i, count) = estimator_of(&cfg.samples, s);
                let q = pts[point_of_sample(i, count, pts.len())];
                let frame = Frame::new(q.n);
                let wo_l = frame.to_local(q.wo);
                match first_bounce(level, &frame, wo_l, &mut rng) {
                    Some((slot, wi, pdf)) => (
                        Some(slot),
                        Some(PathStart {
                            origin: q.x + wi * RAY_EPS,
                            dir: wi,
                            rng,
                            // MIS against the light samples, counts folded into the pdf.
                            pdf: if nl > 0 {
                                count as f32 * pdf / nl as f32
                            } else {
                                0.0
                            },
                        }),
                    ),
                    None => (None, None),
                }
            })
            .unzip();
        let (radiance, st) = scene.trace_paths(starts, &pcfg, 2);
        stats.add(&st);
        // Each pixel's samples are contiguous: accumulate them in order, after the light
        // samples.
        let results: Vec<(usize, [f32; ShadingLayout::DIM], u64)> = px
            .par_iter()
            .enumerate()
            .map(|(k, &p)| {
                let mut acc = [0f32; ShadingLayout::DIM];
                let mut shadow = 0;
                if nl > 0 {
                    let mut rng = Rng::new(cfg.seed ^ 0x11_9447, (view_key << 32) | p as u64);
                    let q = LightQuery {
                        pts: fp.of(p),
                        samples: &cfg.samples,
                        count: nl,
                    };
                    shadow = light_sampled(scene, &q, &mut rng, &mut acc);
                }
                for i in k * per_pixel..(k + 1) * per_pixel {
                    let l = radiance[i];
                    match slots[i] {
                        Some(Slot::Diffuse) => {
                            for c in 0..3 {
                                acc[ShadingLayout::LD.start + c] += l[c] * inv_d;
                            }
                        }
                        Some(Slot::Specular(j, g0, g1)) => {
                            let (s0, s1) =
                                (ShadingLayout::ls0(j).start, ShadingLayout::ls1(j).start);
                            for c in 0..3 {
                                acc[s0 + c] += l[c] * g0 * inv_s[j];
                                acc[s1 + c] += l[c] * g1 * inv_s[j];
                            }
                        }
                        None => {}
                    }
                }
                (p, acc, shadow)
            })
            .collect();
        for (p, acc, shadow) in results {
            for (o, a) in out[p * dim..(p + 1) * dim].iter_mut().zip(acc) {
                *o += a;
            }
            stats.shadow_rays += shadow;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::emitters::{EmitterSet, LightSelection};
    use crate::integrators::bake::tests::{FLOOR_X, floor_form_factor, lit_box};
    use crate::integrators::path::RadianceCache;
    use crate::materials::{MaterialSource, SurfaceMaterial};

    struct Uniform(f32);
    impl MaterialSource for Uniform {
        fn query(&self, points: &[Vec3], _tris: &[u32], out: &mut Vec<SurfaceMaterial>) {
            out.clear();
            out.extend(points.iter().map(|_| SurfaceMaterial {
                base_color: Vec3::splat(0.8),
                roughness: self.0,
                metallic: 0.0,
            }));
        }
    }

    /// L_d at the floor point of a closed unit box whose ceiling is an emitter of radiance 1
    /// and whose other walls carry L′ = `cache_value` and the roughness `sigma`; 12 runs.
    fn floor_ld(sigma: f32, cache_value: f32, max_depth: usize) -> Vec<f64> {
        floor_shadings(&[FLOOR_X], sigma, cache_value, max_depth, 0, 4096, 1)
            .iter()
            .map(|s| s[0] as f64)
            .collect()
    }

    /// The whole shading vector of 12 runs, with `light_samples` at x and `spp` BRDF samples
    /// per estimator, averaged over `passes` estimates (1: `refine_view` without passes).
    fn floor_shadings(
        floor: &[Vec3],
        sigma: f32,
        cache_value: f32,
        max_depth: usize,
        light_samples: usize,
        spp: usize,
        passes: u32,
    ) -> Vec<Vec<f32>> {
        let cfg = RefineConfig {
            samples: BakeSamples {
                diffuse: spp,
                specular: [spp; 6],
            },
            max_depth,
            light_samples,
            ..Default::default()
        };
        floor_view(floor, 1, sigma, cache_value, &cfg, passes, None)
    }

    /// 12 runs of `refine_view` (seeds 0–11, `cfg` otherwise, unfiltered) over a view of
    /// `width` pixels that all see the floor's footprint `floor` in the lit box (walls of
    /// roughness `sigma` and L′ `cache_value`): per run, every pixel's shading vector in turn.
    fn floor_view(
        floor: &[Vec3],
        width: usize,
        sigma: f32,
        cache_value: f32,
        cfg: &RefineConfig,
        passes: u32,
        sharp: Option<&[bool]>,
    ) -> Vec<Vec<f32>> {
        let (accel, lf) = lit_box(&|_| cache_value);
        // The same box as `lit_box`'s.
        let mut pm = fipt_core::scene::procedural::PartMesh::default();
        pm.cuboid("box", Vec3::ZERO, Vec3::ONE, 4);
        let mesh = &pm.mesh;
        let ceiling: Vec<(u32, Vec3)> = (0..mesh.num_triangles() as u32)
            .filter(|&t| mesh.corners(t as usize).iter().all(|v| v.y > 0.999))
            .map(|t| (t, Vec3::ONE))
            .collect();
        assert_eq!(ceiling.len(), 32);
        let lights = EmitterSet::new(mesh, ceiling, true, LightSelection::Uniform);
        let mats = Uniform(sigma);
        let scene = PathScene {
            secondary_materials: None,
            accel: &accel,
            materials: &mats,
            emitters: &lights,
            cache: Some(RadianceCache {
                light_field: &lf,
                min_roughness: 0.6,
            }),
        };
        let wo = Vec3::new(0.6, 0.8, 0.0);
        let hits = ViewHits {
            width,
            height: 1,
            origin: floor[0] + wo,
            direction: vec![-wo; width],
            t: vec![1.0; width],
            tri: vec![0; width],
            position: vec![floor[0]; width],
            normal: vec![Vec3::Y; width],
        };
        let points: Vec<SurfacePoint> = floor
            .iter()
            .map(|&x| SurfacePoint { x, n: Vec3::Y, wo })
            .collect();
        let fp = ViewFootprint::from_lists((0..width).map(|_| points.clone()));
        (0..12)
            .map(|k| {
                let cfg = RefineConfig {
                    filter: crate::filter::FilterConfig {
                        radius: 0,
                        ..Default::default()
                    },
                    seed: k,
                    ..cfg.clone()
                };
                let n = vec![passes; width];
                refine_view(
                    &scene,
                    &hits,
                    &fp,
                    100.0,
                    &cfg,
                    0,
                    PixelPaths {
                        passes: (passes > 1).then_some(&n[..]),
                        sharp,
                    },
                )
                .0
            })
            .collect()
    }

    /// L_d of the runs at `FLOOR_X` (glossy walls, two segments) is the form factor within 4
    /// standard errors; returns the standard error.
    fn ld_is_the_form_factor(runs: &[Vec<f32>]) -> f64 {
        let f = floor_form_factor(FLOOR_X);
        let (m, se) = mean_stderr(&col(runs, 0));
        assert!(
            (m - f).abs() <= 4.0 * se + 2e-3,
            "L_d {m:.5} ± {se:.5}, form factor {f:.5}"
        );
        se
    }

    /// Shading `i` of every run.
    fn col(runs: &[Vec<f32>], i: usize) -> Vec<f64> {
        runs.iter().map(|s| s[i] as f64).collect()
    }

    /// L_s0 and L_s1 at every level of two sets of runs agree within their standard errors.
    fn specular_levels_agree(a: &[Vec<f32>], b: &[Vec<f32>]) {
        for j in 0..6 {
            for i in [ShadingLayout::ls0(j).start, ShadingLayout::ls1(j).start] {
                let (ma, sa) = mean_stderr(&col(a, i));
                let (mb, sb) = mean_stderr(&col(b, i));
                assert!(
                    (ma - mb).abs() <= 4.0 * (sa * sa + sb * sb).sqrt() + 1e-3,
                    "level {j} channel {i}: {ma:.5} ± {sa:.5} vs {mb:.5} ± {sb:.5}"
                );
            }
        }
    }

    fn mean_stderr(v: &[f64]) -> (f64, f64) {
        let m = v.iter().sum::<f64>() / v.len() as f64;
        let var = v.iter().map(|e| (e - m).powi(2)).sum::<f64>() / (v.len() - 1) as f64;
        (m, (var / v.len() as f64).sqrt())
    }

    /// Rough walls end paths with L′, the emitting ceiling gives its radiance:
    /// L_d = F + (1 − F)·L′ with F the analytic form factor to the ceiling.
    #[test]
    fn rough_hits_return_the_cache_and_emitters_their_radiance() {
        let f = floor_form_factor(FLOOR_X);
        let (m, se) = mean_stderr(&floor_ld(1.0, 0.5, 7));
        let exact = f + (1.0 - f) * 0.5;
        assert!(
            (m - exact).abs() <= 4.0 * se + 2e-3,
            "L_d {m:.5} ± {se:.5}, expected {exact:.5}"
        );
        // Without the cache rule (L′ ignored) it would be F = 0.24; with L′ on the ceiling
        // too (the bake), 0.5.
        assert!(4.0 * se + 2e-3 < 0.05, "stderr {se}");
    }

    /// Glossy walls do not use the cache; with paths of two segments only the emitter counts:
    /// L_d = F. With longer paths the walls add light (strictly more).
    #[test]
    fn glossy_hits_continue_the_path() {
        let f = floor_form_factor(FLOOR_X);
        let (m, se) = mean_stderr(&floor_ld(0.3, 0.5, 2));
        assert!(
            (m - f).abs() <= 4.0 * se + 2e-3,
            "L_d {m:.5} ± {se:.5}, form factor {f:.5}"
        );
        let (m3, se3) = mean_stderr(&floor_ld(0.3, 0.5, 3));
        assert!(m3 > m + 4.0 * (se + se3), "depth 3 {m3} vs depth 2 {m}");
    }

    /// Light samples at x with MIS leave every estimator unbiased: L_d is still the form
    /// factor (glossy walls, two segments), and L_s0, L_s1 at every level agree with BRDF
    /// sampling alone within their standard errors; on L_d the noise drops.
    #[test]
    fn light_samples_at_x_are_unbiased_and_cut_noise() {
        let with = floor_shadings(&[FLOOR_X], 0.3, 0.5, 2, 256, 256, 1);
        let without = floor_shadings(&[FLOOR_X], 0.3, 0.5, 2, 0, 2048, 1);
        let se = ld_is_the_form_factor(&with);
        let (_, se_plain) = mean_stderr(&floor_ld(0.3, 0.5, 2));
        // 256 + 256 samples with MIS against 4096 cosine samples alone.
        assert!(
            se < se_plain,
            "stderr with light samples {se} vs without {se_plain}"
        );
        specular_levels_agree(&with, &without);
    }

    /// Over a footprint of two floor points, each estimator is the mean over the points: L_d
    /// is the mean of their form factors (glossy walls, two segments), with BRDF samples alone
    /// and with light samples at the points. At the first point alone it would be 0.237,
    /// against a mean of 0.202.
    #[test]
    fn a_footprints_shadings_are_the_mean_over_its_points() {
        let floor = [FLOOR_X, Vec3::new(0.1, 0.0, 0.1)];
        let f = floor.iter().map(|&x| floor_form_factor(x)).sum::<f64>() / 2.0;
        for (light_samples, spp) in [(0, 4096), (64, 256)] {
            let runs = floor_shadings(&floor, 0.3, 0.5, 2, light_samples, spp, 1);
            let ld: Vec<f64> = runs.iter().map(|s| s[0] as f64).collect();
            let (m, se) = mean_stderr(&ld);
            assert!(
                (m - f).abs() <= 4.0 * se + 2e-3,
                "{light_samples} light samples: L_d {m:.5} ± {se:.5}, want {f:.5}"
            );
            assert!(4.0 * se + 2e-3 < 0.02, "stderr {se}");
        }
    }

    /// A pixel estimated in 8 passes (a small part's, `RefineConfig::small_parts`) keeps every
    /// estimator's mean (L_d the form factor; L_s0, L_s1 at every level those of one pass with
    /// 8 times the samples) and cuts the noise: its runs' spread falls to about 1/√8 of one
    /// pass's (at most 0.6 of it).
    #[test]
    fn a_small_parts_passes_average_to_the_same_shadings_with_less_noise() {
        let one = floor_shadings(&[FLOOR_X], 0.3, 0.5, 2, 8, 32, 1);
        let eight = floor_shadings(&[FLOOR_X], 0.3, 0.5, 2, 8, 32, 8);
        let many = floor_shadings(&[FLOOR_X], 0.3, 0.5, 2, 64, 256, 1);
        let se8 = ld_is_the_form_factor(&eight);
        let (_, se1) = mean_stderr(&col(&one, 0));
        assert!(se8 < 0.6 * se1, "stderr with 8 passes {se8} vs one {se1}");
        specular_levels_agree(&eight, &many);
        // The passes a part's pixel count gives.
        let cfg = RefineConfig::default();
        assert_eq!(cfg.passes_for(10), 1);
        let cfg = RefineConfig {
            small_parts: 1000,
            ..cfg
        };
        assert_eq!(
            [
                cfg.passes_for(1000),
                cfg.passes_for(999),
                cfg.passes_for(250),
                cfg.passes_for(1)
            ],
            [1, 2, 4, SMALL_PART_PASSES]
        );
    }

    /// A pixel flagged sharp (`RefineConfig::sharp`) is estimated exactly as with the sharp
    /// counts as every pixel's samples, and the unflagged pixel beside it exactly as without
    /// the key; the flags do nothing while the key is None.
    #[test]
    fn sharp_pixels_take_the_sharp_paths() {
        let base = RefineConfig {
            samples: BakeSamples {
                diffuse: 8,
                specular: [8; 6],
            },
            max_depth: 2,
            light_samples: 4,
            ..Default::default()
        };
        let specular = [64, 64, 8, 8, 8, 8];
        let keyed = RefineConfig {
            sharp: Some(SharpSamples {
                below: 0.5,
                specular,
            }),
            ..base.clone()
        };
        let more = RefineConfig {
            samples: BakeSamples {
                specular,
                ..base.samples
            },
            ..base.clone()
        };
        let flags = [true, false];
        let view = |cfg: &RefineConfig, sharp: Option<&[bool]>| {
            floor_view(&[FLOOR_X], 2, 0.3, 0.5, cfg, 1, sharp)
        };
        let sharp = view(&keyed, Some(&flags));
        let (plain, all_more) = (view(&base, None), view(&more, None));
        assert_eq!(view(&base, Some(&flags)), plain);
        let dim = ShadingLayout::DIM;
        for k in 0..sharp.len() {
            assert_eq!(
                sharp[k][..dim],
                all_more[k][..dim],
                "run {k}: the sharp pixel"
            );
            assert_eq!(sharp[k][dim..], plain[k][dim..], "run {k}: the plain pixel");
            assert_ne!(sharp[k][..dim], plain[k][..dim], "run {k}");
        }
    }
}
