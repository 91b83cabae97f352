//! Agreement with the Mitsuba 3 reference scene `scenes/fipt-room` (a copy of the Mitsuba reference): the loaders, the
//! camera convention and the ray caster must reproduce the renderer's own hits and labels.

use fipt_bake::{Accel, cast_view};
use fipt_core::scene::{Dataset, LoadOptions, MapKind};
use std::path::PathBuf;

fn scene_dir() -> PathBuf {
    let p = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../scenes/fipt-room");
    assert!(
        p.join("scene.obj").exists(),
        "reference scene missing at {} (the repository carries it under scenes/)",
        p.display()
    );
    p
}

/// `fipt-train check` on fipt-room: full coverage, fused labels agree, all emitters seen.
#[test]
fn check_reports_clean_scene() {
    let r = fipt_train::check::check_scene(&scene_dir()).unwrap();
    assert_eq!(r.views, 56, "{r:?}");
    assert_eq!(r.width, 160);
    assert_eq!(r.height, 120);
    assert_eq!(r.hit_fraction, 1.0, "{r:?}");
    assert!(r.part_agreement_min.unwrap() >= 0.99, "{r:?}");
    assert!(r.semantic_agreement_min.unwrap() >= 0.99, "{r:?}");
    assert!(r.problems.is_empty(), "{r:?}");
    // The three emitters are each seen (in some train view) according to Emit.
    let ds = Dataset::load(&scene_dir(), &LoadOptions::default()).unwrap();
    let meta = ds.meta.as_ref().unwrap();
    let accel = Accel::build(&ds.mesh);
    let tri_part = meta.triangle_part(ds.mesh.num_triangles());
    for part in meta.parts.iter().filter(|p| p.emission.is_some()) {
        let seen = ds.train.views.iter().any(|v| {
            let h = cast_view(&accel, &ds.mesh, &v.camera);
            let e = v.map(MapKind::Emit).unwrap();
            (0..h.num_pixels()).any(|p| {
                h.tri[p] >= 0 && tri_part[h.tri[p] as usize] == part.id && e.rgb(p)[0] > 0.0
            })
        });
        assert!(seen, "emitter {} never seen emitting", part.name);
    }
    let ev = r.emitter_views["train"].as_ref().unwrap();
    assert!(ev.len() >= 7, "{r:?}");
}

/// Ray-cast hit positions match `train/Position` and triangle ids match `train/TriIndex`.
#[test]
fn hits_match_mitsuba_position_and_triangle_index() {
    let opts = LoadOptions {
        maps: vec![MapKind::Position, MapKind::TriIndex],
        val: true,
    };
    let ds = Dataset::load(&scene_dir(), &opts).unwrap();
    let accel = Accel::build(&ds.mesh);
    for split in ds.splits() {
        let (mut err, mut n, mut same) = (0.0f64, 0usize, 0usize);
        for v in &split.views {
            let h = cast_view(&accel, &ds.mesh, &v.camera);
            let pos = v.map(MapKind::Position).unwrap();
            let tri = v.labels(MapKind::TriIndex).unwrap();
            for (p, (&t, &want)) in h.tri.iter().zip(&tri).enumerate() {
                assert!(t >= 0, "{} view {} pixel {p} missed", split.name, v.index);
                err += (h.position[p] - glam::Vec3::from(pos.rgb(p))).length() as f64;
                n += 1;
                same += (t == want) as usize;
            }
        }
        let mean = err / n as f64;
        let frac = same as f64 / n as f64;
        eprintln!(
            "{}: mean position error {mean:.3e} m, triangle ids equal {frac:.5}",
            split.name
        );
        assert!(mean < 1e-3, "{}: mean position error {mean}", split.name);
        assert!(frac >= 0.99, "{}: triangle id agreement {frac}", split.name);
    }
}
