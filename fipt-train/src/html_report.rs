//! The HTML report of a run: `OUT/report.html`, one page with its images in `OUT/report/`,
//! opened from disk without a server (no script). Built from what `run` left in OUT
//! (`metrics.json`, `maps/`, `render/`, `emitters.json`) and the scene's photos and ground
//! truth, so `fipt-train report` rebuilds it for any finished run; `run` writes it last.
//!
//! Sections: the metric table of every round against the best constant predictor, the val
//! re-renders against the trivial predictors, time and memory per stage; the worst, median and
//! best views (photo, re-render, and truth / estimate / error of k_d, a′, σ, m and emission);
//! the per-part table; the emitters found; the basin hops of every round; the loss curve of
//! every round (inline SVG); the contact sheet of the re-rendered and relit val views. Without
//! ground truth (real data) it shows the estimates alone.
//!
//! Owns: the page and its images. Must not touch: how any figure is computed.

use crate::output::write_png;
use crate::pipeline::evaluate::{self, PartRow};
use crate::pipeline::predict::{ViewMaps, rgb_of_scalar};
use crate::pipeline::report::RunReport;
use anyhow::{Context, Result};
use fipt_bake::emitters::Emitter;
use fipt_core::model::step::SegMode;
use fipt_core::scene::{Dataset, Image, LoadOptions, MapKind, Split};
use std::fmt::Write as _;
use std::path::{Path, PathBuf};

/// HTML-escapes text.
fn esc(s: &str) -> String {
    s.replace('&', "&amp;")
        .replace('<', "&lt;")
        .replace('>', "&gt;")
        .replace('"', "&quot;")
}

/// A figure cell: "-" when absent.
fn num(v: Option<f64>, digits: usize) -> String {
    match v {
        Some(x) if x.is_finite() => format!("{x:.digits$}"),
        Some(_) => "not finite".into(),
        None => "-".into(),
    }
}

/// A labelled image tile.
fn tile(src: &str, label: &str) -> String {
    format!(
        "<figure><img src=\"{}\" alt=\"{}\"><figcaption>{}</figcaption></figure>",
        esc(src),
        esc(label),
        esc(label)
    )
}

const STYLE: &str = "body{font-family:sans-serif;margin:2em;max-width:1200px;color:#222}\
table{border-collapse:collapse;margin:0.5em 0 1.5em}td,th{border:1px solid #bbb;padding:3px 8px;text-align:right}\
th{background:#eee}td:first-child,th:first-child{text-align:left}\
figure{display:inline-block;margin:3px;text-align:center}figure img{image-rendering:pixelated;width:240px}\
figcaption{font-size:12px}.sheet img{width:100%;max-width:1000px;image-rendering:pixelated}\
.row{white-space:nowrap}h2{border-bottom:1px solid #ccc}";

/// Writes `OUT/report.html` and its images; returns the page's path.
pub fn write(scene: &Path, out: &Path) -> Result<PathBuf> {
    let metrics_path = out.join("metrics.json");
    let text = std::fs::read_to_string(&metrics_path).with_context(|| {
        format!(
            "{}: cannot read (run `fipt-train run` first)",
            metrics_path.display()
        )
    })?;
    let run: RunReport = serde_json::from_str(&text)
        .with_context(|| format!("{}: not a run's metrics", metrics_path.display()))?;
    let mut maps = MapKind::FIPT.to_vec();
    maps.extend([MapKind::BaseColor, MapKind::Metallic, MapKind::Relight]);
    let ds = Dataset::load(scene, &LoadOptions { maps, val: true })?;
    // The images go into a staged folder that replaces `report/` whole.
    let h = crate::output::staged_dir(&out.join("report"), |img_dir| {
        let mut h = String::new();
        let _ = write!(
            h,
            "<!DOCTYPE html><html><head><meta charset=\"utf-8\"><title>fipt: {}</title><style>{STYLE}</style></head><body>",
            esc(&run.scene)
        );
        let _ = write!(
            h,
            "<h1>fipt run</h1><p>Scene <code>{}</code>, {} train views{}; {} training steps, {} hash-grid levels. Scene model: <code>{}</code>{}.</p>",
            esc(&run.scene),
            ds.train.views.len(),
            ds.val
                .as_ref()
                .map_or(String::new(), |v| format!(", {} val views", v.views.len())),
            run.grid.steps,
            run.grid.levels,
            esc(run.model_dir.as_deref().unwrap_or("-")),
            run.zoo_entry.as_deref().map_or(String::new(), |z| format!(
                ", zoo entry <code>{}</code>",
                esc(z)
            ))
        );
        metric_tables(&mut h, &run, &ds);
        if let Some(l) = &run.ldr {
            ldr_section(&mut h, l);
        }
        times(&mut h, &run);
        views(&mut h, &ds, out, img_dir)?;
        parts(&mut h, run.parts.as_deref());
        emitters(&mut h, out, &ds)?;
        hops(&mut h, &run, &ds);
        loss_curves(&mut h, &run);
        sheet(&mut h, out, img_dir)?;
        scene_viewer(&mut h, scene, out, img_dir)?;
        h.push_str("</body></html>\n");
        Ok(h)
    })?;
    let page = out.join("report.html");
    fipt_core::io::write_bytes_atomic(&page, h.as_bytes())?;
    Ok(page)
}

/// Texels of the viewer's textures (a smaller export than `export`'s default keeps the report
/// light).
const VIEWER_TEXELS: usize = 1024;

/// The recovered scene in 3D: `OUT/model` exported as `.glb` with the offline viewer into
/// `report/viewer/`, linked and shown in a frame (nothing where the run saved no model; the
/// error where it cannot be exported).
fn scene_viewer(h: &mut String, scene: &Path, out: &Path, img_dir: &Path) -> Result<()> {
    let model = out.join("model");
    if !model.join(crate::scene_model::MANIFEST).is_file() {
        return Ok(());
    }
    let job = crate::export::ExportJob {
        source: crate::export::Source::Model {
            name_or_dir: model.display().to_string(),
            zoo: out.join("zoo"),
        },
        scene: Some(scene.to_path_buf()),
        split: crate::export::CameraSplit::Val,
        formats: vec![crate::export::Format::Viewer],
        out: img_dir.join("viewer"),
        texels: VIEWER_TEXELS,
        backend: fipt_core::model::BackendKind::Flex,
        quiet: true,
    };
    // The report does not depend on the viewer: a model it cannot export is named instead.
    let r = match crate::export::export(&job) {
        Ok(r) => r,
        Err(e) => {
            eprintln!("warning: report: no 3D viewer: {e:#}");
            let _ = write!(
                h,
                "<h2>Recovered scene</h2><p>No 3D viewer: {}</p>",
                esc(&format!("{e:#}"))
            );
            return Ok(());
        }
    };
    let _ = write!(
        h,
        "<h2>Recovered scene</h2><p>The scene model as glTF 2.0 (<a href=\"report/viewer/scene.glb\">scene.glb</a>, {} materials, {}² textures; <code>fipt-train export</code> writes larger ones and Mitsuba 3 scenes). Drag to orbit, scroll to zoom; <a href=\"report/viewer/viewer.html\">open the viewer alone</a>.</p><iframe src=\"report/viewer/viewer.html\" style=\"width:100%;max-width:1000px;height:600px;border:1px solid #ccc\"></iframe>",
        r.materials.len(),
        r.texels
    );
    Ok(())
}

fn metric_tables(h: &mut String, run: &RunReport, ds: &Dataset) {
    h.push_str("<h2>Metrics</h2>");
    let constant = evaluate::constant_predictor(&ds.train.views);
    if run.metrics.kd_psnr.is_none() {
        h.push_str("<p>The scene has no ground-truth maps: no material scores.</p>");
    } else {
        h.push_str("<p>Train views, scored as the IRIS protocol does (reference §3). The best constant predictor (each map set to the mean of its ground truth) is the scale.</p><table><tr><th>metric</th>");
        for r in &run.rounds {
            let _ = write!(h, "<th>round {}</th>", r.round);
        }
        h.push_str("<th>best constant</th></tr>");
        type Get = fn(&crate::pipeline::report::RoundReport) -> Option<f64>;
        let rows: [(&str, Get, Option<f64>, usize); 5] = [
            (
                "k_d PSNR (dB)",
                |r| r.kd_psnr,
                constant.as_ref().and_then(|c| c.metrics.kd_psnr),
                2,
            ),
            (
                "a′ PSNR (dB)",
                |r| r.albedo_psnr,
                constant.as_ref().and_then(|c| c.metrics.albedo_psnr),
                2,
            ),
            (
                "σ PSNR (dB)",
                |r| r.roughness_psnr,
                constant.as_ref().and_then(|c| c.metrics.roughness_psnr),
                2,
            ),
            ("emission IoU", |r| r.emission_iou, None, 3),
            ("emission log-L2", |r| r.emission_log_l2, None, 6),
        ];
        for (name, get, c, d) in rows {
            let _ = write!(h, "<tr><td>{name}</td>");
            for r in &run.rounds {
                let _ = write!(h, "<td>{}</td>", num(get(r), d));
            }
            let _ = write!(h, "<td>{}</td></tr>", num(c, d));
        }
        h.push_str("</table>");
    }
    if let Some(r) = &run.renders {
        let (vt, rt) = ds.val.as_ref().map_or((None, None), |v| {
            crate::rerender::trivial_render_scores(&v.views)
        });
        let _ = write!(
            h,
            "<p>Val views re-rendered from the recovered scene ({} spp{}) and relit ({} spp), PSNR of clip(x,0,1)^(1/2.2) against the photos.</p><table><tr><th>re-render</th><th>fipt (dB)</th><th>trivial predictor (dB)</th></tr><tr><td>view synthesis</td><td>{}</td><td>{} (each photo's mean colour)</td></tr><tr><td>relighting</td><td>{}</td><td>{} (the photo under the old lights)</td></tr></table>",
            r.spp,
            if r.cache {
                ", L′ on rough secondary hits"
            } else {
                ""
            },
            r.relight_spp,
            num(run.view_psnr, 2),
            num(vt, 2),
            num(run.relight_psnr, 2),
            num(rt, 2)
        );
    }
}

fn times(h: &mut String, run: &RunReport) {
    h.push_str("<h2>Time and memory</h2><table><tr><th>stage</th><th>seconds</th></tr>");
    for (k, v) in run.time_s.rows() {
        let _ = write!(h, "<tr><td>{k}</td><td>{v:.1}</td></tr>");
    }
    let _ = write!(
        h,
        "<tr><td>peak memory (MB)</td><td>{}</td></tr></table>",
        num(run.peak_rss_mb, 0)
    );
}

/// |a − b| × 4, per value.
fn err(a: &[f32], b: &[f32]) -> Vec<f32> {
    a.iter().zip(b).map(|(x, y)| 4.0 * (x - y).abs()).collect()
}

fn views(h: &mut String, ds: &Dataset, out: &Path, img_dir: &Path) -> Result<()> {
    // The val split where its maps were predicted, else the train split.
    let (split, name): (&Split, &str) = match &ds.val {
        Some(v) if out.join("maps/val").is_dir() => (v, "val"),
        _ => (&ds.train, "train"),
    };
    let dir = out.join("maps").join(name);
    let maps: Vec<ViewMaps> = (0..split.views.len())
        .map(|k| ViewMaps::read(&dir, k))
        .collect::<Result<_>>()
        .with_context(|| format!("{}: predicted maps missing", dir.display()))?;
    let scores: Vec<Option<f64>> = split
        .views
        .iter()
        .zip(&maps)
        .map(|(v, m)| evaluate::score_view(v, m).kd_psnr)
        .collect();
    let mut order: Vec<usize> = (0..split.views.len()).collect();
    let has_gt = scores.iter().all(Option::is_some);
    if has_gt {
        order.sort_by(|&a, &b| {
            scores[a]
                .unwrap_or(0.0)
                .total_cmp(&scores[b].unwrap_or(0.0))
        });
    }
    let n = order.len();
    let picked: Vec<(&str, usize)> = if n == 0 {
        vec![]
    } else {
        let mut p = vec![
            ("worst", order[0]),
            ("median", order[n / 2]),
            ("best", order[n - 1]),
        ];
        p.dedup_by_key(|x| x.1);
        p
    };
    let _ = write!(
        h,
        "<h2>Views</h2><p>{} views {}: the photo, the re-render, and per map the ground truth, the estimate and 4×|error|.</p>",
        name,
        if has_gt {
            "with the worst, median and best k_d PSNR"
        } else {
            "(no ground truth: estimates only)"
        }
    );
    for (label, k) in picked {
        let v = &split.views[k];
        let m = &maps[k];
        let (w, hh) = (m.width, m.height);
        let png = |file: &str, rgb: &[f32]| -> Result<String> {
            write_png(&img_dir.join(file), w, hh, rgb, 1.0)?;
            Ok(format!("report/{file}"))
        };
        let _ = write!(
            h,
            "<h3>{label}: {name} view {k}{}</h3><div class=\"row\">",
            scores[k].map_or(String::new(), |s| format!(", k_d {s:.2} dB"))
        );
        h.push_str(&tile(
            &png(&format!("{name}{k}_photo.png"), &v.image.data)?,
            "photo",
        ));
        let rr = out.join(format!("render/{name}/Image/{k:03}_0001.exr"));
        if let Ok(img) = Image::read_exr(&rr) {
            h.push_str(&tile(
                &png(&format!("{name}{k}_render.png"), &img.data)?,
                "re-render",
            ));
        }
        h.push_str("</div>");
        let gt = |kind: MapKind, scalar: bool| -> Option<Vec<f32>> {
            v.map(kind).map(|i| {
                if scalar {
                    rgb_of_scalar(&i.first_channel().data)
                } else {
                    (0..i.num_pixels()).flat_map(|p| i.rgb(p)).collect()
                }
            })
        };
        let rows: [(&str, MapKind, bool, Vec<f32>); 5] = [
            ("k_d", MapKind::DiffCol, false, m.kd.clone()),
            ("a′", MapKind::Albedo, false, m.albedo.clone()),
            ("σ", MapKind::Roughness, true, rgb_of_scalar(&m.sigma)),
            ("m", MapKind::Metallic, true, rgb_of_scalar(&m.metallic)),
            ("emission", MapKind::Emit, false, m.emit.clone()),
        ];
        for (i, (q, kind, scalar, est)) in rows.into_iter().enumerate() {
            h.push_str("<div class=\"row\">");
            let truth = gt(kind, scalar);
            if let Some(t) = &truth {
                h.push_str(&tile(
                    &png(&format!("{name}{k}_{i}_true.png"), t)?,
                    &format!("{q} truth"),
                ));
            }
            h.push_str(&tile(
                &png(&format!("{name}{k}_{i}_est.png"), &est)?,
                &format!("{q} estimate"),
            ));
            if let Some(t) = &truth
                && t.len() == est.len()
            {
                // Emission is HDR: its error is relative, |e − t| / max(t, 1).
                let (e, what) = if kind == MapKind::Emit {
                    let rel = t
                        .iter()
                        .zip(&est)
                        .map(|(a, b)| (a - b).abs() / a.max(1.0))
                        .collect();
                    (rel, "relative error")
                } else {
                    (err(t, &est), "4×|error|")
                };
                h.push_str(&tile(
                    &png(&format!("{name}{k}_{i}_err.png"), &e)?,
                    &format!("{q} {what}"),
                ));
            }
            h.push_str("</div>");
        }
    }
    Ok(())
}

fn parts(h: &mut String, parts: Option<&[PartRow]>) {
    let Some(rows) = parts else {
        return;
    };
    h.push_str("<h2>Parts</h2><p>Mean over each part's train pixels: estimate / truth.</p><table><tr><th>part</th><th>pixels</th><th>a estimate</th><th>a truth</th><th>σ estimate</th><th>σ truth</th><th>m estimate</th><th>m truth</th></tr>");
    let rgb = |c: [f64; 3]| format!("{:.2}, {:.2}, {:.2}", c[0], c[1], c[2]);
    for r in rows {
        let _ = write!(
            h,
            "<tr><td>{}</td><td>{}</td><td>{}</td><td>{}</td><td>{:.2}</td><td>{:.2}</td><td>{:.2}</td><td>{:.2}</td></tr>",
            esc(&r.name),
            r.pixels,
            rgb(r.a_est),
            rgb(r.a_true),
            r.sigma_est,
            r.sigma_true,
            r.m_est,
            r.m_true
        );
    }
    h.push_str("</table>");
}

fn emitters(h: &mut String, out: &Path, ds: &Dataset) -> Result<()> {
    let path = out.join("emitters.json");
    #[derive(serde::Deserialize)]
    struct File {
        emitters: Vec<Emitter>,
    }
    let f: File = serde_json::from_str(
        &std::fs::read_to_string(&path)
            .with_context(|| format!("{}: cannot read", path.display()))?,
    )
    .with_context(|| format!("{}: malformed", path.display()))?;
    // Grouped by the part they lie on where the scene names parts, else by radiance.
    let part_of = |t: u32| {
        ds.meta.as_ref().and_then(|m| {
            m.parts
                .iter()
                .find(|p| (p.triangles[0]..p.triangles[1]).contains(&(t as usize)))
                .map(|p| (p.name.clone(), p.emission.as_ref().map(|e| e.radiance)))
        })
    };
    /// Emitters on one part (or of one radiance): count, area, area-weighted radiance sum.
    struct Group {
        name: String,
        truth: Option<[f32; 3]>,
        count: usize,
        area: f32,
        weighted: [f32; 3],
    }
    let mut groups: Vec<Group> = Vec::new();
    for e in &f.emitters {
        let (name, truth) = part_of(e.triangle).unwrap_or_else(|| {
            let r = e.radiance;
            (
                format!("radiance {:.2}, {:.2}, {:.2}", r[0], r[1], r[2]),
                None,
            )
        });
        let i = match groups.iter().position(|g| g.name == name) {
            Some(i) => i,
            None => {
                groups.push(Group {
                    name,
                    truth,
                    count: 0,
                    area: 0.0,
                    weighted: [0.0; 3],
                });
                groups.len() - 1
            }
        };
        let g = &mut groups[i];
        g.count += 1;
        g.area += e.area;
        for c in 0..3 {
            g.weighted[c] += e.radiance[c] * e.area;
        }
    }
    let _ = write!(
        h,
        "<h2>Emitters</h2><p>{} emitting triangles extracted.</p><table><tr><th>on part</th><th>triangles</th><th>area (m²)</th><th>mean radiance</th><th>true radiance</th></tr>",
        f.emitters.len()
    );
    for g in groups {
        let (name, truth, n, area) = (g.name, g.truth, g.count, g.area);
        let r = g.weighted.map(|x| x / area.max(1e-12));
        let _ = write!(
            h,
            "<tr><td>{}</td><td>{n}</td><td>{:.4}</td><td>{:.2}, {:.2}, {:.2}</td><td>{}</td></tr>",
            esc(&name),
            area,
            r[0],
            r[1],
            r[2],
            truth.map_or("-".into(), |t| format!(
                "{:.2}, {:.2}, {:.2}",
                t[0], t[1], t[2]
            ))
        );
    }
    h.push_str("</table>");
    Ok(())
}

/// The basin hops of every round (`train.hop`): which segments hopped, from and to which σ,
/// and whether the hopped model was kept.
fn hops(h: &mut String, run: &RunReport, ds: &Dataset) {
    let rows: Vec<String> = run
        .rounds
        .iter()
        .filter_map(|r| r.hop.as_ref().map(|hop| (r.round, hop)))
        .flat_map(|(round, hop)| {
            hop.candidates.iter().map(move |c| {
                // Part ids name their part; semantic labels stay numbers.
                let name = ds
                    .meta
                    .as_ref()
                    .filter(|_| run.seg_loss == SegMode::Part)
                    .and_then(|m| m.parts.iter().find(|p| p.id as i64 == i64::from(c.segment)))
                    .map_or_else(|| format!("segment {}", c.segment), |p| p.name.clone());
                let m = |v: f64| format!(", m {v:.2}");
                format!(
                    "<tr><td>{round}</td><td>{}</td><td>{}</td><td>{}</td><td>{:.2}{}</td><td>{:.2}{}</td><td>{:.2}{}</td><td>{:+.0} %</td><td>{}</td></tr>",
                    esc(&name),
                    c.pixels,
                    if c.alone { format!("{:?}, alone", c.source) } else { format!("{:?}", c.source) },
                    c.sigma,
                    m(c.metallic),
                    c.target,
                    c.target_metallic.map(m).unwrap_or_default(),
                    c.sigma_after,
                    m(c.metallic_after),
                    100.0 * (c.objective_after / c.objective - 1.0),
                    {
                        let kept = if c.source == crate::pipeline::hop::Hypothesis::Patch {
                            hop.patch_accepted.unwrap_or(false)
                        } else if c.alone {
                            hop.plain_accepted.unwrap_or(false)
                        } else {
                            hop.accepted
                        };
                        if kept { "kept" } else { "undone" }
                    }
                )
            })
        })
        .collect();
    if rows.is_empty() {
        return;
    }
    h.push_str("<h2>Basin hops</h2><p>After a fit, segments whose own objective is clearly lower far from the fitted material (at another σ, as a metal, at the last round's material, or at another σ with the colour solved per patch) are pulled there and released (<code>train.hop</code>); the hop is kept only if their objective fell. Patch candidates hop after the others, held at their targets, and are kept or undone on their own; with <code>train.hop.hold_metals</code>, candidates hopping as metals stay pulled through the release at that weight. With <code>train.hop.plain_metal</code>, a metal whose one colour scores within the gain of the fit hops again alone where the first hop was undone (“alone”), held at its target and measured at one colour.</p><table><tr><th>round</th><th>segment</th><th>pixels</th><th>hypothesis</th><th>fitted</th><th>target</th><th>after</th><th>objective</th><th></th></tr>");
    for r in rows {
        h.push_str(&r);
    }
    h.push_str("</table>");
}

fn loss_curves(h: &mut String, run: &RunReport) {
    let mut curves: Vec<(String, Vec<(u64, f32)>)> = run
        .rounds
        .iter()
        .filter(|r| !r.loss_curve.is_empty())
        .map(|r| (format!("round {}", r.round), r.loss_curve.clone()))
        .collect();
    if curves.is_empty() && !run.train_log.step_total.is_empty() {
        curves.push((
            "last fit".into(),
            crate::pipeline::report::binned(&run.train_log.step_total, 200),
        ));
    }
    let pts: Vec<(u64, f32)> = curves
        .iter()
        .flat_map(|c| c.1.iter().copied())
        .filter(|p| p.1.is_finite() && p.1 > 0.0)
        .collect();
    if pts.is_empty() {
        return;
    }
    let (w, hh, pad) = (720.0f64, 280.0f64, 50.0f64);
    let xmax = pts.iter().map(|p| p.0).max().unwrap_or(1).max(1) as f64;
    let ly: Vec<f64> = pts.iter().map(|p| (p.1 as f64).log10()).collect();
    let (ymin, ymax) = (
        ly.iter().cloned().fold(f64::INFINITY, f64::min).floor(),
        ly.iter().cloned().fold(f64::NEG_INFINITY, f64::max).ceil(),
    );
    let yspan = (ymax - ymin).max(1.0);
    let sx = |x: u64| pad + (w - 2.0 * pad) * x as f64 / xmax;
    let sy = |y: f32| hh - pad - (hh - 2.0 * pad) * ((y as f64).log10() - ymin) / yspan;
    let colours = ["#1f77b4", "#d62728", "#2ca02c", "#9467bd", "#ff7f0e"];
    let _ = write!(
        h,
        "<h2>Loss</h2><p>The fit's total loss per step (mean over bins), every round; log scale.</p><svg width=\"{w}\" height=\"{hh}\" xmlns=\"http://www.w3.org/2000/svg\"><rect x=\"{pad}\" y=\"{pad}\" width=\"{}\" height=\"{}\" fill=\"none\" stroke=\"#999\"/>",
        w - 2.0 * pad,
        hh - 2.0 * pad
    );
    let mut e = ymin;
    while e <= ymax {
        let y = hh - pad - (hh - 2.0 * pad) * (e - ymin) / yspan;
        let _ = write!(
            h,
            "<text x=\"{:.0}\" y=\"{y:.0}\" font-size=\"11\" text-anchor=\"end\">1e{e:.0}</text>",
            pad - 4.0
        );
        e += 1.0;
    }
    let _ = write!(
        h,
        "<text x=\"{:.0}\" y=\"{:.0}\" font-size=\"11\" text-anchor=\"end\">step {xmax:.0}</text>",
        w - pad,
        hh - pad + 16.0
    );
    for (i, (label, c)) in curves.iter().enumerate() {
        let colour = colours[i % colours.len()];
        let line: Vec<String> = c
            .iter()
            .filter(|p| p.1.is_finite() && p.1 > 0.0)
            .map(|p| format!("{:.1},{:.1}", sx(p.0), sy(p.1)))
            .collect();
        let _ = write!(
            h,
            "<polyline fill=\"none\" stroke=\"{colour}\" stroke-width=\"1.5\" points=\"{}\"/><text x=\"{:.0}\" y=\"{:.0}\" font-size=\"12\" fill=\"{colour}\">{}</text>",
            line.join(" "),
            w - pad - 80.0,
            pad + 16.0 * (i as f64 + 1.0),
            esc(label)
        );
    }
    h.push_str("</svg>");
}

fn sheet(h: &mut String, out: &Path, img_dir: &Path) -> Result<()> {
    let src = out.join("render/val/sheet.png");
    if !src.is_file() {
        return Ok(());
    }
    let dst = img_dir.join("val_sheet.png");
    std::fs::copy(&src, &dst).with_context(|| format!("{}: cannot copy", src.display()))?;
    h.push_str("<h2>Re-renders</h2><p>Per val view: photo | view synthesis | relit photo | relit re-render.</p><div class=\"sheet\"><img src=\"report/val_sheet.png\" alt=\"val re-renders\"></div>");
    Ok(())
}

/// LDR photos: the response (a plot of f per channel), the exposures, the clipped lamps' solve
/// and view synthesis in LDR.
fn ldr_section(h: &mut String, l: &crate::ldr::report::LdrReport) {
    let cal = &l.calibration;
    let e = &cal.train_exposures;
    let (lo, hi) = e
        .iter()
        .fold((f64::INFINITY, 0.0f64), |(a, b), &x| (a.min(x), b.max(x)));
    let clipped = cal.clipped_share.iter().sum::<f64>() / cal.clipped_share.len().max(1) as f64;
    let _ = write!(
        h,
        "<h2>LDR photos</h2><p>8-bit photos, {:.2} % of the train pixels clipped on average. Exposures {} ({} train frames, {:.3}–{:.3}, the median frame's is 1: radiance is in units of its clip level). View synthesis in LDR (the re-render through the response at the view's exposure, against the photo): <b>{} dB</b>. Relighting after one global scale ({}): {} dB.</p>",
        100.0 * clipped,
        match cal.exposure_source {
            crate::ldr::calibrate::ExposureSource::Given => "given",
            crate::ldr::calibrate::ExposureSource::Estimated => "estimated",
            crate::ldr::calibrate::ExposureSource::Unit => "taken as 1 (not given, not estimated)",
        },
        e.len(),
        lo,
        hi,
        num(l.view_psnr_ldr, 2),
        num(l.relight_scale, 3),
        num(l.relight_psnr_aligned, 2),
    );
    // The response f per channel: code value against linear value.
    let (w, hh, pad) = (320.0f64, 240.0f64, 36.0f64);
    let _ = write!(
        h,
        "<svg width=\"{w}\" height=\"{hh}\" xmlns=\"http://www.w3.org/2000/svg\"><rect x=\"{pad}\" y=\"{pad}\" width=\"{}\" height=\"{}\" fill=\"none\" stroke=\"#999\"/><text x=\"{}\" y=\"{}\" font-size=\"11\" text-anchor=\"middle\">linear value e·L (0–1)</text><text x=\"10\" y=\"{}\" font-size=\"11\">code</text>",
        w - 2.0 * pad,
        hh - 2.0 * pad,
        w / 2.0,
        hh - 8.0,
        pad - 6.0
    );
    for (c, colour) in ["#d62728", "#2ca02c", "#1f77b4"].iter().enumerate() {
        let pts: Vec<String> = (0..=100)
            .map(|i| {
                let x = i as f64 / 100.0;
                let v = cal.response.forward(c, x);
                format!(
                    "{:.1},{:.1}",
                    pad + (w - 2.0 * pad) * x,
                    hh - pad - (hh - 2.0 * pad) * v
                )
            })
            .collect();
        let _ = write!(
            h,
            "<polyline fill=\"none\" stroke=\"{colour}\" stroke-width=\"1.2\" points=\"{}\"/>",
            pts.join(" ")
        );
    }
    let how = match l.light_solve.as_ref().and_then(|s| s.response.as_ref()) {
        Some(r) => format!(
            "estimated: the sRGB curve after the exponents γ = {:.3}, {:.3}, {:.3}",
            r.gamma[0], r.gamma[1], r.gamma[2]
        ),
        None => "the sRGB curve, not estimated".to_string(),
    };
    let truth = l.response_rms_to_truth.map_or(String::new(), |d| {
        format!("; {d:.4} RMS from the twin's true curve")
    });
    let _ = write!(
        h,
        "</svg><p>The camera response f (R, G, B) the photos were linearised with ({how}{truth}).</p>"
    );
    for (title, solve) in [
        ("before the bake", &l.light_solve),
        ("after round 0 (kept)", &l.light_resolve),
    ] {
        let Some(solve) = solve else { continue };
        let raised = solve
            .surface_pixels_filled
            .map_or(String::new(), |n| {
                format!(" (its L′ with the clipped channels of {n} surface pixels raised to round 0's render)")
            });
        let _ = write!(
            h,
            "<p>Clipped lamps, solved {title} from {} pixels of {} parts{raised}:</p><table><tr><th>triangles</th><th>pixels</th><th>clipped</th><th>extracted radiance</th><th>solved radiance</th></tr>",
            solve.pixels, solve.parts
        );
        for lamp in &solve.lamps {
            let _ = write!(
                h,
                "<tr><td>{}</td><td>{}</td><td>{:.0} %</td><td>{:.3?}</td><td>{}</td></tr>",
                lamp.triangles.len(),
                lamp.pixels,
                100.0 * lamp.clipped_share,
                lamp.extracted,
                if lamp.solved_clipped {
                    format!("{:.3?}", lamp.solved)
                } else {
                    "(not clipped: measured)".into()
                }
            );
        }
        h.push_str("</table>");
    }
}
