//! `fipt-train check`: the dataset doctor. Loads everything, casts every pixel-centre ray and
//! reports coverage, map presence, fused-segmentation agreement, emitter visibility and, where
//! the scene carries them, agreement with the renderer's own hit positions and triangle ids.
//!
//! Owns: the report. Must not touch: training.

use anyhow::Result;
use fipt_bake::{Accel, ViewHits, cast_view, segfuse};
use fipt_core::scene::{Dataset, LoadOptions, MapKind, Split};
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;
use std::path::Path;

/// Agreement below this is reported as a problem.
const MIN_AGREEMENT: f64 = 0.99;

/// Per-view agreement of fused labels with the given maps: (min, mean, per view).
fn label_agreement(
    ds: &Dataset,
    hits: &[Vec<ViewHits>],
    kind: MapKind,
) -> Option<(f64, f64, Vec<f64>)> {
    let splits = ds.splits();
    if !splits.iter().all(|s| s.has_map(kind)) {
        return None;
    }
    let labels: Vec<Vec<Vec<i32>>> = splits
        .iter()
        .map(|s| s.views.iter().map(|v| v.labels(kind).unwrap()).collect())
        .collect();
    let all_hits: Vec<ViewHits> = hits.iter().flatten().cloned().collect();
    let all_labels: Vec<Vec<i32>> = labels.iter().flatten().cloned().collect();
    let fused = segfuse::fuse_labels(ds.mesh.num_triangles(), &all_hits, &all_labels, None);
    let per_view: Vec<f64> = all_hits
        .iter()
        .zip(&all_labels)
        .map(|(h, l)| segfuse::agreement(&segfuse::render_labels(&fused, h), l))
        .collect();
    let min = per_view.iter().cloned().fold(f64::INFINITY, f64::min);
    let mean = per_view.iter().sum::<f64>() / per_view.len() as f64;
    Some((min, mean, per_view))
}

fn emitter_views(split: &Split) -> Option<Vec<usize>> {
    if !split.has_map(MapKind::Emit) {
        return None;
    }
    Some(
        split
            .views
            .iter()
            .filter(|v| {
                let e = v.map(MapKind::Emit).unwrap();
                e.data.iter().any(|&x| x > 0.0)
            })
            .map(|v| v.index)
            .collect(),
    )
}

/// Mean hit-position error (m) against `Position` and triangle-id agreement with `TriIndex`.
fn renderer_agreement(split: &Split, hits: &[ViewHits]) -> (Option<f64>, Option<f64>) {
    let pos = split.has_map(MapKind::Position).then(|| {
        let (mut s, mut n) = (0.0f64, 0usize);
        for (v, h) in split.views.iter().zip(hits) {
            let m = v.map(MapKind::Position).unwrap();
            for p in 0..h.num_pixels() {
                if h.tri[p] >= 0 {
                    let g = m.rgb(p);
                    s += (h.position[p] - glam::Vec3::from(g)).length() as f64;
                    n += 1;
                }
            }
        }
        s / n.max(1) as f64
    });
    let tri = split.has_map(MapKind::TriIndex).then(|| {
        let (mut eq, mut n) = (0usize, 0usize);
        for (v, h) in split.views.iter().zip(hits) {
            let l = v.labels(MapKind::TriIndex).unwrap();
            eq += h.tri.iter().zip(&l).filter(|(a, b)| a == b).count();
            n += l.len();
        }
        eq as f64 / n.max(1) as f64
    });
    (pos, tri)
}

/// Agreement of the tracer's first hits with the renderer's own maps, per split.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct RendererAgreement {
    /// Mean distance (m) between our hit positions and `Position/`.
    pub position_error_mean_m: Option<f64>,
    /// Share of pixels whose triangle id equals `TriIndex/`.
    pub tri_index_agreement: Option<f64>,
}

/// What `fipt-train check` reports (`--json` prints it as is).
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct CheckReport {
    pub scene: String,
    pub layout: String,
    pub triangles: usize,
    pub views: usize,
    pub train_views: usize,
    pub val_views: usize,
    pub width: usize,
    pub height: usize,
    pub hit_fraction: f64,
    /// Per split, per map folder: present or not.
    pub maps: BTreeMap<String, BTreeMap<String, bool>>,
    pub part_agreement_min: Option<f64>,
    pub part_agreement_mean: Option<f64>,
    pub semantic_agreement_min: Option<f64>,
    pub semantic_agreement_mean: Option<f64>,
    /// Per split: the views that show an emitter (None without `Emit/`).
    pub emitter_views: BTreeMap<String, Option<Vec<usize>>>,
    pub renderer_agreement: BTreeMap<String, RendererAgreement>,
    /// LDR photos (PNG, JPEG): per split, each view's share of pixels with a clipped channel
    /// (None: HDR photos).
    pub ldr_clipped: Option<BTreeMap<String, Vec<f64>>>,
    /// LDR photos: the camera response read from the train views' occluding contours
    /// (`ldr::edges`; None: HDR photos, or too few contour pixels).
    #[serde(default)]
    pub ldr_response: Option<crate::ldr::edges::EdgeFit>,
    pub problems: Vec<String>,
}

/// Runs every check.
pub fn check_scene(scene: &Path) -> Result<CheckReport> {
    let ds = Dataset::load(scene, &LoadOptions::all_maps())?;
    let accel = Accel::build(&ds.mesh);
    let splits = ds.splits();
    let hits: Vec<Vec<ViewHits>> = splits
        .iter()
        .map(|s| {
            s.views
                .iter()
                .map(|v| cast_view(&accel, &ds.mesh, &v.camera))
                .collect()
        })
        .collect();
    let mut problems: Vec<String> = Vec::new();
    let total: usize = hits.iter().flatten().map(|h| h.num_pixels()).sum();
    let hit: usize = hits.iter().flatten().map(|h| h.num_hits()).sum();
    let hit_fraction = hit as f64 / total.max(1) as f64;
    if hit_fraction < 1.0 {
        problems.push(format!(
            "{} of {total} pixel-centre rays miss the mesh (hit fraction {hit_fraction:.4}); missed pixels are not trained on",
            total - hit
        ));
    }
    let maps = splits
        .iter()
        .map(|s| {
            let present = MapKind::ALL
                .iter()
                .map(|k| (k.folder().to_string(), s.has_map(*k)))
                .collect();
            (s.name.clone(), present)
        })
        .collect();
    if !ds.train.has_map(MapKind::IndexMA) && !ds.train.has_map(MapKind::Segmentation) {
        problems.push(
            "no IndexMA/ or segmentation/ labels: the segmentation losses cannot be used".into(),
        );
    }
    let mut agree = |kind: MapKind, name: &str| {
        let a = label_agreement(&ds, &hits, kind);
        if let Some((min, _, ref per_view)) = a
            && min < MIN_AGREEMENT
        {
            let worst = per_view
                .iter()
                .enumerate()
                .min_by(|a, b| a.1.total_cmp(b.1))
                .map(|(i, _)| i)
                .unwrap_or(0);
            problems.push(format!(
                "fused {name} labels agree with the given maps on only {:.2}% of pixels in view {worst} (of train+val): labels disagree with the geometry",
                min * 100.0
            ));
        }
        a
    };
    let part = agree(MapKind::IndexMA, "IndexMA");
    let sem = agree(MapKind::Segmentation, "segmentation");
    let seen: BTreeMap<String, Option<Vec<usize>>> = splits
        .iter()
        .map(|s| (s.name.clone(), emitter_views(s)))
        .collect();
    if let Some(v) = emitter_views(&ds.train)
        && v.is_empty()
    {
        problems.push("no train view shows an emitter (Emit > 0 nowhere)".into());
    }
    let mut renderer = BTreeMap::new();
    for (s, h) in splits.iter().zip(&hits) {
        let (pos, tri) = renderer_agreement(s, h);
        if let Some(e) = pos
            && e > 1e-3
        {
            problems.push(format!(
                "{}: mean hit-position error {e:.2e} m against Position/ (cameras or mesh do not match)",
                s.name
            ));
        }
        renderer.insert(
            s.name.clone(),
            RendererAgreement {
                position_error_mean_m: pos,
                tri_index_agreement: tri,
            },
        );
    }
    let views: usize = splits.iter().map(|s| s.views.len()).sum();
    let ldr_clipped = ds.is_ldr().then(|| {
        splits
            .iter()
            .map(|s| {
                let shares = s
                    .views
                    .iter()
                    .map(|v| v.ldr.as_ref().map_or(0.0, |f| f.clipped_share()))
                    .collect();
                (s.name.clone(), shares)
            })
            .collect()
    });
    let ldr_response = ds
        .is_ldr()
        .then(|| crate::ldr::edges::estimate(&ds, &accel))
        .flatten();
    Ok(CheckReport {
        scene: scene.display().to_string(),
        layout: format!("{:?}", ds.layout),
        triangles: ds.mesh.num_triangles(),
        views,
        train_views: ds.train.views.len(),
        val_views: ds.val.as_ref().map_or(0, |v| v.views.len()),
        width: ds.train.width,
        height: ds.train.height,
        hit_fraction,
        maps,
        part_agreement_min: part.as_ref().map(|t| t.0),
        part_agreement_mean: part.as_ref().map(|t| t.1),
        semantic_agreement_min: sem.as_ref().map(|t| t.0),
        semantic_agreement_mean: sem.as_ref().map(|t| t.1),
        emitter_views: seen,
        renderer_agreement: renderer,
        ldr_clipped,
        ldr_response,
        problems,
    })
}

impl CheckReport {
    /// The human-readable report.
    pub fn print(&self) {
        let f = |v: Option<f64>| v.map_or("-".to_string(), |x| format!("{x:.4}"));
        println!("scene     {}", self.scene);
        println!("layout    {}", self.layout);
        println!(
            "views     {} ({} train, {} val) at {}x{}, {} triangles",
            self.views, self.train_views, self.val_views, self.width, self.height, self.triangles
        );
        println!("hits      {:.4} of pixel-centre rays", self.hit_fraction);
        println!(
            "IndexMA   agreement min {} mean {}",
            f(self.part_agreement_min),
            f(self.part_agreement_mean)
        );
        println!(
            "semantic  agreement min {} mean {}",
            f(self.semantic_agreement_min),
            f(self.semantic_agreement_mean)
        );
        for (split, v) in &self.emitter_views {
            match v {
                Some(v) => println!("emitters  {split}: seen in views {v:?}"),
                None => println!("emitters  {split}: no Emit/ maps"),
            }
        }
        match &self.ldr_clipped {
            None => println!("photos    HDR (EXR)"),
            Some(c) => {
                for (split, shares) in c {
                    let clipped: Vec<usize> =
                        (0..shares.len()).filter(|&k| shares[k] > 0.0).collect();
                    let mean = shares.iter().sum::<f64>() / shares.len().max(1) as f64;
                    println!(
                        "photos    {split}: LDR (8-bit), {:.2} % of pixels clipped on average; views with clipped regions: {clipped:?}",
                        100.0 * mean
                    );
                }
                match &self.ldr_response {
                    Some(r) => println!(
                        "response  from the contours: γ {:.3} on the sRGB curve, {:?} pixels (R, G, B)",
                        r.gamma[0], r.samples
                    ),
                    None => println!(
                        "response  too few contour pixels to read it: a run assumes the sRGB curve"
                    ),
                }
            }
        }
        for (split, r) in &self.renderer_agreement {
            println!(
                "renderer  {split}: position error {} m, TriIndex agreement {}",
                r.position_error_mean_m
                    .map_or("-".into(), |x| format!("{x:.2e}")),
                f(r.tri_index_agreement)
            );
        }
        for (split, m) in &self.maps {
            let have: Vec<&str> = m
                .iter()
                .filter(|(_, v)| **v)
                .map(|(k, _)| k.as_str())
                .collect();
            println!("maps      {split}: {}", have.join(" "));
        }
        if self.problems.is_empty() {
            println!("problems  none");
        }
        for p in &self.problems {
            println!("problem   {p}");
        }
    }
}

pub fn run(scene: &Path, as_json: bool) -> Result<()> {
    let r = check_scene(scene)?;
    if as_json {
        println!("{}", serde_json::to_string_pretty(&r)?);
    } else {
        r.print();
    }
    Ok(())
}
