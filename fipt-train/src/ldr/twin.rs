//! `fipt-train ldr`: the LDR twin of an HDR scene, as a phone would have taken its photos.
//! Every photo becomes I = round(255·f(clip(e_i·L, 0, 1))) (IRIS's image formation, with
//! rounding) in 8-bit PNG or JPEG; everything else of the scene folder (mesh, cameras, ground
//! truth maps, relighting set) is linked or copied unchanged, in any of the three layouts.
//! `ldr.json` records the truth: the response, every exposure, the clipped shares.
//!
//! Owns: the twin's image formation and layout. Must not touch: how fipt reads or fits LDR
//! photos.

use anyhow::{Context, Result, bail};
use fipt_core::scene::dataset::Layout;
use fipt_core::scene::ldr::Response;
use fipt_core::scene::{Dataset, LoadOptions, MapKind, Split};
use image::ImageEncoder;
use serde::{Deserialize, Serialize};
use serde_json::Value;
use std::path::{Path, PathBuf};

/// A response curve by name: `srgb`, or `gamma:G` / `gamma:R,G,B` (f(x) = x^(1/γ)).
#[derive(Clone, Debug, PartialEq)]
pub enum CurveSpec {
    Srgb,
    Gamma([f64; 3]),
}

impl std::str::FromStr for CurveSpec {
    type Err = String;
    fn from_str(s: &str) -> std::result::Result<Self, String> {
        if s == "srgb" {
            return Ok(Self::Srgb);
        }
        let bad = || format!("'{s}': expected srgb, gamma:G or gamma:R,G,B (each G in [1, 4])");
        let g = s.strip_prefix("gamma:").ok_or_else(bad)?;
        let v: Vec<f64> = g
            .split(',')
            .map(|t| t.trim().parse::<f64>())
            .collect::<std::result::Result<_, _>>()
            .map_err(|_| bad())?;
        let v = match v.as_slice() {
            [a] => [*a; 3],
            [a, b, c] => [*a, *b, *c],
            _ => return Err(bad()),
        };
        if v.iter().any(|g| !(1.0..=4.0).contains(g)) {
            return Err(bad());
        }
        Ok(Self::Gamma(v))
    }
}

impl CurveSpec {
    /// The exact curve f_c(x) (the twin's photos are made with it; `response` is its table).
    pub fn forward(&self, c: usize, x: f64) -> f64 {
        let x = x.clamp(0.0, 1.0);
        match self {
            Self::Srgb => fipt_core::scene::ldr::linear_to_srgb(x),
            Self::Gamma(g) => x.powf(1.0 / g[c]),
        }
    }

    pub fn response(&self) -> Response {
        match self {
            Self::Srgb => Response::srgb(),
            Self::Gamma(g) => Response::gamma(*g),
        }
    }
    fn name(&self) -> String {
        match self {
            Self::Srgb => "srgb".into(),
            Self::Gamma(g) => format!("gamma:{},{},{}", g[0], g[1], g[2]),
        }
    }
}

/// The twin's photo format.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, clap::ValueEnum)]
#[serde(rename_all = "lowercase")]
pub enum LdrFormat {
    Png,
    Jpeg,
}

/// What `ldr` makes.
#[derive(Clone, Debug)]
pub struct TwinJob {
    pub scene: PathBuf,
    pub out: PathBuf,
    pub response: CurveSpec,
    /// The base exposure; `None`: chosen so that at least `clip_share` of the train pixels and,
    /// in every view at its own exposure, every pixel of a true emitter (where `Emit` maps
    /// exist) are clipped.
    pub exposure: Option<f64>,
    pub clip_share: f64,
    /// Per-view exposures 2^u·e, u uniform in [−stops, stops].
    pub stops: f64,
    /// Write each frame's relative exposure 2^u as `exposure` in the cameras file.
    pub give_exposure: bool,
    pub format: LdrFormat,
    pub quality: u8,
    pub seed: u64,
}

/// One split's truth.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct SplitTruth {
    pub name: String,
    /// e_i of every frame (absolute: the factor applied to the HDR photo).
    pub exposures: Vec<f64>,
    /// The share of pixels with a clipped channel, per frame.
    pub clipped_share: Vec<f64>,
    /// Per frame with a true emitter in view: the share of its emitter pixels clipped.
    pub emitter_clipped: Vec<Option<f64>>,
}

/// `ldr.json`: how the twin was made.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct TwinTruth {
    pub source: PathBuf,
    pub response_name: String,
    pub response: Response,
    /// The base exposure e (the median frame's exposure when `stops` is 0).
    pub exposure: f64,
    pub stops: f64,
    pub exposure_given: bool,
    pub format: LdrFormat,
    pub quality: u8,
    pub splits: Vec<SplitTruth>,
}

impl TwinTruth {
    pub fn load(path: &Path) -> Result<Self> {
        let text = std::fs::read_to_string(path)
            .with_context(|| format!("{}: cannot read", path.display()))?;
        serde_json::from_str(&text).with_context(|| format!("{}: malformed", path.display()))
    }
}

/// The base exposure e that clips `share` of the train pixels (their brightest channel) and,
/// in every view (at its exposure e·2^u, `stops[split][view]`), every pixel of a true emitter.
fn auto_exposure(splits: &[&Split], stops: &[Vec<f64>], share: f64) -> f64 {
    let mut peak: Vec<f32> = Vec::new();
    let mut need = 0.0f64;
    for (s, (split, us)) in splits.iter().zip(stops).enumerate() {
        for (v, u) in split.views.iter().zip(us) {
            let e = v.map(MapKind::Emit);
            let mut emit_min = f32::INFINITY;
            for p in 0..v.image.num_pixels() {
                let m = v.image.rgb(p).into_iter().fold(0.0f32, f32::max);
                if s == 0 {
                    peak.push(m);
                }
                if let Some(e) = e
                    && e.rgb(p).iter().any(|&x| x > 0.0)
                {
                    emit_min = emit_min.min(m);
                }
            }
            if emit_min.is_finite() {
                need = need.max(1.0 / (emit_min.max(1e-6) as f64 * 2f64.powf(*u)));
            }
        }
    }
    let k = ((1.0 - share) * (peak.len().saturating_sub(1)) as f64) as usize;
    let (_, q, _) = peak.select_nth_unstable_by(k, f32::total_cmp);
    need.max(1.0 / q.max(1e-6) as f64)
}

/// Encodes one HDR image as 8-bit codes.
fn encode(image: &fipt_core::scene::Image, curve: &CurveSpec, e: f64) -> Vec<u8> {
    image
        .data
        .chunks_exact(3)
        .flat_map(|px| {
            [0, 1, 2].map(|c| {
                let v = curve.forward(c, e * px[c].max(0.0) as f64);
                (255.0 * v).round().clamp(0.0, 255.0) as u8
            })
        })
        .collect()
}

fn write_photo(path: &Path, w: usize, h: usize, codes: &[u8], job: &TwinJob) -> Result<()> {
    let mut bytes = Vec::new();
    match job.format {
        LdrFormat::Png => image::codecs::png::PngEncoder::new(&mut bytes).write_image(
            codes,
            w as u32,
            h as u32,
            image::ExtendedColorType::Rgb8,
        )?,
        LdrFormat::Jpeg => {
            image::codecs::jpeg::JpegEncoder::new_with_quality(&mut bytes, job.quality)
                .write_image(codes, w as u32, h as u32, image::ExtendedColorType::Rgb8)?
        }
    }
    std::fs::write(path, bytes).with_context(|| format!("{}: cannot write", path.display()))
}

/// Folders deeper than this are taken for a loop of links.
const MAX_DEPTH: usize = 32;

/// Hard-links (or copies) the tree `from` into `to` at `depth`, skipping the files `skip` says.
fn link_tree(from: &Path, to: &Path, skip: &dyn Fn(&Path) -> bool, depth: usize) -> Result<()> {
    if depth > MAX_DEPTH {
        bail!(
            "{}: folders nested more than {MAX_DEPTH} deep (a loop of links?)",
            from.display()
        );
    }
    std::fs::create_dir_all(to).with_context(|| format!("{}: cannot create", to.display()))?;
    for e in std::fs::read_dir(from).with_context(|| format!("{}: cannot list", from.display()))? {
        let e = e?;
        let src = e.path();
        let dst = to.join(e.file_name());
        if skip(&src) {
            continue;
        }
        // A linked folder is copied as a folder: the twin must never write through a link
        // into the source.
        if std::fs::metadata(&src)
            .with_context(|| format!("{}: cannot read", src.display()))?
            .is_dir()
        {
            link_tree(&src, &dst, skip, depth + 1)?;
        } else if std::fs::hard_link(&src, &dst).is_err() {
            std::fs::copy(&src, &dst).with_context(|| format!("{}: cannot copy", src.display()))?;
        }
    }
    Ok(())
}

/// Per split, per view: the HDR photo's path and the LDR photo's, relative to the scene. The
/// FIPT layouts name frames `Image/{k:03}_0001.exr`; nerfstudio's frames name theirs in
/// `file_path` (with or without the extension), where the twin's photo keeps the name with
/// `ext`.
fn photo_paths(ds: &Dataset, scene: &Path, ext: &str) -> Result<Vec<Vec<(PathBuf, PathBuf)>>> {
    let fipt = |split: &Split, dir: PathBuf| {
        split
            .views
            .iter()
            .map(|v| {
                let name = format!("{:03}_0001", v.index);
                (
                    dir.join(format!("{name}.exr")),
                    dir.join(format!("{name}.{ext}")),
                )
            })
            .collect()
    };
    Ok(match ds.layout {
        Layout::FiptSynthetic => ds
            .splits()
            .into_iter()
            .map(|s| fipt(s, PathBuf::from(&s.name).join("Image")))
            .collect(),
        Layout::FiptReal => vec![fipt(&ds.train, PathBuf::from("Image"))],
        Layout::Nerfstudio => {
            let tpath = scene.join("transforms.json");
            let json = fipt_core::scene::dataset::parse_transforms(&tpath)?;
            let frames = fipt_core::scene::dataset::frames_of(&json, &tpath)?;
            let paths = ds
                .train
                .views
                .iter()
                .map(|v| {
                    let fp = frames[v.index]["file_path"].as_str().with_context(|| {
                        format!("{}: frame {}: no file_path", tpath.display(), v.index)
                    })?;
                    let fp = PathBuf::from(fp);
                    if fp.is_absolute()
                        || fp
                            .components()
                            .any(|c| matches!(c, std::path::Component::ParentDir))
                    {
                        bail!(
                            "{}: frame {}: file_path {} leaves the scene folder; the twin keeps its photos inside it",
                            tpath.display(),
                            v.index,
                            fp.display()
                        );
                    }
                    Ok((fp.with_extension("exr"), fp.with_extension(ext)))
                })
                .collect::<Result<Vec<_>>>()?;
            vec![paths]
        }
    })
}

/// Makes the twin in `job.out` (staged, then moved into place).
pub fn make_twin(job: &TwinJob) -> Result<TwinTruth> {
    let ds = Dataset::load(
        &job.scene,
        &LoadOptions {
            maps: vec![MapKind::Emit],
            val: true,
        },
    )?;
    if ds.is_ldr() {
        bail!("{}: the photos are already LDR", job.scene.display());
    }
    if !(0.0..=3.0).contains(&job.stops) {
        bail!("--stops {}: expected 0 to 3", job.stops);
    }
    if job.give_exposure && ds.layout == Layout::FiptReal {
        bail!("--give-exposure needs a transforms.json (the FIPT synthetic or nerfstudio layout)");
    }
    let response = job.response.response();
    let ext = match job.format {
        LdrFormat::Png => "png",
        LdrFormat::Jpeg => "jpg",
    };
    let photos = photo_paths(&ds, &job.scene, ext)?;
    let photo_dirs: Vec<(&Split, &Vec<(PathBuf, PathBuf)>)> =
        ds.splits().into_iter().zip(&photos).collect();
    // Each view's stops u, drawn before the base exposure that depends on them.
    let mut rng = fipt_core::rng::Rng::new(job.seed, 0x1d2_7a1a);
    let stops: Vec<Vec<f64>> = photo_dirs
        .iter()
        .map(|(split, _)| {
            (0..split.views.len())
                .map(|_| (2.0 * rng.next_f32() as f64 - 1.0) * job.stops)
                .collect()
        })
        .collect();
    let splits: Vec<&Split> = photo_dirs.iter().map(|(s, _)| *s).collect();
    let base = match job.exposure {
        Some(e) => e,
        None => auto_exposure(&splits, &stops, job.clip_share),
    };
    // The HDR photos stay behind, their extension in any case.
    let key = |p: &Path| p.with_extension("").to_string_lossy().into_owned();
    let sources: std::collections::HashSet<String> = photos
        .iter()
        .flatten()
        .map(|(src, _)| key(&job.scene.join(src)))
        .collect();
    let skip = |p: &Path| {
        p.extension().is_some_and(|e| e.eq_ignore_ascii_case("exr")) && sources.contains(&key(p))
    };
    let truth = crate::output::staged_dir(&job.out, |tmp| {
        link_tree(&job.scene, tmp, &skip, 0)?;
        let mut splits = Vec::new();
        for ((split, paths), us) in photo_dirs.iter().zip(&stops) {
            let mut exposures = Vec::new();
            let mut clipped_share = Vec::new();
            let mut emitter_clipped = Vec::new();
            for ((v, u), (_, dst)) in split.views.iter().zip(us).zip(paths.iter()) {
                let e = base * 2f64.powf(*u);
                let codes = encode(&v.image, &job.response, e);
                let path = tmp.join(dst);
                if let Some(d) = path.parent() {
                    std::fs::create_dir_all(d)
                        .with_context(|| format!("{}: cannot create", d.display()))?;
                }
                write_photo(&path, split.width, split.height, &codes, job)?;
                let clipped = |p: usize| codes[3 * p..3 * p + 3].contains(&255);
                let n = v.image.num_pixels();
                clipped_share.push((0..n).filter(|&p| clipped(p)).count() as f64 / n as f64);
                emitter_clipped.push(v.map(MapKind::Emit).and_then(|m| {
                    let em: Vec<usize> = (0..n)
                        .filter(|&p| m.rgb(p).iter().any(|&x| x > 0.0))
                        .collect();
                    (!em.is_empty()).then(|| {
                        em.iter().filter(|&&p| clipped(p)).count() as f64 / em.len() as f64
                    })
                }));
                exposures.push(e);
            }
            // transforms.json: the photos' new names (nerfstudio) and the exposures (asked).
            let nerfstudio = ds.layout == Layout::Nerfstudio;
            if job.give_exposure || nerfstudio {
                let cams = if nerfstudio {
                    tmp.join("transforms.json")
                } else {
                    tmp.join(&split.name).join("transforms.json")
                };
                let text = std::fs::read_to_string(&cams)?;
                let mut json: Value = serde_json::from_str(&text)?;
                let frames = json["frames"].as_array_mut().context("frames")?;
                for ((f, e), (_, dst)) in frames.iter_mut().zip(&exposures).zip(paths.iter()) {
                    if job.give_exposure {
                        f["exposure"] = serde_json::json!(e / base);
                    }
                    if nerfstudio {
                        f["file_path"] = serde_json::json!(dst.to_string_lossy());
                        if !job.give_exposure
                            && let Some(o) = f.as_object_mut()
                        {
                            // A source's own exposure would read as the twin's.
                            o.remove("exposure");
                        }
                    }
                }
                // The linked file is replaced, never written through (the source keeps its own).
                std::fs::remove_file(&cams)?;
                std::fs::write(&cams, serde_json::to_string_pretty(&json)?)?;
            }
            splits.push(SplitTruth {
                name: split.name.clone(),
                exposures,
                clipped_share,
                emitter_clipped,
            });
        }
        let truth = TwinTruth {
            source: job.scene.clone(),
            response_name: job.response.name(),
            response: response.clone(),
            exposure: base,
            stops: job.stops,
            exposure_given: job.give_exposure,
            format: job.format,
            quality: job.quality,
            splits,
        };
        crate::output::write_json(&tmp.join("ldr.json"), &truth)?;
        Ok(truth)
    })?;
    Ok(truth)
}
