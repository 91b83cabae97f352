//! The shading bake (paper §4.2, Eq. 9 for the integrals of Eq. 6; reference §2.2): per
//! training pixel, the diffuse shading L_d and the specular shadings L_s0, L_s1 at the roughness
//! levels linspace(0.02, 1, 6), each a Monte Carlo mean of L′ at the first hit of secondary rays
//! from x + ε·ω: x the pixel-centre hit, or with `BakeConfig::footprint` the points of the
//! pixel's footprint on its part (`accel::footprint`).
//!
//! Random numbers come from (seed, view, pixel), so results are bit-identical for any thread
//! count.
//!
//! Owns: the shading estimators and the per-view shading buffers. Must not touch: files, the
//! filter (see `filter`), tensors.

use crate::accel::Accel;
use crate::accel::footprint::{SurfacePoint, ViewFootprint, point_of_sample};
use crate::accel::raycast::ViewHits;
use crate::lightfield::LightField;
use fipt_core::brdf::{Frame, ROUGHNESS_LEVELS, roughness_levels, sample_cosine, sample_specular};
use fipt_core::rng::Rng;
use fipt_core::scene::Camera;
use fipt_core::shading::ShadingLayout;
use glam::Vec3;
use rayon::prelude::*;

/// Secondary-ray offset along the new direction (Mitsuba's RayEpsilon, reference §2.1).
pub const RAY_EPS: f32 = 1500.0 / (1u32 << 24) as f32;

/// Sample counts of the bake.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct BakeSamples {
    /// Cosine samples for L_d.
    pub diffuse: usize,
    /// GGX samples per roughness level.
    pub specular: [usize; ROUGHNESS_LEVELS],
}

impl Default for BakeSamples {
    /// The reference's counts: 256 diffuse; 64 at level 0, 128 at levels 1–5.
    fn default() -> Self {
        Self {
            diffuse: 256,
            specular: [64, 128, 128, 128, 128, 128],
        }
    }
}

impl BakeSamples {
    pub fn rays_per_pixel(&self) -> usize {
        self.diffuse + self.specular.iter().sum::<usize>()
    }
}

/// The shading estimator over one scene: geometry, L′ and sample counts.
pub struct Baker<'a> {
    pub accel: &'a Accel,
    pub lf: &'a LightField,
    pub samples: BakeSamples,
}

impl Baker<'_> {
    /// Shadings of one pixel whose footprint is the surface points `pts` (at least one; each
    /// seen from its direction `wo`, its normal facing `wo`); `out` receives
    /// `ShadingLayout::DIM` values. The samples of each estimator share the points equally
    /// (`point_of_sample`), so the estimate is the mean over the points' shadings. Returns the
    /// number of rays cast (GGX samples below the horizon cast none).
    ///
    /// All the pixel's directions are drawn first (in the estimators' order of random
    /// numbers), traced as one batch (`Accel::closest_many`), L′ looked up at every hit as one
    /// batch (`LightField::query_many`, whose cache misses overlap), then summed in the same
    /// order: the result equals tracing and looking up one ray at a time, bit for bit.
    pub fn shade_point(&self, pts: &[SurfacePoint], rng: &mut Rng, out: &mut [f32]) -> u64 {
        let frames: Vec<(Frame, Vec3)> = pts
            .iter()
            .map(|q| {
                let f = Frame::new(q.n);
                (f, f.to_local(q.wo))
            })
            .collect();
        let at = |i: usize, count: usize| {
            let k = point_of_sample(i, count, pts.len());
            (pts[k].x, &frames[k])
        };
        let nd = self.samples.diffuse;
        let mut rays: Vec<(Vec3, Vec3)> = Vec::with_capacity(self.samples.rays_per_pixel());
        let push = |rays: &mut Vec<(Vec3, Vec3)>, x: Vec3, w: Vec3| rays.push((x + w * RAY_EPS, w));
        for i in 0..nd {
            let (x, (frame, _)) = at(i, nd);
            push(
                &mut rays,
                x,
                frame.to_world(sample_cosine(rng.next_f32(), rng.next_f32())),
            );
        }
        // Per specular sample: its roughness level and GGX weights.
        let mut spec: Vec<(usize, f32, f32)> = Vec::with_capacity(rays.capacity() - nd);
        for (j, sigma) in roughness_levels().into_iter().enumerate() {
            for i in 0..self.samples.specular[j] {
                let (x, (frame, wo_l)) = at(i, self.samples.specular[j]);
                if let Some((wi, g0, g1)) =
                    sample_specular(*wo_l, sigma, rng.next_f32(), rng.next_f32())
                {
                    push(&mut rays, x, frame.to_world(wi).normalize());
                    spec.push((j, g0, g1));
                }
            }
        }
        let mut hits = vec![None; rays.len()];
        self.accel
            .closest_many(&rays, 0.0, f32::INFINITY, &mut hits);
        // L′ at every hit, on the side the ray hits (`LightField::query_many`); a miss sees 0.
        let queries: Vec<Option<(Vec3, Vec3)>> = rays
            .iter()
            .zip(&hits)
            .map(|(&(o, w), h)| h.map(|h| (o + w * h.t, self.accel.facing_normal(h.tri, w))))
            .collect();
        let mut radiance = vec![Vec3::ZERO; rays.len()];
        self.lf.query_many(&queries, &mut radiance);
        let ld = radiance[..nd].iter().fold(Vec3::ZERO, |a, &l| a + l);
        out[ShadingLayout::LD].copy_from_slice(&(ld / nd.max(1) as f32).to_array());
        let mut s = [(Vec3::ZERO, Vec3::ZERO); ROUGHNESS_LEVELS];
        for (&(j, g0, g1), &l) in spec.iter().zip(&radiance[nd..]) {
            s[j].0 += l * g0;
            s[j].1 += l * g1;
        }
        for (j, (s0, s1)) in s.into_iter().enumerate() {
            let inv = 1.0 / self.samples.specular[j].max(1) as f32;
            out[ShadingLayout::ls0(j)].copy_from_slice(&(s0 * inv).to_array());
            out[ShadingLayout::ls1(j)].copy_from_slice(&(s1 * inv).to_array());
        }
        rays.len() as u64
    }

    /// Bakes every pixel of one view from its footprints (`ShadingLayout::DIM` values per
    /// pixel, zeros where the pixel-centre ray missed) and the number of rays cast.
    /// `view_key` distinguishes views in the random streams.
    pub fn bake_view(&self, fp: &ViewFootprint, seed: u64, view_key: u64) -> (Vec<f32>, u64) {
        let mut out = vec![0f32; fp.num_pixels() * ShadingLayout::DIM];
        let rays = out
            .par_chunks_mut(ShadingLayout::DIM)
            .enumerate()
            .with_min_len(16)
            .map(|(p, o)| {
                let pts = fp.of(p);
                if pts.is_empty() {
                    return 0;
                }
                let mut rng = Rng::new(seed, (view_key << 32) | p as u64);
                self.shade_point(pts, &mut rng, o)
            })
            .sum();
        (out, rays)
    }
}

/// Everything the bake needs to know.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct BakeConfig {
    /// L′ grid resolution per axis (a multiple of 8).
    pub voxel_res: usize,
    /// The most rings of L′'s hole filling on the mesh's surface (`LightField::build_filled`;
    /// `docs/departures/lightfield.md`).
    #[serde(default = "default_fill_rings")]
    pub fill_rings: usize,
    pub samples: BakeSamples,
    /// Shadings over the pixel's footprint: the estimators spread their samples over the hits
    /// of an n×n grid of rays per pixel that land on the centre hit's part
    /// (`accel::footprint`; 0: at the pixel-centre hit, the reference).
    #[serde(default)]
    pub footprint: usize,
    pub filter: crate::filter::FilterConfig,
    /// Random seed (set from the run's seed, not read from config files).
    #[serde(skip)]
    pub seed: u64,
}

impl Default for BakeConfig {
    fn default() -> Self {
        Self {
            voxel_res: 256,
            fill_rings: FILL_RINGS,
            samples: BakeSamples::default(),
            footprint: 0,
            filter: Default::default(),
            seed: 0,
        }
    }
}

/// The default of `BakeConfig::fill_rings`.
pub const FILL_RINGS: usize = 32;

fn default_fill_rings() -> usize {
    FILL_RINGS
}

/// One training view as the bake sees it.
pub struct BakeView<'a> {
    pub hits: &'a ViewHits,
    /// HDR image, 3 values per pixel.
    pub image: &'a [f32],
    /// The view's camera (its focal length sets the filter's footprint).
    pub camera: &'a Camera,
}

/// Builds L′ from the training views' pixel-centre hits and HDR values, its holes filled with
/// `rings` rings on the surface of `mesh`.
pub fn build_light_field(
    views: &[BakeView],
    mesh: &fipt_core::scene::Mesh,
    res: usize,
    rings: usize,
) -> LightField {
    build_light_field_without(views, mesh, res, rings, &|_, _| false)
}

/// `build_light_field` without the pixels `p` of view `k` where `left_out(k, p)`: they add
/// nothing to L′ (the scene box still spans every hit).
pub fn build_light_field_without(
    views: &[BakeView],
    mesh: &fipt_core::scene::Mesh,
    res: usize,
    rings: usize,
    left_out: &(dyn Fn(usize, usize) -> bool + Sync),
) -> LightField {
    let triangles: Vec<[Vec3; 3]> = (0..mesh.num_triangles()).map(|t| mesh.corners(t)).collect();
    let sb = fipt_core::scene::SceneBox::from_points(views.iter().flat_map(|v| {
        v.hits
            .position
            .iter()
            .zip(&v.hits.tri)
            .filter(|(_, t)| **t >= 0)
            .map(|(p, _)| p)
    }));
    LightField::build_filled(
        sb,
        res,
        crate::lightfield::HoleFill {
            rings,
            surface: Some(&triangles),
        },
        views.iter().enumerate().flat_map(|(k, v)| {
            (0..v.hits.num_pixels())
                .filter(move |&p| v.hits.tri[p] >= 0 && !left_out(k, p))
                .map(|p| {
                    (
                        v.hits.position[p],
                        v.hits.normal[p],
                        [v.image[3 * p], v.image[3 * p + 1], v.image[3 * p + 2]],
                    )
                })
        }),
    )
}

/// The channel groups the filter touches: L_d and, per filtered level, L_s0 and L_s1.
pub fn filter_groups(cfg: &crate::filter::FilterConfig) -> Vec<Vec<usize>> {
    let mut g = vec![ShadingLayout::LD.collect()];
    for &j in &cfg.specular_levels {
        g.push(ShadingLayout::ls0(j).chain(ShadingLayout::ls1(j)).collect());
    }
    g
}

/// The baked shadings of every view and the rays it took.
pub struct BakeOutput {
    /// `ShadingLayout::DIM` values per pixel, per view.
    pub shadings: Vec<Vec<f32>>,
    /// Secondary rays cast (samples below the horizon cast none).
    pub rays: u64,
}

/// Bakes (and filters) every view; `progress(k)` is called after view k and returns whether
/// to go on: `false` before the last view stops the bake, which then returns None (nothing
/// partial). With `cfg.footprint` > 0, `parts` (a key per triangle) says which sub-pixel hits
/// share the centre's part (`ViewFootprint::cast`); without it the centre hits serve.
pub fn bake_views(
    accel: &Accel,
    lf: &LightField,
    views: &[BakeView],
    cfg: &BakeConfig,
    parts: Option<&[u64]>,
    progress: &(dyn Fn(usize) -> bool + Sync),
) -> Option<BakeOutput> {
    let baker = Baker {
        accel,
        lf,
        samples: cfg.samples.clone(),
    };
    let groups = filter_groups(&cfg.filter);
    let mut rays = 0;
    let mut shadings = Vec::with_capacity(views.len());
    for (k, v) in views.iter().enumerate() {
        let fp = ViewFootprint::cast(accel, v.camera, v.hits, parts, cfg.footprint);
        let (mut s, r) = baker.bake_view(&fp, cfg.seed, k as u64);
        drop(fp);
        rays += r;
        crate::filter::filter_view(
            &cfg.filter,
            v.hits,
            v.camera.fx as f32,
            &mut s,
            ShadingLayout::DIM,
            &groups,
        );
        shadings.push(s);
        if !progress(k) && k + 1 < views.len() {
            return None;
        }
    }
    Some(BakeOutput { shadings, rays })
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;
    use fipt_core::brdf::{Brdf, Frame};
    use fipt_core::scene::SceneBox;
    use fipt_core::scene::procedural::PartMesh;

    /// Directional albedo of the pure specular lobe (k_d = 0, k_s = 1) by quadrature over half
    /// vectors in f64, θ_h = atan(α tan ψ) with ψ uniform (the GGX mass is sin²ψ, so even
    /// α = 4e-4 is resolved), φ uniform. Independent of the f32 BRDF code.
    fn specular_albedo(sigma: f32, wo: Vec3, n_psi: usize, n_phi: usize) -> f64 {
        use std::f64::consts::{FRAC_PI_2, PI, TAU};
        let s = sigma as f64;
        let alpha = s * s;
        let k = (s + 1.0).powi(2) / 8.0;
        let g1 = |c: f64| c * (1.0 - k) + k;
        let wo = wo.as_dvec3();
        let mut sum = 0.0f64;
        for i in 0..n_psi {
            let psi = (i as f64 + 0.5) / n_psi as f64 * FRAC_PI_2;
            let tan_h = alpha * psi.tan();
            let th = tan_h.atan();
            let dth = alpha / psi.cos().powi(2) / (1.0 + tan_h * tan_h);
            let (st, ct) = (th.sin(), th.cos());
            // GGX D in its stable tangent form: α² / (π cos⁴θ (α² + tan²θ)²).
            let d = alpha * alpha / (PI * ct.powi(4) * (alpha * alpha + tan_h * tan_h).powi(2));
            for j in 0..n_phi {
                let ph = (j as f64 + 0.5) / n_phi as f64 * TAU;
                let h = glam::DVec3::new(st * ph.cos(), st * ph.sin(), ct);
                let vh = wo.dot(h);
                if vh <= 0.0 {
                    continue;
                }
                let wi = 2.0 * vh * h - wo;
                if wi.z <= 0.0 {
                    continue;
                }
                let fs = d / (4.0 * g1(wo.z) * g1(wi.z));
                sum += fs * wi.z * 4.0 * vh * st * dth;
            }
        }
        sum * FRAC_PI_2 / n_psi as f64 * TAU / n_phi as f64
    }

    /// A closed unit box whose light field is 1 on every surface voxel.
    fn furnace() -> (Accel, LightField) {
        lit_box(&|_| 1.0)
    }

    /// A closed unit box whose light field at surface point x is `radiance(x)`.
    pub(crate) fn lit_box(radiance: &dyn Fn(Vec3) -> f32) -> (Accel, LightField) {
        let mut pm = PartMesh::default();
        pm.cuboid("box", Vec3::ZERO, Vec3::ONE, 4);
        let mesh = pm.mesh;
        let mut r = Rng::new(1, 1);
        let mut samples = Vec::new();
        for t in 0..mesh.num_triangles() {
            let [a, b, c] = mesh.corners(t);
            for _ in 0..20_000 {
                let (u, v) = (r.next_f32(), r.next_f32());
                let (u, v) = if u + v > 1.0 {
                    (1.0 - u, 1.0 - v)
                } else {
                    (u, v)
                };
                let x = a + (b - a) * u + (c - a) * v;
                // The side facing the inside of the box, where the rays come from.
                let n = mesh.normal(t);
                let n = if n.dot(Vec3::splat(0.5) - x) < 0.0 {
                    -n
                } else {
                    n
                };
                samples.push((x, n, [radiance(x); 3]));
            }
        }
        let lf = LightField::build(
            SceneBox {
                min: -0.1,
                max: 1.1,
            },
            64,
            samples,
        );
        (Accel::build(&mesh), lf)
    }

    /// Runs `shade_point` 12 times (independent seeds) on the furnace floor for view angle
    /// cos θ_o; returns the runs and ω_o in the local frame.
    fn furnace_runs(cos_o: f32, spp: usize) -> (Vec<Vec<f32>>, Vec3) {
        box_runs(furnace(), cos_o, spp)
    }

    /// The point on the floor where `box_runs` shades.
    pub(crate) const FLOOR_X: Vec3 = Vec3::new(0.43, 0.0, 0.57);

    fn box_runs((accel, lf): (Accel, LightField), cos_o: f32, spp: usize) -> (Vec<Vec<f32>>, Vec3) {
        let baker = Baker {
            accel: &accel,
            lf: &lf,
            samples: BakeSamples {
                diffuse: spp,
                specular: [spp; 6],
            },
        };
        let x = FLOOR_X; // on the floor, normal +y
        let n = Vec3::Y;
        let wo_l = Vec3::new((1.0 - cos_o * cos_o).sqrt(), 0.0, cos_o);
        let wo = Frame::new(n).to_world(wo_l);
        let runs = (0..12)
            .map(|k| {
                let mut out = vec![0f32; ShadingLayout::DIM];
                baker.shade_point(&[SurfacePoint { x, n, wo }], &mut Rng::new(k, 0), &mut out);
                out
            })
            .collect();
        (runs, wo_l)
    }

    /// Furnace: with L′ ≡ 1 on a closed surface every cosine sample returns 1, so L_d = 1.
    #[test]
    fn furnace_diffuse_shading_is_one() {
        for cos_o in [0.95f32, 0.25] {
            let (runs, _) = furnace_runs(cos_o, 256);
            for o in &runs {
                for ld in &o[ShadingLayout::LD] {
                    assert!((ld - 1.0).abs() < 1e-6, "L_d = {ld} in a furnace");
                }
            }
        }
    }

    /// Form factor from a differential area facing a parallel rectangle at height 1 to that
    /// rectangle, the area's foot at one corner and sides a, b (Howell's catalogue, C-11 case).
    pub(crate) fn corner_form_factor(a: f64, b: f64) -> f64 {
        let (ra, rb) = ((1.0 + a * a).sqrt(), (1.0 + b * b).sqrt());
        (a / ra * (b / ra).atan() + b / rb * (a / rb).atan()) / std::f64::consts::TAU
    }

    /// The form factor from floor point `x` of the unit box to its ceiling: four corner form
    /// factors.
    pub(crate) fn floor_form_factor(x: Vec3) -> f64 {
        let (px, pz) = (x.x as f64, x.z as f64);
        [
            (px, pz),
            (1.0 - px, pz),
            (px, 1.0 - pz),
            (1.0 - px, 1.0 - pz),
        ]
        .into_iter()
        .map(|(a, b)| corner_form_factor(a, b))
        .sum()
    }

    /// A footprint's shadings are the mean of its points': with only the ceiling lit, L_d over
    /// two floor points and a ceiling point (which sees the dark floor) is the mean of the
    /// floor points' form factors and 0. Shading all samples at the first point would give its
    /// form factor (0.237, against a mean of 0.135).
    #[test]
    fn a_footprints_shadings_are_the_mean_over_its_points() {
        let (accel, lf) = lit_box(&|x| if x.y > 0.999 { 1.0 } else { 0.0 });
        let baker = Baker {
            accel: &accel,
            lf: &lf,
            samples: BakeSamples {
                diffuse: 3 * 2048,
                specular: [0; 6],
            },
        };
        let floor = [FLOOR_X, Vec3::new(0.1, 0.0, 0.1)];
        let wo = Vec3::new(0.6, 0.8, 0.0);
        let pts = [
            SurfacePoint {
                x: floor[0],
                n: Vec3::Y,
                wo,
            },
            SurfacePoint {
                x: floor[1],
                n: Vec3::Y,
                wo,
            },
            SurfacePoint {
                x: Vec3::new(0.5, 1.0, 0.5),
                n: Vec3::NEG_Y,
                wo: -wo,
            },
        ];
        let est: Vec<f64> = (0..12)
            .map(|k| {
                let mut out = vec![0f32; ShadingLayout::DIM];
                baker.shade_point(&pts, &mut Rng::new(k, 0), &mut out);
                out[0] as f64
            })
            .collect();
        let mean = est.iter().sum::<f64>() / est.len() as f64;
        let var = est.iter().map(|e| (e - mean).powi(2)).sum::<f64>() / (est.len() - 1) as f64;
        let stderr = (var / est.len() as f64).sqrt();
        let exact = floor.iter().map(|&x| floor_form_factor(x)).sum::<f64>() / 3.0;
        assert!(
            (mean - exact).abs() <= 4.0 * stderr + 2e-3,
            "L_d = {mean:.5} ± {stderr:.5}, want {exact:.5}"
        );
        assert!(4.0 * stderr + 2e-3 < 0.02, "stderr {stderr}");
    }

    /// Only the ceiling of the box (y = 1) is lit, with L′ = 1: then L_d at a floor point is the
    /// form factor to the unit ceiling square, the sum of four corner form factors (0.2368 at
    /// (0.43, 0.57)). A sampler that drops the cosine, or a wrong pdf, misses it by far: uniform
    /// hemisphere sampling weighted as cosine sampling gives the ceiling's solid angle / 2π.
    #[test]
    fn lit_ceiling_gives_the_analytic_form_factor() {
        let lit = lit_box(&|x| if x.y > 0.999 { 1.0 } else { 0.0 });
        let (runs, _) = box_runs(lit, 0.7, 4096);
        let est: Vec<f64> = runs.iter().map(|o| o[0] as f64).collect();
        let mean = est.iter().sum::<f64>() / est.len() as f64;
        let var = est.iter().map(|e| (e - mean).powi(2)).sum::<f64>() / (est.len() - 1) as f64;
        let stderr = (var / est.len() as f64).sqrt();
        let exact = floor_form_factor(FLOOR_X);
        assert!(
            (mean - exact).abs() <= 4.0 * stderr + 2e-3,
            "L_d = {mean:.5} ± {stderr:.5}, form factor {exact:.5}"
        );
        // The wrong answers are far outside the tolerance (the test can fail).
        assert!(4.0 * stderr + 2e-3 < 0.02, "stderr {stderr}");
        // Every channel agrees (L′ is grey).
        for o in &runs {
            assert_eq!(o[0], o[1]);
            assert_eq!(o[1], o[2]);
        }
    }

    /// Furnace: L_s0 + L_s1 at every roughness level equals the directional albedo of the GGX
    /// lobe with k_s = 1 (f64 quadrature), within 4 standard errors of the Monte Carlo mean.
    #[test]
    fn furnace_specular_shadings_are_the_ggx_albedo() {
        for cos_o in [0.95f32, 0.6, 0.25] {
            let (runs, wo_l) = furnace_runs(cos_o, 4096);
            for (j, sigma) in roughness_levels().into_iter().enumerate() {
                let est: Vec<f64> = runs
                    .iter()
                    .map(|o| {
                        (o[ShadingLayout::ls0(j).start] + o[ShadingLayout::ls1(j).start]) as f64
                    })
                    .collect();
                let mean = est.iter().sum::<f64>() / est.len() as f64;
                let var =
                    est.iter().map(|e| (e - mean).powi(2)).sum::<f64>() / (est.len() - 1) as f64;
                let stderr = (var / est.len() as f64).sqrt();
                let q = specular_albedo(sigma, wo_l, 4000, 1000);
                assert!(
                    (mean - q).abs() <= 4.0 * stderr + 2e-3,
                    "cos θo {cos_o}, σ {sigma}: L_s0 + L_s1 = {mean:.5} ± {stderr:.5}, quadrature {q:.5}"
                );
            }
        }
    }

    /// The procedural room, its accelerator, a `w`×`h` camera looking across it and that
    /// camera's pixel-centre hits.
    fn room_view(
        w: usize,
        h: usize,
    ) -> (
        fipt_core::scene::procedural::PartMesh,
        Accel,
        fipt_core::scene::Camera,
        ViewHits,
    ) {
        use fipt_core::scene::{Camera, procedural};
        use glam::DVec3;
        let room = procedural::room(Vec3::new(5.0, 2.7, 4.0), 1);
        let accel = Accel::build(&room.mesh);
        let cam = Camera::look_at_fov(
            DVec3::new(1.0, 1.5, 1.0),
            DVec3::new(3.0, 1.0, 3.0),
            DVec3::Y,
            1.2,
            w,
            h,
        );
        let hits = crate::accel::raycast::cast_view(&accel, &room.mesh, &cam);
        (room, accel, cam, hits)
    }

    /// Left-out pixels add nothing to L′: a bright square of pixels (100, as next to an
    /// emitter) raises the voxels it hits when kept; left out, every voxel holds at most the
    /// other pixels' value (1) and the scene box is the same.
    #[test]
    fn left_out_pixels_add_nothing_to_the_light_field() {
        let (room, _, cam, hits) = room_view(32, 24);
        let bright = |p: usize| (10..16).contains(&(p % 32)) && (8..14).contains(&(p / 32));
        let image: Vec<f32> = (0..hits.num_pixels() * 3)
            .map(|i| if bright(i / 3) { 100.0 } else { 1.0 })
            .collect();
        let views = [BakeView {
            hits: &hits,
            image: &image,
            camera: &cam,
        }];
        let kept = build_light_field(&views, &room.mesh, 32, 8);
        let left = build_light_field_without(&views, &room.mesh, 32, 8, &|_, p| bright(p));
        assert_eq!(kept.scene_box, left.scene_box);
        // The brightest channel L′ holds at each hit of the view.
        let at_hits = |lf: &LightField| -> Vec<f32> {
            (0..hits.num_pixels())
                .filter(|&p| hits.tri[p] >= 0)
                .map(|p| lf.query(hits.position[p], hits.normal[p]).max_element())
                .collect()
        };
        let max = |v: Vec<f32>| v.into_iter().fold(0.0, f32::max);
        let (kept_max, left_at) = (max(at_hits(&kept)), at_hits(&left));
        assert!(kept_max > 10.0, "kept: {kept_max}");
        assert!(
            left_at.iter().all(|&x| x <= 1.0 + 1e-5),
            "left out: {}",
            max(left_at.clone())
        );
        assert!(
            left_at.iter().all(|&x| x > 0.0),
            "the left-out pixels' voxels are filled from their neighbours"
        );
    }

    /// Same seed → bit-identical shadings whatever the thread count, with and without a
    /// footprint.
    #[test]
    fn bake_is_deterministic_across_thread_counts() {
        let (room, accel, cam, hits) = room_view(24, 18);
        let image: Vec<f32> = (0..hits.num_pixels() * 3)
            .map(|i| (i % 7) as f32 * 0.1)
            .collect();
        let views = [BakeView {
            hits: &hits,
            image: &image,
            camera: &cam,
        }];
        let lf = build_light_field(&views, &room.mesh, 32, 1);
        // Every second triangle starts a part: sub-pixel hits on both sides of some edges.
        let keys: Vec<u64> = (0..room.mesh.num_triangles() as u64)
            .map(|t| t / 2)
            .collect();
        for (footprint, parts) in [(0, None), (2, Some(keys.as_slice()))] {
            let cfg = BakeConfig {
                voxel_res: 32,
                samples: BakeSamples {
                    diffuse: 16,
                    specular: [8; 6],
                },
                footprint,
                ..Default::default()
            };
            let run = |threads: usize| {
                rayon::ThreadPoolBuilder::new()
                    .num_threads(threads)
                    .build()
                    .unwrap()
                    .install(|| bake_views(&accel, &lf, &views, &cfg, parts, &|_| true).unwrap())
            };
            let (a, b) = (run(1), run(2));
            assert_eq!(a.rays, b.rays);
            let (a, b) = (a.shadings, b.shadings);
            assert!(a[0].iter().any(|v| *v > 0.0));
            assert_eq!(
                a[0].iter().map(|v| v.to_bits()).collect::<Vec<_>>(),
                b[0].iter().map(|v| v.to_bits()).collect::<Vec<_>>()
            );
        }
    }

    /// The half-vector quadrature agrees with a plain quadrature over ω_i for a rough lobe.
    #[test]
    fn albedo_quadratures_agree() {
        let wo = Vec3::new(0.6, 0.0, 0.8);
        let b = Brdf {
            kd: Vec3::ZERO,
            ks: Vec3::ONE,
            sigma: 0.8,
        };
        let a = fipt_core::brdf::directional_albedo_quadrature(&b, wo, 2000, 1000).x as f64;
        let h = specular_albedo(0.8, wo, 2000, 1000);
        assert!((a - h).abs() < 2e-3, "{a} vs {h}");
        // And in the mirror limit it tends to the closed form G_s·(n·v)² (h = n, F = 1).
        let c = 0.8f64;
        let k = (1.02f64).powi(2) / 8.0;
        let limit = c * c / (c * (1.0 - k) + k).powi(2);
        let m = specular_albedo(0.02, wo, 4000, 400);
        assert!((m - limit).abs() < 1e-3, "{m} vs {limit}");
    }
}
