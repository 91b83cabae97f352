//! `bench query`: material queries per second of a scene model's learned field.
//!
//! Owns: that benchmark. Must not touch: the field.

use super::median;
use super::workloads::surface_sample;
use anyhow::Result;
use std::path::Path;

/// `bench query`: material queries per second of a scene model's learned field, as the path
/// tracer makes them (batches of `batch` points spread on the mesh): exact (hash-grid encoding
/// and MLP; the encoding alone reported beside) and through the voxel cache of `render`.
pub fn query(model_dir: &Path, as_json: bool, batch: usize, reps: usize) -> Result<()> {
    use fipt_bake::materials::{MaterialSource, VoxelMaterials};
    let device = burn::tensor::Device::flex();
    let sm = crate::scene_model::SceneModel::load(model_dir, &device)?;
    let learned =
        crate::learned::LearnedMaterials::new(sm.model.clone(), sm.mesh.num_triangles(), &[]);
    let lf = &sm.light_field;
    let t0 = std::time::Instant::now();
    let (voxels, evaluated) = VoxelMaterials::from_surface(
        lf.scene_box,
        lf.res,
        &sm.mesh,
        &learned,
        vec![false; sm.mesh.num_triangles()],
        2.0,
        0,
    );
    let build_s = t0.elapsed().as_secs_f64();
    // Points spread on the surface (another seed than the cache's).
    let (pts, tris) = surface_sample(&sm.mesh, batch, 7);
    let x_unit: Vec<[f32; 3]> = pts
        .iter()
        .map(|&p| sm.model.spec.scene_box.to_unit(p).to_array())
        .collect();
    let mut out = Vec::new();
    let time = |f: &mut dyn FnMut()| {
        median(
            (0..reps)
                .map(|_| {
                    let t = std::time::Instant::now();
                    f();
                    t.elapsed().as_secs_f64()
                })
                .collect(),
        )
    };
    let exact = time(&mut || learned.query(&pts, &tris, &mut out));
    let encode = time(&mut || {
        std::hint::black_box(sm.model.grid.encode(&x_unit));
    });
    let cached = time(&mut || voxels.query(&pts, &tris, &mut out));
    let mut probe = Vec::new();
    let missed = {
        // Forwarded points answer exactly; a cached answer differs from the exact one.
        let mut exact = Vec::new();
        learned.query(&pts, &tris, &mut exact);
        voxels.query(&pts, &tris, &mut probe);
        probe.iter().zip(&exact).filter(|(a, b)| a == b).count()
    };
    let j = serde_json::json!({
        "bench": "query",
        "model": model_dir.display().to_string(),
        "batch": batch,
        "threads": rayon::current_num_threads(),
        "exact_points_per_s": batch as f64 / exact,
        "encode_points_per_s": batch as f64 / encode,
        "encode_share": encode / exact,
        "cached_points_per_s": batch as f64 / cached,
        "cache_voxels": voxels.len(),
        "cache_miss_share": missed as f64 / batch as f64,
        "cache_points_evaluated": evaluated,
        "cache_build_s": build_s,
    });
    if as_json {
        println!("{}", serde_json::to_string_pretty(&j)?);
    } else {
        println!(
            "exact field: {:.2} M points/s (encoding {:.0} % of it); voxel cache: {:.1} M points/s ({:.1} % forwarded; {} voxels from {} points in {:.2} s)",
            batch as f64 / exact / 1e6,
            100.0 * encode / exact,
            batch as f64 / cached / 1e6,
            100.0 * missed as f64 / batch as f64,
            voxels.len(),
            evaluated,
            build_s
        );
    }
    Ok(())
}
