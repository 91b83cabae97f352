//! A wavefront path tracer (the rendering equation, paper Eq. 3–4) over the scene mesh with the
//! FIPT BRDF (Eq. 1) at every hit: each bounce takes the batch of live rays → closest hits →
//! one batched material query (`MaterialSource`) → one batched L′ lookup where the radiance
//! cache ends a path (`LightField::query_many`) → next-event estimation to the area lights
//! with MIS (power heuristic) → BRDF sampling (a diffuse/GGX mixture: the reference's 50/50 or
//! by lobe reflectance, `PathConfig::lobe`) → the next batch.
//!
//! Conventions as Mitsuba's `path` integrator, which rendered the reference scenes: `max_depth`
//! counts path segments (1: emitters seen directly; 2: direct lighting; 7: the reference);
//! surfaces are two-sided with the flat face normal turned towards the incoming ray; pixel
//! samples are jittered over the whole pixel (box filter). Every path draws its random numbers
//! from (seed, view, pixel, sample), so an image is bit-identical for any thread count or batch.
//!
//! Owns: path construction and the per-pixel estimate. Must not touch: where materials and
//! emitters come from, files.

use crate::accel::Accel;
use crate::emitters::EmitterSet;
use crate::integrators::bake::RAY_EPS;
use crate::lightfield::LightField;
use crate::materials::{MaterialSource, SurfaceMaterial};
use fipt_core::brdf::{Brdf, Frame, LobeChoice};
use fipt_core::rng::Rng;
use fipt_core::scene::Camera;
use glam::Vec3;
use rayon::prelude::*;

/// Path tracer settings.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct PathConfig {
    /// Samples per pixel.
    pub spp: usize,
    /// Maximum path length in segments (Mitsuba's `max_depth`; the reference scenes use 7).
    pub max_depth: usize,
    /// Russian roulette from this depth on (None: off, the default; the estimate is unbiased
    /// either way).
    pub rr_depth: Option<usize>,
    /// Whether emitters also reflect light with their material (Mitsuba's area emitters do;
    /// FIPT's refinement assumes they do not: paths end on emitters).
    pub emitters_reflect: bool,
    /// How BRDF sampling picks a lobe: `half` (the reference's 50/50 mixture) or `luminance`
    /// (by the lobes' reflectance, as the Mitsuba plugin that rendered the reference scenes).
    pub lobe: LobeChoice,
    /// Paths traced per wavefront (memory bound, not a result-changing setting).
    pub wave: usize,
    pub seed: u64,
    /// 0: every sample jitters its camera ray anywhere in the pixel. N = g² > 0: sample s goes
    /// through the pixel's position s mod N, one random point in each cell of a g × g grid
    /// over the pixel, fixed per pixel and view (an N-sample stratified estimate of the box
    /// filter, unbiased; edge and texture noise stops falling beyond N), so camera hits repeat
    /// bit for bit and a memo of first-hit materials (`materials::Memo`) answers all but N
    /// queries per pixel.
    pub pixel_positions: usize,
}

impl Default for PathConfig {
    fn default() -> Self {
        Self {
            spp: 64,
            max_depth: 7,
            rr_depth: None,
            emitters_reflect: true,
            lobe: LobeChoice::Luminance,
            wave: 1 << 18,
            seed: 0,
            pixel_positions: 0,
        }
    }
}

/// Counters of one render.
#[derive(Clone, Copy, Debug, Default, serde::Serialize, serde::Deserialize)]
pub struct PathStats {
    pub paths: u64,
    /// Closest-hit rays (camera and continuation).
    pub rays: u64,
    /// Shadow rays of next-event estimation.
    pub shadow_rays: u64,
    /// Path samples whose estimate was not finite (counted as 0).
    pub nonfinite: u64,
}

impl PathStats {
    /// Adds another render's counters.
    pub fn add(&mut self, o: &PathStats) {
        self.paths += o.paths;
        self.rays += o.rays;
        self.shadow_rays += o.shadow_rays;
        self.nonfinite += o.nonfinite;
    }
}

/// The scene as the tracer sees it.
pub struct PathScene<'a> {
    pub accel: &'a Accel,
    pub materials: &'a dyn MaterialSource,
    /// A cheaper source for every hit but the first segment's (e.g. a voxel cache of the
    /// learned field; None: `materials` everywhere).
    pub secondary_materials: Option<&'a dyn MaterialSource>,
    pub emitters: &'a EmitterSet,
    /// The radiance cache on secondary hits (None: pure path tracing).
    pub cache: Option<RadianceCache<'a>>,
}

/// FIPT's radiance-cache termination (reference §2.5): a BRDF-sampled ray (not a camera ray)
/// that hits a non-emitter surface rougher than `min_roughness`, where L′ is non-zero, takes
/// L′ there as the incoming radiance and ends the path.
#[derive(Clone, Copy)]
pub struct RadianceCache<'a> {
    pub light_field: &'a LightField,
    pub min_roughness: f32,
}

/// A ray that starts a path: origin (already offset), unit direction, its random stream, and
/// the pdf that MIS-weights an emitter hit of this first segment against one light sample
/// (0: weight 1, no light sampling at the origin).
pub struct PathStart {
    pub origin: Vec3,
    pub dir: Vec3,
    pub rng: Rng,
    pub pdf: f32,
}

/// One path in flight.
#[derive(Clone)]
struct PathState {
    origin: Vec3,
    dir: Vec3,
    throughput: Vec3,
    radiance: Vec3,
    /// Solid-angle pdf of the BRDF sample that made `dir` (0 for the camera ray: no MIS).
    pdf_bsdf: f32,
    rng: Rng,
    alive: bool,
}

/// Where a path's ray ended in one wavefront: the hit at distance `t` on triangle `tri` with
/// its material, L′ there where the radiance cache applies (0 elsewhere, `cache_lookups`), and
/// the segment `depth` the ray was.
#[derive(Clone, Copy)]
struct PathVertex {
    t: f32,
    tri: u32,
    mat: SurfaceMaterial,
    cached: Vec3,
    depth: usize,
}

/// Power heuristic weight of a strategy with pdf `a` against one with pdf `b`.
#[inline]
pub fn power_heuristic(a: f32, b: f32) -> f32 {
    let (a2, b2) = (a * a, b * b);
    if a2 + b2 > 0.0 && a2.is_finite() {
        a2 / (a2 + b2)
    } else if a2.is_infinite() {
        1.0
    } else {
        0.0
    }
}

/// An unoccluded light sample seen from a surface point.
pub struct LightHit {
    /// Unit direction from the point to the light.
    pub wi: Vec3,
    /// Radiance arriving along `wi`.
    pub radiance: Vec3,
    /// Solid-angle pdf of the sample.
    pub pdf: f32,
}

/// The closest hit of a live path: (distance, triangle).
type WaveHit = Option<(f32, u32)>;

impl PathScene<'_> {
    /// Renders one camera view: the mean radiance over `cfg.spp` jittered samples per pixel,
    /// RGB row-major. `view_key` separates views in the random streams; `progress(n)` is called
    /// with the number of finished samples per pixel.
    pub fn render_view(
        &self,
        camera: &Camera,
        cfg: &PathConfig,
        view_key: u64,
        progress: &(dyn Fn(usize) + Sync),
    ) -> (Vec<f32>, PathStats) {
        let n_pix = camera.width * camera.height;
        let mut sum = vec![Vec3::ZERO; n_pix];
        let mut stats = PathStats::default();
        let per_wave = (cfg.wave / n_pix.max(1)).max(1);
        let mut done = 0;
        while done < cfg.spp {
            let k = per_wave.min(cfg.spp - done);
            let (rad, st) = self.trace_wave(camera, cfg, view_key, done, k);
            for (i, r) in rad.iter().enumerate() {
                sum[i % n_pix] += *r;
            }
            stats.add(&st);
            done += k;
            progress(done);
        }
        let inv = 1.0 / cfg.spp.max(1) as f32;
        (
            sum.iter().flat_map(|s| (*s * inv).to_array()).collect(),
            stats,
        )
    }

    /// Samples `first..first + count` of every pixel as one wavefront; returns each path's
    /// radiance (sample-major, pixel-minor) and the counters.
    fn trace_wave(
        &self,
        camera: &Camera,
        cfg: &PathConfig,
        view_key: u64,
        first: usize,
        count: usize,
    ) -> (Vec<Vec3>, PathStats) {
        let (w, n_pix) = (camera.width, camera.width * camera.height);
        let origin = camera.origin_f32();
        let starts: Vec<Option<PathStart>> = (0..count * n_pix)
            .into_par_iter()
            .map(|i| {
                let (s, p) = (first + i / n_pix, i % n_pix);
                let mut rng = Rng::new(cfg.seed, (view_key << 44) | ((p as u64) << 20) | s as u64);
                let (x, y) = ((p % w) as f64, (p / w) as f64);
                let (mut jx, mut jy) = (rng.next_f64(), rng.next_f64());
                let np = cfg.pixel_positions;
                if np > 0 {
                    let k = s % np;
                    let g = np.isqrt();
                    debug_assert_eq!(g * g, np, "pixel_positions must be a square");
                    let mut fixed = Rng::new(
                        cfg.seed ^ 0x5eed_9121,
                        (view_key << 44) | ((p as u64) << 20) | k as u64,
                    );
                    jx = ((k % g) as f64 + fixed.next_f64()) / g as f64;
                    jy = ((k / g) as f64 + fixed.next_f64()) / g as f64;
                }
                Some(PathStart {
                    origin,
                    dir: camera.direction_at(x + jx, y + jy),
                    rng,
                    pdf: 0.0,
                })
            })
            .collect();
        self.trace_paths(starts, cfg, 1)
    }

    /// Traces paths from the given rays (None: a path that carries nothing, radiance 0) whose
    /// first segment is segment `first_depth` of a path (1: camera rays; 2: rays leaving a
    /// first surface, as in shading refinement; the first segment is never MIS-weighted and
    /// the cache applies from segment 2 on). Returns each path's radiance and the counters.
    pub fn trace_paths(
        &self,
        starts: Vec<Option<PathStart>>,
        cfg: &PathConfig,
        first_depth: usize,
    ) -> (Vec<Vec3>, PathStats) {
        let mut paths: Vec<PathState> = starts
            .into_par_iter()
            .map(|s| match s {
                Some(s) => PathState {
                    origin: s.origin,
                    dir: s.dir,
                    throughput: Vec3::ONE,
                    radiance: Vec3::ZERO,
                    pdf_bsdf: s.pdf,
                    rng: s.rng,
                    alive: true,
                },
                None => PathState {
                    origin: Vec3::ZERO,
                    dir: Vec3::Z,
                    throughput: Vec3::ZERO,
                    radiance: Vec3::ZERO,
                    pdf_bsdf: 0.0,
                    rng: Rng::new(0, 0),
                    alive: false,
                },
            })
            .collect();
        let mut stats = PathStats {
            paths: paths.iter().filter(|p| p.alive).count() as u64,
            ..Default::default()
        };
        let mut hits: Vec<WaveHit> = Vec::new();
        let mut mats: Vec<SurfaceMaterial> = Vec::new();
        for depth in first_depth..=cfg.max_depth {
            // Closest hits of every live ray, traced in batches (`Accel::closest_many`).
            hits.clear();
            hits.resize(paths.len(), None);
            hits.par_chunks_mut(256)
                .zip(paths.par_chunks(256))
                .for_each(|(h, p)| {
                    let live: Vec<usize> = (0..p.len()).filter(|&i| p[i].alive).collect();
                    let rays: Vec<(Vec3, Vec3)> =
                        live.iter().map(|&i| (p[i].origin, p[i].dir)).collect();
                    let mut out = vec![None; rays.len()];
                    self.accel.closest_many(&rays, 0.0, f32::INFINITY, &mut out);
                    for (&i, o) in live.iter().zip(out) {
                        h[i] = o.map(|o| (o.t, o.tri));
                    }
                });
            stats.rays += paths.par_iter().filter(|p| p.alive).count() as u64;
            // One batched material query for all hit points, in path order.
            let (idx, (points, tris)): (Vec<usize>, (Vec<Vec3>, Vec<u32>)) = hits
                .par_iter()
                .enumerate()
                .filter_map(|(i, h)| {
                    h.map(|(t, tri)| (i, (paths[i].origin + paths[i].dir * t, tri)))
                })
                .unzip();
            let source = match self.secondary_materials {
                Some(m) if depth >= 2 => m,
                _ => self.materials,
            };
            source.query(&points, &tris, &mut mats);
            let mut mat_of = vec![u32::MAX; paths.len()];
            for (k, &i) in idx.iter().enumerate() {
                mat_of[i] = k as u32;
            }
            let cached = self.cache_lookups(&paths, &hits, &mat_of, &mats, depth);
            // Shade: emission, next-event estimation, BRDF sampling.
            let shadow: u64 = paths
                .par_iter_mut()
                .zip(&hits)
                .zip(&mat_of)
                .zip(&cached)
                .with_min_len(256)
                .map(|(((ps, hit), &m), &l)| {
                    if !ps.alive {
                        return 0;
                    }
                    let Some((t, tri)) = *hit else {
                        ps.alive = false;
                        return 0;
                    };
                    let vertex = PathVertex {
                        t,
                        tri,
                        mat: mats[m as usize],
                        cached: l,
                        depth,
                    };
                    self.shade(ps, &vertex, cfg)
                })
                .sum();
            stats.shadow_rays += shadow;
            if !paths.par_iter().any(|p| p.alive) {
                break;
            }
        }
        let radiance = paths
            .iter()
            .map(|p| {
                if p.radiance.is_finite() {
                    p.radiance
                } else {
                    stats.nonfinite += 1;
                    Vec3::ZERO
                }
            })
            .collect();
        (radiance, stats)
    }

    /// Next-event estimation from `x` (normal `n`): one point on one light from the random
    /// numbers `u`; the sample if the light faces `x`, lies above its horizon and is not
    /// occluded, and the shadow rays cast (0 or 1).
    pub fn sample_light(&self, x: Vec3, n: Vec3, u: (f32, f32, f32)) -> (Option<LightHit>, u64) {
        let Some(s) = self.emitters.sample(u.0, u.1, u.2) else {
            return (None, 0);
        };
        let to = s.point - x;
        let d2 = to.length_squared();
        let dist = d2.sqrt();
        let wi = to / dist;
        let lt = &self.emitters.lights[s.light as usize];
        let le = lt.radiance_towards(-wi);
        let cos_l = lt.normal.dot(wi).abs();
        if n.dot(wi) <= 0.0 || le == Vec3::ZERO || cos_l <= 0.0 || dist <= 2.0 * RAY_EPS {
            return (None, 0);
        }
        let o = x + wi * RAY_EPS;
        if self
            .accel
            .occluded(o, wi, 0.0, dist * (1.0 - 1e-4) - RAY_EPS)
        {
            return (None, 1);
        }
        let hit = LightHit {
            wi,
            radiance: le,
            pdf: s.pdf_area * d2 / cos_l,
        };
        (Some(hit), 1)
    }

    /// Whether the radiance cache applies at this vertex of segment `depth`: a hit on a
    /// non-emitter rougher than the cache's threshold (`cache_lookups` reads L′ there, and
    /// `shade` ends the path where that is lit).
    #[inline]
    fn cache_applies(&self, tri: u32, mat: &SurfaceMaterial, depth: usize) -> bool {
        self.cache.is_some_and(|c| {
            depth >= 2 && mat.roughness > c.min_roughness && self.emitters.light_of(tri).is_none()
        })
    }

    /// L′ at every hit of a wavefront where the radiance cache applies (0 elsewhere), looked
    /// up in batches whose cache misses overlap (`LightField::query_many`): the values `query`
    /// gives at the hit point on the side the ray hits.
    fn cache_lookups(
        &self,
        paths: &[PathState],
        hits: &[WaveHit],
        mat_of: &[u32],
        mats: &[SurfaceMaterial],
        depth: usize,
    ) -> Vec<Vec3> {
        let mut out = vec![Vec3::ZERO; paths.len()];
        let Some(c) = self.cache else {
            return out;
        };
        out.par_chunks_mut(1024)
            .zip(paths.par_chunks(1024))
            .zip(hits.par_chunks(1024))
            .zip(mat_of.par_chunks(1024))
            .for_each(|(((o, p), h), m)| {
                let queries: Vec<Option<(Vec3, Vec3)>> = (0..p.len())
                    .map(|i| {
                        let (t, tri) = h[i]?;
                        let ok = p[i].alive && self.cache_applies(tri, &mats[m[i] as usize], depth);
                        ok.then(|| {
                            let x = p[i].origin + p[i].dir * t;
                            (x, self.accel.facing_normal(tri, p[i].dir))
                        })
                    })
                    .collect();
                c.light_field.query_many(&queries, o);
            });
        out
    }

    /// Shades path `ps` at its next vertex `v`: emission, the radiance cache, next-event
    /// estimation and the next BRDF-sampled ray. Returns the shadow rays cast.
    fn shade(&self, ps: &mut PathState, v: &PathVertex, cfg: &PathConfig) -> u64 {
        let PathVertex {
            t,
            tri,
            mat,
            cached,
            depth,
        } = *v;
        let x = ps.origin + ps.dir * t;
        let wo = -ps.dir;
        // Emission seen along the ray, weighted against light sampling when a BRDF sample
        // made the ray.
        let light = self.emitters.light_of(tri);
        if let Some(l) = light {
            let le = self.emitters.lights[l as usize].radiance_towards(wo);
            if le != Vec3::ZERO {
                let w = if ps.pdf_bsdf > 0.0 {
                    let cos_l = self.emitters.lights[l as usize].normal.dot(wo).abs();
                    let pdf_light = self.emitters.pdf_area(l) * t * t / cos_l.max(1e-12);
                    power_heuristic(ps.pdf_bsdf, pdf_light)
                } else {
                    1.0
                };
                ps.radiance += ps.throughput * le * w;
            }
            if !cfg.emitters_reflect {
                ps.alive = false;
                return 0;
            }
        } else if cached.element_sum() > 0.0 {
            // The radiance cache applied here (`cache_lookups`: 0 where it does not) and L′ is
            // lit: the path takes it and ends.
            ps.radiance += ps.throughput * cached;
            ps.alive = false;
            return 0;
        }
        if depth == cfg.max_depth {
            ps.alive = false;
            return 0;
        }
        let n = self.accel.facing_normal(tri, ps.dir);
        let frame = Frame::new(n);
        let wo_l = frame.to_local(wo);
        let brdf = Brdf::from_material(mat.base_color, mat.roughness, mat.metallic);
        let p_spec = brdf.spec_probability(cfg.lobe);
        // Next-event estimation: one point on one light.
        let u = (ps.rng.next_f32(), ps.rng.next_f32(), ps.rng.next_f32());
        let (sample, shadow) = self.sample_light(x, n, u);
        if let Some(l) = sample {
            let wi_l = frame.to_local(l.wi);
            let f = brdf.f(wo_l, wi_l);
            let w = power_heuristic(l.pdf, brdf.pdf_mix(wo_l, wi_l, p_spec));
            ps.radiance += ps.throughput * f * wi_l.z.max(0.0) * l.radiance * (w / l.pdf);
        }
        // Continue with a BRDF sample.
        let (u0, u1, u2) = (ps.rng.next_f32(), ps.rng.next_f32(), ps.rng.next_f32());
        let (wi_l, weight, pdf) = brdf.sample_f_mix(wo_l, u0, u1, u2, p_spec);
        if weight == Vec3::ZERO || pdf <= 0.0 || !pdf.is_finite() {
            ps.alive = false;
            return shadow;
        }
        ps.throughput *= weight;
        if let Some(rr) = cfg.rr_depth
            && depth >= rr
        {
            let q = ps.throughput.max_element().min(0.95);
            if ps.rng.next_f32() >= q {
                ps.alive = false;
                return shadow;
            }
            ps.throughput /= q;
        }
        let wi = frame.to_world(wi_l).normalize();
        ps.origin = x + wi * RAY_EPS;
        ps.dir = wi;
        ps.pdf_bsdf = pdf;
        shadow
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::emitters::LightSelection;
    use fipt_core::brdf::directional_albedo_quadrature;
    use fipt_core::scene::procedural::PartMesh;
    use glam::DVec3;

    /// One material everywhere.
    struct Uniform(SurfaceMaterial);

    impl MaterialSource for Uniform {
        fn query(&self, points: &[Vec3], _tris: &[u32], out: &mut Vec<SurfaceMaterial>) {
            out.clear();
            out.resize(points.len(), self.0);
        }
    }

    const MAT: SurfaceMaterial = SurfaceMaterial {
        base_color: Vec3::new(0.7, 0.5, 0.3),
        roughness: 0.5,
        metallic: 0.2,
    };

    /// A closed unit box whose every triangle emits L_e = 1 (two-sided) and reflects with `MAT`.
    fn furnace(selection: LightSelection) -> (Accel, EmitterSet) {
        let mut pm = PartMesh::default();
        pm.cuboid("box", Vec3::ZERO, Vec3::ONE, 3);
        let mesh = pm.mesh;
        let em = EmitterSet::new(
            &mesh,
            (0..mesh.num_triangles() as u32).map(|t| (t, Vec3::ONE)),
            true,
            selection,
        );
        (Accel::build(&mesh), em)
    }

    /// A 4×4 camera with a 0.02 rad field of view from `eye` at `target` on a wall.
    fn camera(eye: DVec3, target: DVec3) -> Camera {
        Camera::look_at_fov(eye, target, DVec3::Y, 0.02, 4, 4)
    }

    fn render(
        cfg: &PathConfig,
        sel: LightSelection,
        cam: &Camera,
        reflect: bool,
    ) -> (Vec<f32>, PathStats) {
        let (accel, em) = furnace(sel);
        let mats = Uniform(MAT);
        let scene = PathScene {
            secondary_materials: None,
            cache: None,
            accel: &accel,
            materials: &mats,
            emitters: &em,
        };
        let cfg = PathConfig {
            emitters_reflect: reflect,
            ..cfg.clone()
        };
        scene.render_view(cam, &cfg, 0, &|_| {})
    }

    /// Furnace with two segments (direct light only): L = L_e + L_e·a′(ω_o), a′ the directional
    /// albedo of the BRDF at the wall seen (quadrature). Both strategies (lights and BRDF
    /// sampling) carry energy here; a wrong MIS weight, pdf or cosine breaks the sum. One
    /// segment gives L_e; emitters that do not reflect give L_e at any depth.
    #[test]
    fn furnace_direct_light_is_one_plus_the_albedo() {
        let cases = [
            (DVec3::new(0.5, 0.5, 0.1), DVec3::new(0.5, 0.5, 1.0)),
            (DVec3::new(0.1, 0.5, 0.5), DVec3::new(0.6, 0.5, 1.0)),
        ];
        for sel in [
            LightSelection::Uniform,
            LightSelection::Area,
            LightSelection::Power,
        ] {
            for (eye, target) in cases {
                let cam = camera(eye, target);
                let cfg = PathConfig {
                    spp: 2048,
                    max_depth: 2,
                    seed: 3,
                    ..Default::default()
                };
                let (img, stats) = render(&cfg, sel, &cam, true);
                assert_eq!(stats.nonfinite, 0);
                let wo = (eye - target).normalize().as_vec3();
                let brdf = Brdf::from_material(MAT.base_color, MAT.roughness, MAT.metallic);
                let wo_l = Vec3::new((1.0 - wo.z * wo.z).max(0.0).sqrt(), 0.0, -wo.z);
                let a = directional_albedo_quadrature(&brdf, wo_l, 512, 1024);
                for c in 0..3 {
                    let mean = img.iter().skip(c).step_by(3).sum::<f32>() / 16.0;
                    let want = 1.0 + a[c];
                    assert!(
                        (mean - want).abs() < 0.01 * want,
                        "{sel:?} eye {eye}: channel {c} {mean:.4} vs {want:.4}"
                    );
                }
                let one = PathConfig {
                    max_depth: 1,
                    spp: 4,
                    ..cfg.clone()
                };
                let (img, _) = render(&one, sel, &cam, true);
                assert!(img.iter().all(|&v| (v - 1.0).abs() < 1e-6));
                let (img, _) = render(&cfg, sel, &cam, false);
                assert!(img.iter().all(|&v| (v - 1.0).abs() < 1e-6));
            }
        }
    }

    /// Same seed → bit-identical image for any thread count and wavefront size.
    #[test]
    fn render_is_deterministic() {
        let cam = camera(DVec3::new(0.5, 0.5, 0.1), DVec3::new(0.5, 0.5, 1.0));
        let cfg = PathConfig {
            spp: 64,
            max_depth: 5,
            ..Default::default()
        };
        let run = |threads: usize, wave: usize| {
            rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .build()
                .unwrap()
                .install(|| {
                    render(
                        &PathConfig {
                            wave,
                            ..cfg.clone()
                        },
                        LightSelection::Power,
                        &cam,
                        true,
                    )
                    .0
                })
        };
        let a = run(1, 1 << 18);
        let b = run(2, 100);
        assert_eq!(
            a.iter().map(|v| v.to_bits()).collect::<Vec<_>>(),
            b.iter().map(|v| v.to_bits()).collect::<Vec<_>>()
        );
    }
}
