//! The built-in demo: a room described as data (`configs/demo-scene.json`, compiled in), its
//! photos and ground-truth maps rendered by fipt's own path tracer into the FIPT synthetic
//! layout (so `check`, `run` and any FIPT tool read it), then the whole pipeline on it.
//!
//! The scene folder is cached: a stamp (the description, the code version) says whether it is
//! current, and a second demo skips the rendering. It is written under a temporary name and
//! renamed, so it is complete or absent.
//!
//! Owns: the scene description's schema (`Desc`), the scene writer and the demo job. Must not touch:
//! light transport (fipt-bake), the pipeline's stages.

use crate::pipeline::predict::{ViewMaps, albedo_mc};
use crate::rerender::{CamRef, Edits, TrueScene, render_truth};
use anyhow::{Context, Result};
use fipt_bake::Accel;
use fipt_bake::emitters::LightSelection;
use fipt_bake::integrators::path::PathConfig;
use fipt_bake::materials::TrueMaterials;
use fipt_core::io::Fnv64;
use fipt_core::rng::Rng;
use fipt_core::scene::meta::{Part, PartEmission, PartMaterial, Relight, SceneMeta};
use fipt_core::scene::procedural::PartMesh;
use fipt_core::scene::{Camera, Image, MapKind, Mesh};
use glam::{DVec3, Vec3};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};

/// The demo room, as shipped.
pub const DEMO_SCENE: &str = include_str!("../../configs/demo-scene.json");
/// The demo's run configuration, as shipped.
pub const DEMO_CONFIG: &str = include_str!("../../configs/demo.json");

/// A room as data (`configs/demo-scene.json`'s schema; `suite::generate` draws them at random).
#[derive(Clone, Debug, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Desc {
    pub name: String,
    #[serde(default)]
    pub description: String,
    pub resolution: [usize; 2],
    pub fov_x_deg: f64,
    pub train_views: usize,
    pub val_views: usize,
    pub spp: usize,
    pub max_depth: usize,
    pub albedo_samples: usize,
    pub seed: u64,
    /// The first train views each look at one emitter part, so every emitter is photographed
    /// (as a capture of a room would); the others look at random surface points.
    #[serde(default)]
    pub emitter_views: bool,
    pub parts: Vec<PartDesc>,
    pub relight: Relight,
}

/// One part: its shapes, its material and its emission.
#[derive(Clone, Debug, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PartDesc {
    pub name: String,
    pub semantic: String,
    pub shapes: Vec<Shape>,
    pub material: MatDesc,
    #[serde(default)]
    pub emission: Option<[f32; 3]>,
}

/// A shape of a part; grids face `u × v`, cuboids and spheres outwards.
#[derive(Clone, Debug, Serialize, Deserialize)]
#[serde(rename_all = "lowercase", deny_unknown_fields)]
pub enum Shape {
    Grid {
        origin: [f32; 3],
        u: [f32; 3],
        v: [f32; 3],
        n: [usize; 2],
    },
    Cuboid {
        lo: [f32; 3],
        hi: [f32; 3],
        n: usize,
    },
    Sphere {
        centre: [f32; 3],
        r: f32,
        n: [usize; 2],
    },
}

/// A part's material: a constant base colour or a checker texture.
#[derive(Clone, Debug, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct MatDesc {
    #[serde(default)]
    pub base_color: Option<[f32; 3]>,
    #[serde(default)]
    pub checker: Option<Checker>,
    pub roughness: f32,
    pub metallic: f32,
}

/// A two-colour checker texture, mapped planar-world.
#[derive(Clone, Debug, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Checker {
    pub colors: [[f32; 3]; 2],
    pub cells: [usize; 2],
    pub size: [f32; 2],
    pub origin: [f32; 3],
    pub axis_u: [f32; 3],
    pub axis_v: [f32; 3],
}

/// The mesh of every part, parts in order (contiguous triangle ranges).
fn build_mesh(d: &Desc) -> (Mesh, Vec<[usize; 2]>) {
    let mut mesh = Mesh::default();
    let mut ranges = Vec::new();
    for p in &d.parts {
        let start = mesh.num_triangles();
        for s in &p.shapes {
            let mut pm = PartMesh::default();
            match *s {
                Shape::Grid { origin, u, v, n } => pm.grid(
                    "",
                    origin.into(),
                    u.into(),
                    v.into(),
                    n[0].max(1),
                    n[1].max(1),
                ),
                Shape::Cuboid { lo, hi, n } => pm.cuboid("", lo.into(), hi.into(), n.max(1)),
                Shape::Sphere { centre, r, n } => {
                    pm.sphere("", centre.into(), r, n[0].max(3), n[1].max(3))
                }
            }
            let off = mesh.vertices.len() as u32;
            mesh.vertices.extend_from_slice(&pm.mesh.vertices);
            mesh.triangles
                .extend(pm.mesh.triangles.iter().map(|t| t.map(|i| i + off)));
        }
        ranges.push([start, mesh.num_triangles()]);
    }
    (mesh, ranges)
}

/// Cameras inside the room looking at random surface points; deterministic. Half the targets
/// are area-weighted over the whole room (walls, floor and ceiling get photographed, so L′ covers
/// them), half are area-weighted within a part drawn uniformly (small objects and emitters get
/// close-ups), so that the bake sees the whole room and not only the finely tessellated parts.
fn cameras(d: &Desc, mesh: &Mesh, ranges: &[[usize; 2]], n: usize, stream: u64) -> Vec<Camera> {
    let (lo, hi) = mesh.bounds();
    let mut rng = Rng::new(d.seed, stream);
    // Cumulative areas: the whole mesh is one table, each part a slice of it.
    let cdf = mesh.area_cdf();
    let pick = |r: &mut Rng, range: [usize; 2]| -> Vec3 {
        let t = Mesh::triangle_by_area(&cdf, range, r.next_f32() as f64);
        mesh.point_at(t, r.next_f32(), r.next_f32())
    };
    let accel = Accel::build(mesh);
    let emitter_ranges: Vec<[usize; 2]> = if d.emitter_views && stream == 1 {
        (d.parts.iter().zip(ranges))
            .filter(|(p, _)| p.emission.is_some())
            .map(|(_, r)| *r)
            .collect()
    } else {
        Vec::new()
    };
    let mut out = Vec::with_capacity(n);
    while out.len() < n {
        let u = |r: &mut Rng, a: f32, b: f32| a + (b - a) * r.next_f32();
        let eye = Vec3::new(
            u(&mut rng, lo.x + 0.4, hi.x - 0.4),
            u(&mut rng, 0.95, (hi.y - 0.6).max(1.0)),
            u(&mut rng, lo.z + 0.4, hi.z - 0.4),
        );
        let range = if let Some(&r) = emitter_ranges.get(out.len()) {
            r
        } else if rng.next_f32() < 0.5 {
            [0, mesh.num_triangles()]
        } else {
            ranges[(rng.next_f32() * ranges.len() as f32) as usize % ranges.len()]
        };
        let target = pick(&mut rng, range);
        let dir = target - eye;
        if dir.length() < 0.8 {
            continue;
        }
        // The eye must see the target (not inside or behind furniture).
        let hit = accel.closest(eye, dir.normalize(), 1e-4, f32::INFINITY);
        if hit.is_none_or(|h| h.t < 0.5 * dir.length()) {
            continue;
        }
        out.push(Camera::look_at_fov(
            eye.as_dvec3(),
            target.as_dvec3(),
            DVec3::Y,
            d.fov_x_deg.to_radians(),
            d.resolution[0],
            d.resolution[1],
        ));
    }
    out
}

/// FIPT's `transform_matrix`: c2w with columns (left, up, forward, position).
fn fipt_c2w(c: &Camera) -> [[f64; 4]; 4] {
    let (right, down, fwd) = (c.rotation.x_axis, c.rotation.y_axis, c.rotation.z_axis);
    let cols = [-right, -down, fwd, c.origin];
    let mut m = [[0.0; 4]; 4];
    for (j, col) in cols.iter().enumerate() {
        m[0][j] = col.x;
        m[1][j] = col.y;
        m[2][j] = col.z;
    }
    m[3][3] = 1.0;
    m
}

/// The demo scene being written: its description, geometry and true materials.
struct DemoScene<'a> {
    dir: &'a Path,
    d: &'a Desc,
    mesh: Mesh,
    /// Each part's triangle range, and each triangle's part.
    ranges: Vec<[usize; 2]>,
    tri_part: Vec<usize>,
    accel: Accel,
    meta: SceneMeta,
    mats: TrueMaterials,
}

/// The ground-truth maps of one camera at pixel centres (as the reference scenes' maps are):
/// k_d, σ, m, a, a′ (Monte Carlo), emission towards the camera, part ids and semantic ids.
fn gt_maps(sc: &DemoScene, cam: &Camera, view_key: u64) -> (ViewMaps, Vec<f32>, Vec<f32>) {
    let (accel, mesh, mats, meta, d) = (&sc.accel, &sc.mesh, &sc.mats, &sc.meta, sc.d);
    let tri_part = &sc.tri_part;
    let (w, h) = (cam.width, cam.height);
    let origin = cam.origin_f32();
    let px: Vec<_> = (0..w * h)
        .into_par_iter()
        .map(|p| {
            let dir = cam.pixel_direction(p / w, p % w);
            let Some(hit) = accel.closest(origin, dir, 0.0, f32::INFINITY) else {
                return (
                    [0.0f32; 3],
                    1.0f32,
                    0.0f32,
                    [0.0f32; 3],
                    [0.0f32; 3],
                    [0.0f32; 3],
                    0.0f32,
                    0.0f32,
                );
            };
            let x = origin + dir * hit.t;
            let m = mats.at(x, hit.tri);
            let part = &meta.parts[tri_part[hit.tri as usize]];
            let ng = mesh.normal(hit.tri as usize);
            let front = ng.dot(-dir) > 0.0;
            let n = if front { ng } else { -ng };
            let base = m.base_color;
            let kd = base * (1.0 - m.metallic);
            let ks = Vec3::splat(0.04 * (1.0 - m.metallic)) + base * m.metallic;
            let mut rng = Rng::new(d.seed ^ 0x00a1_bed0, (view_key << 32) | p as u64);
            let albedo = albedo_mc(kd, ks, m.roughness, n, -dir, d.albedo_samples, &mut rng);
            let emit = match &part.emission {
                Some(e) if front => e.radiance,
                _ => [0.0; 3],
            };
            (
                kd.to_array(),
                m.roughness,
                m.metallic,
                base.to_array(),
                albedo.to_array(),
                emit,
                part.id as f32,
                part.semantic_id as f32,
            )
        })
        .collect();
    let mut vm = ViewMaps {
        width: w,
        height: h,
        kd: Vec::with_capacity(3 * w * h),
        sigma: Vec::with_capacity(w * h),
        metallic: Vec::with_capacity(w * h),
        base: Vec::with_capacity(3 * w * h),
        albedo: Vec::with_capacity(3 * w * h),
        emit: Vec::with_capacity(3 * w * h),
    };
    let (mut ids, mut sem) = (Vec::new(), Vec::new());
    for (kd, s, m, base, al, e, id, se) in px {
        vm.kd.extend(kd);
        vm.sigma.push(s);
        vm.metallic.push(m);
        vm.base.extend(base);
        vm.albedo.extend(al);
        vm.emit.extend(e);
        ids.extend([id; 3]);
        sem.extend([se; 3]);
    }
    (vm, ids, sem)
}

/// The cache stamp: the description and the code version.
pub(crate) fn stamp(text: &str) -> String {
    let mut h = Fnv64::default();
    h.bytes(text.as_bytes());
    h.bytes(env!("CARGO_PKG_VERSION").as_bytes());
    format!("{:016x}", h.finish())
}

const STAMP_FILE: &str = "demo.stamp";

/// The cache stamp of the scene written into `dir`, if there is one.
pub fn scene_stamp(dir: &Path) -> Option<String> {
    let t = std::fs::read_to_string(dir.join(STAMP_FILE)).ok()?;
    Some(t.trim().to_owned())
}

/// Writes the demo scene into `dir` unless it is there and current; returns whether it was
/// written.
pub fn write_scene(dir: &Path, quiet: bool) -> Result<bool> {
    write_scene_text(dir, DEMO_SCENE, "configs/demo-scene.json", quiet)
}

/// Writes the scene that the description `text` (named `what` in errors) gives into `dir`
/// unless it is there and current (its stamp: the text and the code version); returns whether
/// it was written.
pub fn write_scene_text(dir: &Path, text: &str, what: &str, quiet: bool) -> Result<bool> {
    let s = stamp(text);
    if scene_stamp(dir).is_some_and(|t| t == s) {
        return Ok(false);
    }
    let d: Desc = serde_json::from_str(text).with_context(|| format!("{what}: malformed"))?;
    crate::output::staged_dir(dir, |tmp| {
        std::fs::create_dir_all(tmp.join("textures"))
            .with_context(|| format!("{}: cannot create", tmp.display()))?;
        write_into(tmp, &d, quiet)?;
        fipt_core::io::write_bytes_atomic(&tmp.join(STAMP_FILE), s.as_bytes())?;
        Ok(())
    })?;
    Ok(true)
}

fn write_into(dir: &Path, d: &Desc, quiet: bool) -> Result<()> {
    let (mesh, ranges) = build_mesh(d);
    mesh.save_obj(
        &dir.join("scene.obj"),
        &format!("{}: {}", d.name, d.description),
    )?;
    let meta = scene_meta(dir, d, &mesh, &ranges)?;
    crate::output::write_json(&dir.join("scene_meta.json"), &meta)?;
    crate::output::write_json(&dir.join("relight.json"), &d.relight)?;
    let mats = TrueMaterials::load(
        dir,
        &dir.join("scene_meta.json"),
        &meta,
        mesh.num_triangles(),
    )?;
    let mut tri_part = vec![0usize; mesh.num_triangles()];
    for (i, r) in ranges.iter().enumerate() {
        tri_part[r[0]..r[1]].iter_mut().for_each(|t| *t = i);
    }
    let sc = DemoScene {
        dir,
        d,
        accel: Accel::build(&mesh),
        mesh,
        ranges,
        tri_part,
        meta,
        mats,
    };
    let path = PathConfig {
        spp: d.spp,
        max_depth: d.max_depth,
        seed: d.seed,
        ..Default::default()
    };
    for (split, n, stream) in [("train", d.train_views, 1u64), ("val", d.val_views, 2)] {
        write_split(&sc, split, (n, stream), &path, quiet)?;
    }
    Ok(())
}

/// The scene's `scene_meta.json` (its parts with their materials, textures written into
/// `dir/textures`, and emission; semantic labels in order of first use).
fn scene_meta(dir: &Path, d: &Desc, mesh: &Mesh, ranges: &[[usize; 2]]) -> Result<SceneMeta> {
    // Semantic labels in order of first use.
    let mut labels: Vec<String> = Vec::new();
    let mut parts = Vec::new();
    for (id, (p, r)) in d.parts.iter().zip(ranges).enumerate() {
        if !labels.contains(&p.semantic) {
            labels.push(p.semantic.clone());
        }
        let area: f64 = (r[0]..r[1]).map(|t| mesh.area(t) as f64).sum();
        let texture = match &p.material.checker {
            Some(c) => {
                let file = format!("textures/{}.exr", p.name);
                let (w, h) = (c.cells[0].max(1), c.cells[1].max(1));
                let data: Vec<f32> = (0..w * h)
                    .flat_map(|i| c.colors[((i % w) + (i / w)) % 2])
                    .collect();
                Image::from_data(w, h, 3, data).write_exr(&dir.join(&file))?;
                let mean: Vec<f32> = (0..3)
                    .map(|k| 0.5 * (c.colors[0][k] + c.colors[1][k]))
                    .collect();
                Some(serde_json::json!({
                    "file": file, "width": w, "height": h, "mapping": "planar-world",
                    "origin": c.origin, "axis_u": c.axis_u, "axis_v": c.axis_v,
                    "size_u": c.size[0], "size_v": c.size[1], "filter": "nearest",
                    "wrap": "repeat", "mean_color": mean,
                }))
            }
            None => None,
        };
        parts.push(Part {
            id,
            name: p.name.clone(),
            semantic: p.semantic.clone(),
            semantic_id: labels.iter().position(|l| *l == p.semantic).unwrap_or(0),
            triangles: *r,
            area,
            material: PartMaterial {
                base_color: if texture.is_some() {
                    None
                } else {
                    p.material.base_color
                },
                roughness: p.material.roughness,
                metallic: p.material.metallic,
                texture,
            },
            emission: p.emission.map(|e| PartEmission {
                radiance: e,
                side: "front".into(),
            }),
        });
    }
    Ok(SceneMeta {
        scene: d.name.clone(),
        semantic_labels: labels,
        parts,
        resolution: Some(d.resolution),
        camera_angle_x: Some(d.fov_x_deg.to_radians()),
    })
}

/// One split of `n` views (camera stream `stream`): its cameras, ground-truth maps, photos and,
/// for `val`, the relit photos.
fn write_split(
    sc: &DemoScene,
    split: &str,
    (n, stream): (usize, u64),
    path: &PathConfig,
    quiet: bool,
) -> Result<()> {
    let fov = sc.d.fov_x_deg.to_radians();
    let (d, dir) = (sc.d, sc.dir);
    let sdir = dir.join(split);
    let cams = cameras(d, &sc.mesh, &sc.ranges, n, stream);
    let frames: Vec<_> = cams
            .iter()
            .enumerate()
            .map(|(k, c)| {
                serde_json::json!({"file_path": format!("Image/{k:03}_0001"), "transform_matrix": fipt_c2w(c)})
            })
            .collect();
    crate::output::write_json(
        &sdir.join("transforms.json"),
        &serde_json::json!({"camera_angle_x": fov, "frames": frames}),
    )?;
    for (k, c) in cams.iter().enumerate() {
        let (maps, ids, sem) = gt_maps(sc, c, (stream << 16) | k as u64);
        maps.write(&sdir, k)?;
        let (w, h) = (c.width, c.height);
        for (kind, v) in [(MapKind::IndexMA, ids), (MapKind::Segmentation, sem)] {
            Image::from_data(w, h, 3, v)
                .write_exr(&sdir.join(kind.folder()).join(kind.file_name(k)))?;
        }
    }
    let refs: Vec<CamRef> = cams
        .iter()
        .enumerate()
        .map(|(k, c)| (k, c.clone(), None))
        .collect();
    let picked: Vec<&CamRef> = refs.iter().collect();
    let truth = TrueScene {
        dir,
        mesh: &sc.mesh,
        meta: &sc.meta,
    };
    render_truth(
        &truth,
        &Edits::default(),
        &picked,
        path,
        LightSelection::Power,
        &sdir.join("Image"),
        quiet,
    )?;
    if split == "val" {
        let edits = Edits {
            relight: Some(&d.relight),
            meta: Some(&sc.meta),
            inserted: &[],
        };
        render_truth(
            &truth,
            &edits,
            &picked,
            path,
            LightSelection::Power,
            &sdir.join("Relight"),
            quiet,
        )?;
    }
    Ok(())
}

/// `fipt-train demo`: the demo scene (cached in `OUT/scene`), then `run` on it into
/// `OUT/run` with the shipped demo config; returns the run's report path.
pub fn demo(out: &Path, quiet: bool) -> Result<PathBuf> {
    // One demo per folder (the run in OUT/run holds its own lock too).
    let _lock = crate::lock::DirLock::acquire(out)?;
    let scene = out.join("scene");
    let t = std::time::Instant::now();
    let written = write_scene(&scene, quiet)?;
    if !quiet {
        if written {
            println!(
                "demo scene rendered in {:.0} s: {}",
                t.elapsed().as_secs_f64(),
                scene.display()
            );
        } else {
            println!("demo scene from the cache: {}", scene.display());
        }
    }
    let cfg = crate::config::Config::from_json(DEMO_CONFIG).context("configs/demo.json")?;
    let run_out = out.join("run");
    let opts = crate::pipeline::RunOptions {
        quiet,
        oracle: false,
        zoo: Some((out.join("zoo"), "fipt-demo".to_string())),
    };
    crate::pipeline::run_with(&scene, &run_out, &cfg, &opts)?;
    Ok(run_out.join("report.html"))
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;

    /// The shipped description parses and builds a sound room (`assert_room_sound`).
    #[test]
    fn shipped_room_is_sound() {
        let d: Desc = serde_json::from_str(DEMO_SCENE).unwrap();
        assert_room_sound(&d);
    }

    /// Every part has triangles, every wall faces inwards (a ray from the room's centre hits
    /// each wall, floor and ceiling on its front), the cameras are deterministic, and every
    /// emitter is seen from the front by a train camera's pixel-centre rays.
    pub(crate) fn assert_room_sound(d: &Desc) {
        let (mesh, ranges) = build_mesh(d);
        assert!(
            ranges.iter().all(|r| r[1] > r[0]),
            "{}: an empty part",
            d.name
        );
        mesh.validate(Path::new("demo")).unwrap();
        let accel = Accel::build(&mesh);
        let (lo, hi) = mesh.bounds();
        // Off the grids' cell edges.
        let at = |f: f32, a: f32, b: f32| a + f * (b - a);
        let centre = Vec3::new(
            at(0.507, lo.x, hi.x),
            at(0.62, lo.y, hi.y),
            at(0.49, lo.z, hi.z),
        );
        for dir in [Vec3::X, -Vec3::X, Vec3::Y, -Vec3::Y, Vec3::Z, -Vec3::Z] {
            let h = accel
                .closest(centre, dir, 0.0, f32::INFINITY)
                .unwrap_or_else(|| panic!("{}: no hit towards {dir}", d.name));
            assert!(
                mesh.cross(h.tri as usize).dot(-dir) > 0.0,
                "{}: back face towards {dir}",
                d.name
            );
        }
        let cams = cameras(d, &mesh, &ranges, d.train_views, 1);
        assert_eq!(cams.len(), d.train_views);
        assert_eq!(
            cams[3].origin,
            cameras(d, &mesh, &ranges, d.train_views, 1)[3].origin
        );
        let mut seen = vec![false; d.parts.len()];
        for c in &cams {
            let (w, h) = (c.width, c.height);
            for p in 0..w * h {
                let dir = c.pixel_direction(p / w, p % w);
                if let Some(hit) = accel.closest(c.origin_f32(), dir, 0.0, f32::INFINITY) {
                    let t = hit.tri as usize;
                    let part = ranges
                        .iter()
                        .position(|r| (r[0]..r[1]).contains(&t))
                        .unwrap();
                    if mesh.cross(t).dot(-dir) > 0.0 {
                        seen[part] = true;
                    }
                }
            }
        }
        for (p, s) in d.parts.iter().zip(&seen) {
            if p.emission.is_some() {
                assert!(
                    *s,
                    "{}: emitter {} is never seen from the front",
                    d.name, p.name
                );
            }
        }
    }
}
