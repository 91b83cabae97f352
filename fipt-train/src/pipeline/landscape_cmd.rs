//! `fipt-train landscape`: the per-part loss landscapes (`landscape`) of a run's shadings —
//! baked, every refined round cached in its output folder, and the oracle's — into
//! `out/landscape.json`, and their printed tables.
//!
//! Owns: that command's inputs and outputs. Must not touch: the sweep itself.

use super::context::{RunContext, RunOptions};
use super::landscape::{PartLandscape, SWEEP, landscape};
use super::{bake, refine, score};
use crate::config::Config;
use crate::output::write_json;
use anyhow::Result;
use std::path::Path;

/// Which tables `landscapes` adds to the baked and refined shadings' and how it chooses pixels.
#[derive(Clone, Debug, Default)]
pub struct Tables {
    /// The oracle shadings' table (computed and cached).
    pub oracle: bool,
    /// Every table also at the fitted model's base colour and metallic.
    pub fitted: bool,
    /// Coverage measured per plane of the mesh instead of per part.
    pub cover_planes: bool,
    /// The tables of the shadings with part of the oracle swapped for the model in `out/model`
    /// (`refine::swapped`), one more per part named here.
    pub swap: Option<Vec<String>>,
}

/// `fipt-train landscape`: the per-part loss landscape of the baked shadings, of every refined
/// round cached in `out/cache`, and with `what.oracle` of the oracle shadings; written to
/// `out/landscape.json` and returned as (shadings name, table). With `what.fitted`, every table
/// also sweeps σ at the base colour and metallic of the model `run` left in `out/maps/train`,
/// and gives that model's own data term. Every table leaves out the pixels within
/// `refine.emitter_margin` of a true emitter's, and with `train.min_coverage` τ those that
/// their part (with `what.cover_planes`, their plane of the mesh) covers less than τ of.
pub fn landscapes(
    scene: &Path,
    out: &Path,
    cfg: &Config,
    what: Tables,
    quiet: bool,
) -> Result<Vec<(String, Vec<PartLandscape>)>> {
    let Tables {
        oracle,
        fitted,
        cover_planes,
        swap,
    } = what;
    if cover_planes && cfg.train.min_coverage <= 0.0 {
        anyhow::bail!(
            "--cover-planes needs train.min_coverage > 0 in the config (it is {})",
            cfg.train.min_coverage
        );
    }
    let opts = RunOptions {
        quiet,
        oracle,
        zoo: None,
    };
    let ctx = RunContext::load(scene, out, cfg, &opts)?;
    let ds = &ctx.ds;
    // The model and the part names of `swap`, checked before anything is traced.
    let swap = match swap {
        Some(mut parts) => {
            let mut seen = std::collections::HashSet::new();
            parts.retain(|p| seen.insert(p.clone()));
            let parts = refine::part_triangles(scene, ds, &parts)?;
            let device = cfg.backend.device().map_err(anyhow::Error::msg)?;
            let m = crate::scene_model::SceneModel::load(&out.join("model"), &device)?;
            Some((m, parts))
        }
        None => None,
    };
    let maps = if fitted {
        Some(score::read_train_maps(ds, out)?)
    } else {
        None
    };
    let maps = maps.as_deref();
    let (baked, _) = bake::bake_cached(out, ds, &ctx.accel, &ctx.bake_cfg, ctx.progress())?;
    // Each table's prior is that of the fit on those shadings (round 0's for the baked and the
    // oracle shadings, round r's for `refine{r}.bin`).
    let prior = |r: usize| {
        let t = cfg.train_for_round(r);
        fipt_core::model::loss::DiffusePrior {
            lambda_d: t.lambda_d,
            sigma: t.prior_sigma,
        }
    };
    // The pixels the fits leave out: next to an emitter, and split between two parts (the
    // true parts' keys; with `cover_planes`, two planes of the mesh).
    let cover = (cfg.train.min_coverage > 0.0).then(|| {
        let parts = ds
            .meta
            .as_ref()
            .map(|m| m.triangle_part(ds.mesh.num_triangles()));
        let keys = super::pixels::CoverKeys::with_crease(
            cover_keys(&ds.mesh, parts, cover_planes),
            &ds.mesh,
            cfg.train.coverage_crease,
        );
        let cams = ds.train.views.iter().map(|v| &v.camera);
        let c = super::pixels::coverage(&ctx.accel, cams, &baked.hits, &keys);
        (c, cfg.train.min_coverage)
    });
    let left = super::landscape::LeftOut {
        margin: cfg.refine.emitter_margin,
        cover,
    };
    // The patch profile's cubes: `train.hop.patch` footprints a side (2 where the hop has none).
    let sb = baked.light_field.scene_box;
    let footprint = super::pixels::pixel_footprint(&ds.train, &baked.hits, &sb);
    let per = cfg.train.hop.as_ref().map_or(0.0, |h| h.patch).max(0.0);
    let side = (footprint * (sb.max - sb.min) as f64) as f32 * if per > 0.0 { per } else { 2.0 };
    let with_patch = |mut rows: Vec<PartLandscape>, s: &[Vec<f32>]| {
        super::landscape::patch_profile(ds, &baked.hits, s, &left, side, &mut rows);
        rows
    };
    let mut tables = vec![(
        "baked".to_string(),
        with_patch(
            landscape(ds, &baked.hits, &baked.shadings, prior(0), maps, &left),
            &baked.shadings,
        ),
    )];
    let (w, h, n) = (ds.train.width, ds.train.height, ds.train.views.len());
    for r in 1.. {
        let path = out.join("cache").join(format!("refine{r}.bin"));
        let Some(s) = crate::cache::load_keyed(&path, None, n, w, h)? else {
            break;
        };
        tables.push((
            format!("refined{r}"),
            with_patch(landscape(ds, &baked.hits, &s, prior(r), maps, &left), &s),
        ));
    }
    if oracle {
        let s = refine::oracle_cached(&ctx, &baked)?;
        tables.push((
            "oracle".to_string(),
            with_patch(landscape(ds, &baked.hits, &s, prior(0), maps, &left), &s),
        ));
    }
    if let Some((m, parts)) = swap {
        for (name, s) in refine::swapped(&ctx, &baked, &m.model, &m.emitters, &parts)? {
            tables.push((
                name,
                with_patch(landscape(ds, &baked.hits, &s, prior(0), maps, &left), &s),
            ));
        }
    }
    let json: serde_json::Map<String, serde_json::Value> = tables
        .iter()
        .map(|(k, v)| (k.clone(), serde_json::to_value(v).unwrap_or_default()))
        .collect();
    write_json(&out.join("landscape.json"), &json)?;
    Ok(tables)
}

/// The coverage keys per triangle: its true part (`parts`, from `scene_meta.json`), or with
/// `planes` or without parts its plane of the mesh (`ldr::edges::plane_keys`).
fn cover_keys(mesh: &fipt_core::scene::Mesh, parts: Option<Vec<usize>>, planes: bool) -> Vec<u64> {
    match parts.filter(|_| !planes) {
        Some(p) => p.into_iter().map(|p| p as u64).collect(),
        None => crate::ldr::edges::plane_keys(mesh),
    }
}

/// Prints `landscapes`' tables: per part the argmin over σ at the true a and m, and where a
/// fitted model was swept, where it stands.
pub fn print_tables(tables: &[(String, Vec<PartLandscape>)]) {
    for (name, rows) in tables {
        println!("\n{name}: argmin over σ at the true a and m");
        println!(
            "part                  pixels   σ true  m true   argmin data   argmin data+prior   render/photo  argmin patch  patch/min at .1 .2 .3 .4 .5 .6 .7 .8 .9 1"
        );
        for r in rows {
            let mn = r.patch.iter().cloned().fold(f64::INFINITY, f64::min);
            let at: Vec<String> = [0.1f64, 0.2, 0.3, 0.4, 0.5, 0.6, 0.7, 0.8, 0.9, 1.0]
                .iter()
                .filter_map(|s| {
                    let j = ((s - 0.02) / 0.98 * (SWEEP - 1) as f64).round() as usize;
                    r.patch.get(j).map(|v| format!("{:.3}", v / mn))
                })
                .collect();
            println!(
                "{:<20} {:>7}   {:>6.2}  {:>6.2}   {:>11.2}   {:>17.2}   {:>12.3}  {:>6.2}  {}",
                r.name,
                r.pixels,
                r.sigma_true,
                r.m_true,
                r.argmin_data,
                r.argmin_total,
                r.render_ratio,
                r.argmin_patch,
                at.join(" ")
            );
        }
        if rows.iter().any(|r| r.fitted.is_some()) {
            println!("{name}: the fitted model (data terms x 1e4; at its a and m, σ swept)");
            println!(
                "part                 data at truth   fit σ   fit m   fit data   argmin at fit a, m   data there"
            );
            for r in rows {
                if let Some(f) = &r.fitted {
                    let best = f.data.iter().cloned().fold(f64::INFINITY, f64::min);
                    println!(
                        "{:<20} {:>13.3}   {:>5.2}   {:>5.2}   {:>8.3}   {:>18.2}   {:>10.3}",
                        r.name,
                        r.loss_true * 1e4,
                        f.sigma,
                        f.metallic,
                        f.loss * 1e4,
                        f.argmin_data,
                        best * 1e4
                    );
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::cover_keys;
    use fipt_core::scene::procedural::PartMesh;
    use glam::Vec3;

    /// One box part: by part every triangle shares a key; by plane the six faces get six keys,
    /// the triangles of one face the same.
    #[test]
    fn cover_keys_split_a_part_into_its_faces_by_plane() {
        let mut pm = PartMesh::default();
        pm.cuboid("leg", Vec3::ZERO, Vec3::new(0.05, 0.7, 0.05), 2);
        let n = pm.mesh.num_triangles();
        let parts = Some(vec![3; n]);
        let by_part = cover_keys(&pm.mesh, parts.clone(), false);
        assert_eq!(by_part, vec![3u64; n]);
        let by_plane = cover_keys(&pm.mesh, parts, true);
        assert_eq!(by_plane, cover_keys(&pm.mesh, None, false));
        let distinct: std::collections::BTreeSet<u64> = by_plane.iter().copied().collect();
        assert_eq!(distinct.len(), 6);
        // Each face is a 2 × 2 grid of two triangles a cell: 8 triangles a face.
        for face in by_plane.chunks(n / 6) {
            assert!(face.iter().all(|&k| k == face[0]));
        }
    }
}
