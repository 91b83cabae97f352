//! Scene folders: the FIPT synthetic layout, the FIPT real layout and nerfstudio
//! `transforms.json`, loaded into one `Dataset` of plain arrays.
//!
//! Owns: folder layouts, file naming, cross-file validation (sizes, counts). Must not touch: ray
//! tracing, training.

use super::ldr::{LdrFrame, is_ldr_ext, read_ldr};
use super::{Camera, Image, Intrinsics, Mesh, Response, meta::SceneMeta};
use crate::io::{FileError, Result, read_text};
use glam::DVec3;
use rayon::prelude::*;
use serde_json::Value;
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

/// The per-pixel maps a view can carry besides its HDR image.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub enum MapKind {
    DiffCol,
    Roughness,
    Emit,
    IndexMA,
    Segmentation,
    Albedo,
    BaseColor,
    Metallic,
    Normal,
    Position,
    Depth,
    TriIndex,
    Relight,
}

impl MapKind {
    pub const ALL: [MapKind; 13] = [
        MapKind::DiffCol,
        MapKind::Roughness,
        MapKind::Emit,
        MapKind::IndexMA,
        MapKind::Segmentation,
        MapKind::Albedo,
        MapKind::BaseColor,
        MapKind::Metallic,
        MapKind::Normal,
        MapKind::Position,
        MapKind::Depth,
        MapKind::TriIndex,
        MapKind::Relight,
    ];
    /// The maps FIPT itself reads.
    pub const FIPT: [MapKind; 6] = [
        MapKind::DiffCol,
        MapKind::Roughness,
        MapKind::Emit,
        MapKind::IndexMA,
        MapKind::Segmentation,
        MapKind::Albedo,
    ];

    pub fn folder(self) -> &'static str {
        match self {
            MapKind::DiffCol => "DiffCol",
            MapKind::Roughness => "Roughness",
            MapKind::Emit => "Emit",
            MapKind::IndexMA => "IndexMA",
            MapKind::Segmentation => "segmentation",
            MapKind::Albedo => "albedo",
            MapKind::BaseColor => "BaseColor",
            MapKind::Metallic => "Metallic",
            MapKind::Normal => "Normal",
            MapKind::Position => "Position",
            MapKind::Depth => "Depth",
            MapKind::TriIndex => "TriIndex",
            MapKind::Relight => "Relight",
        }
    }

    /// File name of frame `k` (`{k:03d}_0001.exr`, or `{k:03d}.exr` for segmentation/albedo).
    pub fn file_name(self, k: usize) -> String {
        match self {
            MapKind::Segmentation | MapKind::Albedo => format!("{k:03}.exr"),
            _ => format!("{k:03}_0001.exr"),
        }
    }

    /// Number of channels kept in memory: scalar maps keep their first channel.
    pub fn channels(self) -> usize {
        match self {
            MapKind::Roughness
            | MapKind::IndexMA
            | MapKind::Segmentation
            | MapKind::Metallic
            | MapKind::Depth
            | MapKind::TriIndex => 1,
            _ => 3,
        }
    }

    /// Maps holding integer labels.
    pub fn is_label(self) -> bool {
        matches!(
            self,
            MapKind::IndexMA | MapKind::Segmentation | MapKind::TriIndex
        )
    }
}

/// Which scene-folder convention a dataset came from.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Layout {
    FiptSynthetic,
    FiptReal,
    Nerfstudio,
}

/// One posed photograph and its optional per-pixel maps.
#[derive(Clone, Debug)]
pub struct View {
    /// Frame index within its split (the `k` of the file names).
    pub index: usize,
    pub camera: Camera,
    /// Linear radiance, 3 channels: the HDR photo, or an LDR photo linearised (at load with the
    /// sRGB curve and the frame's given exposure, or 1; a run re-linearises it with the
    /// response and exposures it estimates).
    pub image: Image,
    /// The 8-bit photo when the view's photo is LDR (PNG, JPEG).
    pub ldr: Option<LdrFrame>,
    pub maps: BTreeMap<MapKind, Image>,
}

impl View {
    pub fn map(&self, kind: MapKind) -> Option<&Image> {
        self.maps.get(&kind)
    }

    /// Integer labels of a label map (rounded), row-major.
    pub fn labels(&self, kind: MapKind) -> Option<Vec<i32>> {
        self.map(kind).map(|m| {
            (0..m.num_pixels())
                .map(|p| m.scalar(p).round() as i32)
                .collect()
        })
    }
}

/// A set of views of one size.
#[derive(Clone, Debug)]
pub struct Split {
    pub name: String,
    pub width: usize,
    pub height: usize,
    pub views: Vec<View>,
}

impl Split {
    pub fn num_pixels(&self) -> usize {
        self.views.len() * self.width * self.height
    }

    /// True when every view has the map.
    pub fn has_map(&self, kind: MapKind) -> bool {
        !self.views.is_empty() && self.views.iter().all(|v| v.maps.contains_key(&kind))
    }

    /// True when the photos are 8-bit LDR (the loader never mixes the two kinds).
    pub fn is_ldr(&self) -> bool {
        self.views.first().is_some_and(|v| v.ldr.is_some())
    }
}

/// What to load besides meshes, cameras and images.
#[derive(Clone, Debug)]
pub struct LoadOptions {
    /// Maps to load where present (absent folders are skipped, incomplete folders are errors).
    pub maps: Vec<MapKind>,
    /// Also load the `val/` split (synthetic layout) or its stand-in.
    pub val: bool,
}

impl Default for LoadOptions {
    fn default() -> Self {
        Self {
            maps: MapKind::FIPT.to_vec(),
            val: true,
        }
    }
}

impl LoadOptions {
    pub fn all_maps() -> Self {
        Self {
            maps: MapKind::ALL.to_vec(),
            val: true,
        }
    }
}

/// A loaded scene folder.
#[derive(Clone, Debug)]
pub struct Dataset {
    pub root: PathBuf,
    pub layout: Layout,
    pub mesh: Mesh,
    pub train: Split,
    pub val: Option<Split>,
    pub meta: Option<SceneMeta>,
}

impl Dataset {
    /// Loads a scene folder, detecting its layout: `train/transforms.json` (FIPT synthetic),
    /// `cam.txt` (FIPT real) or `transforms.json` (nerfstudio).
    pub fn load(root: &Path, opts: &LoadOptions) -> Result<Dataset> {
        if !root.is_dir() {
            return Err(FileError::new(root, "scene folder not found"));
        }
        let layout = if root.join("train/transforms.json").exists() {
            Layout::FiptSynthetic
        } else if root.join("cam.txt").exists() {
            Layout::FiptReal
        } else if root.join("transforms.json").exists() {
            Layout::Nerfstudio
        } else {
            return Err(FileError::new(
                root,
                "not a scene folder: expected train/transforms.json (FIPT synthetic), cam.txt (FIPT real) or transforms.json (nerfstudio)",
            ));
        };
        let mesh = Mesh::load_obj(&root.join("scene.obj"))?;
        let (train, val) = match layout {
            Layout::FiptSynthetic => {
                let train = load_synthetic_split(root, "train", opts, None)?;
                let val = if opts.val && root.join("val/transforms.json").exists() {
                    Some(load_synthetic_split(
                        root,
                        "val",
                        opts,
                        Some((train.width, train.height)),
                    )?)
                } else {
                    None
                };
                (train, val)
            }
            Layout::FiptReal => {
                let train = load_real(root, opts)?;
                let val = opts.val.then(|| first_views(&train, 8, "val"));
                (train, val)
            }
            Layout::Nerfstudio => {
                let train = load_nerfstudio(root, opts)?;
                let val = opts.val.then(|| first_views(&train, 8, "val"));
                (train, val)
            }
        };
        if let Some(v) = val.as_ref().filter(|v| v.is_ldr() != train.is_ldr()) {
            let kind = |s: &Split| {
                if s.is_ldr() {
                    "LDR (PNG/JPEG)"
                } else {
                    "HDR (EXR)"
                }
            };
            return Err(FileError::new(
                root,
                format!(
                    "mixed HDR and LDR photos: the train photos are {} but the {} photos are {}",
                    kind(&train),
                    v.name,
                    kind(v)
                ),
            ));
        }
        let meta_path = root.join("scene_meta.json");
        let meta = if meta_path.exists() {
            let m = SceneMeta::load(&meta_path)?;
            let ntri = mesh.num_triangles();
            if let Some((k, p)) = m
                .parts
                .iter()
                .enumerate()
                .find(|(_, p)| p.triangles[1] > ntri)
            {
                return Err(FileError::new(
                    root.join("scene.obj"),
                    format!(
                        "has {ntri} triangles: {} parts[{k}].triangles [{}, {}] runs past them",
                        meta_path.display(),
                        p.triangles[0],
                        p.triangles[1],
                    ),
                ));
            }
            Some(m)
        } else {
            None
        };
        Ok(Dataset {
            root: root.to_path_buf(),
            layout,
            mesh,
            train,
            val,
            meta,
        })
    }

    /// True when the photos are 8-bit LDR.
    pub fn is_ldr(&self) -> bool {
        self.train.is_ldr()
    }

    /// The splits present, train first.
    pub fn splits(&self) -> Vec<&Split> {
        std::iter::once(&self.train)
            .chain(self.val.as_ref())
            .collect()
    }
}

fn first_views(split: &Split, n: usize, name: &str) -> Split {
    Split {
        name: name.into(),
        width: split.width,
        height: split.height,
        views: split.views.iter().take(n).cloned().collect(),
    }
}

/// Reads a `transforms.json` (either layout, or `render --cameras`), its numbers checked
/// against their ranges (`crate::ranges`).
pub fn parse_transforms(path: &Path) -> Result<Value> {
    let text = read_text(path)?;
    let v = serde_json::from_str(&text)
        .map_err(|e| FileError::new(path, format!("malformed JSON: {e}")))?;
    crate::ranges::check(crate::ranges::Kind::Transforms, &v, path)?;
    Ok(v)
}

fn json_f64(v: &Value, key: &str, path: &Path) -> Result<f64> {
    v.get(key)
        .and_then(Value::as_f64)
        .ok_or_else(|| FileError::new(path, format!("missing or non-numeric '{key}'")))
}

fn json_matrix4(v: &Value, path: &Path, k: usize) -> Result<[[f64; 4]; 4]> {
    let bad = || {
        FileError::new(
            path,
            format!("frame {k}: 'transform_matrix' must be a 4x4 array of numbers"),
        )
    };
    let rows = v
        .get("transform_matrix")
        .and_then(Value::as_array)
        .ok_or_else(bad)?;
    if rows.len() != 4 {
        return Err(bad());
    }
    let mut m = [[0.0; 4]; 4];
    for (i, r) in rows.iter().enumerate() {
        let r = r.as_array().filter(|r| r.len() == 4).ok_or_else(bad)?;
        for (j, x) in r.iter().enumerate() {
            m[i][j] = x.as_f64().ok_or_else(bad)?;
        }
    }
    if m.iter().flatten().any(|x| !x.is_finite()) {
        return Err(bad());
    }
    // The camera's axes (the first three columns) must span space: the volume they span
    // against the product of their lengths (scale-free).
    let col = |j: usize| glam::DVec3::new(m[0][j], m[1][j], m[2][j]);
    let volume = col(0).cross(col(1)).dot(col(2)).abs();
    if volume <= 1e-6 * col(0).length() * col(1).length() * col(2).length() {
        return Err(FileError::new(
            path,
            format!("frame {k}: 'transform_matrix' has degenerate axes (its 3x3 part is singular)"),
        ));
    }
    Ok(m)
}

/// The `frames` array of a parsed `transforms.json`, or an error naming the file.
pub fn frames_of<'a>(v: &'a Value, path: &Path) -> Result<&'a Vec<Value>> {
    let frames = v
        .get("frames")
        .and_then(Value::as_array)
        .ok_or_else(|| FileError::new(path, "missing 'frames' array"))?;
    if frames.is_empty() {
        return Err(FileError::new(path, "'frames' is empty"));
    }
    Ok(frames)
}

/// Checks that `dir` holds the file `name(k)` of every frame `k < n` that `lister` lists,
/// naming the missing files (and, with `strict`, any file of the same extension that no frame
/// names) in the error.
fn check_frames(
    dir: &Path,
    n: usize,
    name: impl Fn(usize) -> String,
    lister: &Path,
    strict: bool,
) -> Result<()> {
    let rd = std::fs::read_dir(dir).map_err(|e| FileError::new(dir, e.to_string()))?;
    let first = name(0);
    let ext = Path::new(&first)
        .extension()
        .and_then(|e| e.to_str())
        .unwrap_or("exr")
        .to_string();
    let present: std::collections::BTreeSet<String> = rd
        .filter_map(|e| e.ok())
        .filter(|e| {
            e.path()
                .extension()
                .is_some_and(|x| x.eq_ignore_ascii_case(&ext))
        })
        .map(|e| e.file_name().to_string_lossy().into_owned())
        .collect();
    let list = |names: &[String]| {
        let shown = names.iter().take(5).cloned().collect::<Vec<_>>().join(", ");
        if names.len() > 5 {
            format!("{shown} and {} more", names.len() - 5)
        } else {
            shown
        }
    };
    let expected: Vec<String> = (0..n).map(name).collect();
    let missing: Vec<String> = expected
        .iter()
        .filter(|f| !present.contains(*f))
        .cloned()
        .collect();
    if !missing.is_empty() {
        return Err(FileError::new(
            dir,
            format!(
                "missing {} of the {n} frames that {} lists: {}",
                missing.len(),
                lister.display(),
                list(&missing)
            ),
        ));
    }
    if strict && present.len() > n {
        let expected: std::collections::BTreeSet<&String> = expected.iter().collect();
        let extra: Vec<String> = present
            .iter()
            .filter(|f| !expected.contains(f))
            .cloned()
            .collect();
        return Err(FileError::new(
            dir,
            format!(
                "{} {} file(s) that no frame of {} names ({n} frames): {}",
                extra.len(),
                ext.to_uppercase(),
                lister.display(),
                list(&extra)
            ),
        ));
    }
    Ok(())
}

fn check_size(img: &Image, path: &Path, want: (usize, usize)) -> Result<()> {
    if (img.width, img.height) != want {
        return Err(FileError::new(
            path,
            format!(
                "image is {}x{} but the scene's images are {}x{}",
                img.width, img.height, want.0, want.1
            ),
        ));
    }
    Ok(())
}

/// File name of the HDR photo of frame `k`.
pub fn image_file(k: usize) -> String {
    format!("{k:03}_0001.exr")
}

/// The photo extensions fipt reads: HDR first.
const PHOTO_EXTS: [&str; 4] = ["exr", "png", "jpg", "jpeg"];

/// The extension of the photos of a FIPT image folder (`exr`, `png`, `jpg` or `jpeg`, as
/// spelled on disk), from the files named `{k:03}_0001.<ext>`. HDR and LDR photos mixed in
/// one folder are an error naming one of each.
fn photo_ext(dir: &Path) -> Result<String> {
    let rd = std::fs::read_dir(dir).map_err(|e| FileError::new(dir, e.to_string()))?;
    let mut seen: BTreeMap<String, String> = BTreeMap::new();
    for e in rd.filter_map(|e| e.ok()) {
        let name = e.file_name().to_string_lossy().into_owned();
        let Some((stem, ext)) = name.rsplit_once('.') else {
            continue;
        };
        if stem.len() == 8
            && stem.ends_with("_0001")
            && stem[..3].bytes().all(|b| b.is_ascii_digit())
            && PHOTO_EXTS.contains(&ext.to_ascii_lowercase().as_str())
        {
            seen.entry(ext.to_string()).or_insert(name);
        }
    }
    let hdr = seen.iter().find(|(e, _)| e.eq_ignore_ascii_case("exr"));
    let ldr = seen.iter().find(|(e, _)| !e.eq_ignore_ascii_case("exr"));
    match (hdr, ldr) {
        (Some((_, h)), Some((_, l))) => Err(FileError::new(
            dir,
            format!(
                "mixed HDR and LDR photos ({h} and {l}): a scene's photos must all be EXR or all 8-bit PNG/JPEG"
            ),
        )),
        (Some((e, _)), None) => Ok(e.clone()),
        (None, Some(_)) => {
            if seen.len() > 1 {
                let names: Vec<&String> = seen.values().collect();
                return Err(FileError::new(
                    dir,
                    format!(
                        "photos of more than one format ({}): use one",
                        names
                            .iter()
                            .map(|s| s.as_str())
                            .collect::<Vec<_>>()
                            .join(", ")
                    ),
                ));
            }
            Ok(seen.keys().next().expect("one").clone())
        }
        (None, None) => Ok("exr".to_string()),
    }
}

/// Reads a photo, HDR (EXR) or LDR (PNG, JPEG, by extension), checking its size when `size`
/// is given. An LDR photo comes back linearised with the sRGB curve at `exposure` (or 1).
fn read_any_photo(
    path: &Path,
    size: Option<(usize, usize)>,
    exposure: Option<f64>,
) -> Result<(Image, Option<LdrFrame>)> {
    if !is_ldr_ext(path) {
        return Ok((read_sized(path, 3, false, size)?, None));
    }
    let mut f = read_ldr(path)?;
    f.exposure = exposure;
    let image = f.linearise(&Response::srgb(), exposure.unwrap_or(1.0));
    if let Some(s) = size {
        check_size(&image, path, s)?;
    }
    Ok((image, Some(f)))
}

/// The `exposure` of frame `k` of a `transforms.json`, where given.
fn frame_exposure(f: &Value, path: &Path, k: usize) -> Result<Option<f64>> {
    match f.get("exposure") {
        None => Ok(None),
        Some(v) => match v.as_f64() {
            Some(e) if e > 0.0 && e.is_finite() => Ok(Some(e)),
            _ => Err(FileError::new(
                path,
                format!("frame {k}: 'exposure' must be a positive number (relative exposure)"),
            )),
        },
    }
}

/// Reads one map file and keeps the channels its kind needs.
fn read_map(path: &Path, kind: MapKind, size: (usize, usize)) -> Result<Image> {
    read_sized(path, kind.channels(), kind.is_label(), Some(size))
}

/// Reads an EXR with `channels` channels (1: the first; 3: a single channel repeated), of
/// `size` where given, its values integers where `is_label`.
fn read_sized(
    path: &Path,
    channels: usize,
    is_label: bool,
    size: Option<(usize, usize)>,
) -> Result<Image> {
    let img = Image::read_exr(path)?;
    if let Some(size) = size {
        check_size(&img, path, size)?;
    }
    let img = if channels == 1 {
        img.first_channel()
    } else if img.channels == 1 {
        let data = img.data.iter().flat_map(|&v| [v, v, v]).collect();
        Image::from_data(img.width, img.height, 3, data)
    } else {
        img
    };
    if is_label && let Some(p) = img.data.iter().position(|v| (v - v.round()).abs() > 1e-3) {
        return Err(FileError::new(
            path,
            format!(
                "label map has a non-integer value {} at row {} col {}",
                img.data[p],
                p / img.width,
                p % img.width
            ),
        ));
    }
    Ok(img)
}

/// Loads the optional maps of frame `k` from `dir/<Folder>/` where the folder exists.
fn load_maps(
    dir: &Path,
    k: usize,
    opts: &LoadOptions,
    size: (usize, usize),
) -> Result<BTreeMap<MapKind, Image>> {
    let mut maps = BTreeMap::new();
    for &kind in &opts.maps {
        let folder = dir.join(kind.folder());
        if !folder.is_dir() {
            continue;
        }
        let path = folder.join(kind.file_name(k));
        maps.insert(kind, read_map(&path, kind, size)?);
    }
    Ok(maps)
}

/// One split (`train` or `val`) of a FIPT synthetic scene alone: what rendering a recovered
/// model needs from a scene folder (cameras and reference images), even when its other split
/// is absent.
pub fn load_split(root: &Path, name: &str, opts: &LoadOptions) -> Result<Split> {
    let t = root.join(name).join("transforms.json");
    if !t.is_file() {
        return Err(FileError::new(&t, "file not found (the split's cameras)"));
    }
    load_synthetic_split(root, name, opts, None)
}

fn load_synthetic_split(
    root: &Path,
    name: &str,
    opts: &LoadOptions,
    size: Option<(usize, usize)>,
) -> Result<Split> {
    let dir = root.join(name);
    let tpath = dir.join("transforms.json");
    let json = parse_transforms(&tpath)?;
    let fov = json_f64(&json, "camera_angle_x", &tpath)?;
    if !(fov > 0.0 && fov < std::f64::consts::PI) {
        return Err(FileError::new(
            &tpath,
            format!("camera_angle_x = {fov} is not a field of view in (0, pi) radians"),
        ));
    }
    let frames = frames_of(&json, &tpath)?;
    let img_dir = dir.join("Image");
    if !img_dir.is_dir() {
        return Err(FileError::new(&img_dir, "image folder not found"));
    }
    let ext = photo_ext(&img_dir)?;
    let photo = |k: usize| format!("{k:03}_0001.{ext}");
    check_frames(&img_dir, frames.len(), photo, &tpath, true)?;
    for &kind in &opts.maps {
        let folder = dir.join(kind.folder());
        if folder.is_dir() {
            check_frames(&folder, frames.len(), |k| kind.file_name(k), &tpath, false)?;
        }
    }
    let mats: Vec<[[f64; 4]; 4]> = frames
        .iter()
        .enumerate()
        .map(|(k, f)| json_matrix4(f, &tpath, k))
        .collect::<Result<_>>()?;
    let exposures: Vec<Option<f64>> = frames
        .iter()
        .enumerate()
        .map(|(k, f)| frame_exposure(f, &tpath, k))
        .collect::<Result<_>>()?;
    // The size is set by the first train image (as the reference does).
    let size = match size {
        Some(s) => s,
        None => {
            let (img, _) = read_any_photo(&img_dir.join(photo(0)), None, None)?;
            (img.width, img.height)
        }
    };
    let views: Vec<View> = mats
        .par_iter()
        .enumerate()
        .map(|(k, m)| {
            let path = img_dir.join(photo(k));
            let (image, ldr) = read_any_photo(&path, Some(size), exposures[k])?;
            let maps = load_maps(&dir, k, opts, size)?;
            Ok(View {
                index: k,
                camera: Camera::from_fipt_c2w(*m, fov, size.0, size.1),
                image,
                ldr,
                maps,
            })
        })
        .collect::<Result<_>>()?;
    Ok(Split {
        name: name.into(),
        width: size.0,
        height: size.1,
        views,
    })
}

/// Parses a "count line + 3 lines per item" text file into rows of 3 numbers.
fn parse_triples(path: &Path) -> Result<Vec<[f64; 3]>> {
    let text = read_text(path)?;
    let mut lines = text
        .lines()
        .enumerate()
        .filter(|(_, l)| !l.trim().is_empty());
    let (_, first) = lines
        .next()
        .ok_or_else(|| FileError::new(path, "empty file"))?;
    let n: usize = first
        .trim()
        .parse()
        .map_err(|_| FileError::new(path, format!("line 1: expected a count, found '{first}'")))?;
    // `n` comes from the file: nothing is sized by it (a damaged count once asked for 309 GB).
    let mut rows = Vec::new();
    for (ln, l) in lines {
        let vals: Vec<f64> = l
            .split_whitespace()
            .map(|t| t.parse::<f64>())
            .collect::<std::result::Result<_, _>>()
            .map_err(|_| FileError::new(path, format!("line {}: bad number in '{l}'", ln + 1)))?;
        if vals.len() != 3 || vals.iter().any(|v| !v.is_finite()) {
            return Err(FileError::new(
                path,
                format!("line {}: expected 3 finite numbers, found '{l}'", ln + 1),
            ));
        }
        rows.push([vals[0], vals[1], vals[2]]);
    }
    if n.checked_mul(3) != Some(rows.len()) {
        return Err(FileError::new(
            path,
            format!(
                "header says {n} cameras ({} lines) but {} lines follow",
                n.saturating_mul(3),
                rows.len()
            ),
        ));
    }
    Ok(rows)
}

fn load_real(root: &Path, opts: &LoadOptions) -> Result<Split> {
    let cam_path = root.join("cam.txt");
    let k_path = root.join("K_list.txt");
    let cams = parse_triples(&cam_path)?;
    let ks = parse_triples(&k_path)?;
    if cams.len() != ks.len() {
        return Err(FileError::new(
            &k_path,
            format!(
                "{} intrinsics but {} lists {} cameras",
                ks.len() / 3,
                cam_path.display(),
                cams.len() / 3
            ),
        ));
    }
    let n = cams.len() / 3;
    let img_dir = root.join("Image");
    if !img_dir.is_dir() {
        return Err(FileError::new(&img_dir, "image folder not found"));
    }
    let ext = photo_ext(&img_dir)?;
    let photo = |k: usize| format!("{k:03}_0001.{ext}");
    check_frames(&img_dir, n, photo, &cam_path, true)?;
    for &kind in &opts.maps {
        let folder = root.join(kind.folder());
        if folder.is_dir() {
            check_frames(&folder, n, |k| kind.file_name(k), &cam_path, false)?;
        }
    }
    let (first, _) = read_any_photo(&img_dir.join(photo(0)), None, None)?;
    let size = (first.width, first.height);
    let views = (0..n)
        .into_par_iter()
        .map(|k| {
            let path = img_dir.join(photo(k));
            let (mut image, ldr) = read_any_photo(&path, Some(size), None)?;
            image.data.iter_mut().for_each(|v| *v = v.max(0.0));
            let o = DVec3::from(cams[3 * k]);
            let target = DVec3::from(cams[3 * k + 1]);
            let up = DVec3::from(cams[3 * k + 2]);
            let fwd = target - o;
            if fwd.length() == 0.0 || up.length() == 0.0 || fwd.normalize().cross(up).length() < 1e-6
            {
                return Err(FileError::new(
                    &cam_path,
                    format!("camera {k}: look-at point equals origin or up is parallel to the view direction"),
                ));
            }
            let kmat = [ks[3 * k], ks[3 * k + 1], ks[3 * k + 2]];
            let (fx, fy) = (kmat[0][0], kmat[1][1]);
            if !(fx > 0.0 && fx <= 1e6 && fy > 0.0 && fy <= 1e6) {
                return Err(FileError::new(
                    &k_path,
                    format!(
                        "camera {k}: focal lengths fx = {fx}, fy = {fy} (K[0][0], K[1][1]) are out of their range (0, 1e6] pixels"
                    ),
                ));
            }
            let maps = load_maps(root, k, opts, size)?;
            Ok(View {
                index: k,
                camera: Camera::from_look_at(o, target, up, kmat, size.0, size.1),
                image,
                ldr,
                maps,
            })
        })
        .collect::<Result<Vec<_>>>()?;
    Ok(Split {
        name: "train".into(),
        width: size.0,
        height: size.1,
        views,
    })
}

fn load_nerfstudio(root: &Path, opts: &LoadOptions) -> Result<Split> {
    let tpath = root.join("transforms.json");
    let json = parse_transforms(&tpath)?;
    let frames = frames_of(&json, &tpath)?;
    let get = |f: &Value, key: &str| f.get(key).or_else(|| json.get(key)).and_then(Value::as_f64);
    let views = frames
        .par_iter()
        .enumerate()
        .map(|(k, f)| {
            let need = |key: &str| {
                get(f, key).ok_or_else(|| {
                    FileError::new(&tpath, format!("frame {k}: missing or non-numeric '{key}'"))
                })
            };
            let k_px = Intrinsics {
                fx: need("fl_x")?,
                fy: need("fl_y")?,
                cx: need("cx")?,
                cy: need("cy")?,
            };
            let (w, h) = (need("w")? as usize, need("h")? as usize);
            let fp = f
                .get("file_path")
                .and_then(Value::as_str)
                .ok_or_else(|| FileError::new(&tpath, format!("frame {k}: missing 'file_path'")))?;
            let mut path = root.join(fp);
            if path.extension().is_none() {
                // The first of `PHOTO_EXTS` present, EXR by default (named in the error).
                path = PHOTO_EXTS
                    .iter()
                    .map(|e| path.with_extension(e))
                    .find(|p| p.is_file())
                    .unwrap_or_else(|| path.with_extension("exr"));
            }
            let (image, ldr) = read_any_photo(&path, Some((w, h)), frame_exposure(f, &tpath, k)?)?;
            let m = json_matrix4(f, &tpath, k)?;
            let stem = path.file_stem().and_then(|s| s.to_str()).unwrap_or("");
            let mut maps = BTreeMap::new();
            if opts.maps.contains(&MapKind::Segmentation) {
                let seg = root.join("segmentation").join(format!("{stem}.exr"));
                if root.join("segmentation").is_dir() {
                    maps.insert(
                        MapKind::Segmentation,
                        read_map(&seg, MapKind::Segmentation, (w, h))?,
                    );
                }
            }
            Ok((
                View {
                    index: k,
                    camera: Camera::from_opengl_c2w(m, k_px, w, h),
                    image,
                    ldr,
                    maps,
                },
                path,
            ))
        })
        .collect::<Result<Vec<(View, PathBuf)>>>()?;
    if let (Some((_, h)), Some((_, l))) = (
        views.iter().find(|(v, _)| v.ldr.is_none()),
        views.iter().find(|(v, _)| v.ldr.is_some()),
    ) {
        return Err(FileError::new(
            &tpath,
            format!(
                "mixed HDR and LDR photos ({} and {}): a scene's photos must all be EXR or all 8-bit PNG/JPEG",
                h.display(),
                l.display()
            ),
        ));
    }
    let views: Vec<View> = views.into_iter().map(|(v, _)| v).collect();
    let (w, h) = (views[0].image.width, views[0].image.height);
    if let Some(v) = views
        .iter()
        .find(|v| (v.image.width, v.image.height) != (w, h))
    {
        return Err(FileError::new(
            &tpath,
            format!("frame {} has a different image size than frame 0", v.index),
        ));
    }
    Ok(Split {
        name: "train".into(),
        width: w,
        height: h,
        views,
    })
}

/// Cameras alone from a `transforms.json`, for rendering new views: the nerfstudio convention
/// where the file has intrinsics (`fl_x`, `fl_y`, `cx`, `cy`, `w`, `h`, per frame or at the top),
/// else the FIPT synthetic one (`camera_angle_x`, c2w columns left/up/forward) at `size` (the
/// scene's image size) unless the file gives `w` and `h`.
pub fn load_cameras(path: &Path, size: (usize, usize)) -> Result<Vec<Camera>> {
    let json = parse_transforms(path)?;
    let frames = frames_of(&json, path)?;
    let get = |f: &Value, key: &str| f.get(key).or_else(|| json.get(key)).and_then(Value::as_f64);
    let nerfstudio = frames.first().is_some_and(|f| get(f, "fl_x").is_some());
    let fov = if nerfstudio {
        0.0
    } else {
        let fov = json_f64(&json, "camera_angle_x", path)?;
        if !(fov > 0.0 && fov < std::f64::consts::PI) {
            return Err(FileError::new(
                path,
                format!("camera_angle_x = {fov} is not a field of view in (0, pi) radians"),
            ));
        }
        fov
    };
    frames
        .iter()
        .enumerate()
        .map(|(k, f)| {
            let m = json_matrix4(f, path, k)?;
            let w = get(f, "w").map_or(size.0, |v| v as usize);
            let h = get(f, "h").map_or(size.1, |v| v as usize);
            if w == 0 || h == 0 || w > 1 << 15 || h > 1 << 15 {
                return Err(FileError::new(
                    path,
                    format!("frame {k}: image size {w}x{h}"),
                ));
            }
            if !nerfstudio {
                return Ok(Camera::from_fipt_c2w(m, fov, w, h));
            }
            let need = |key: &str| {
                get(f, key).ok_or_else(|| {
                    FileError::new(path, format!("frame {k}: missing or non-numeric '{key}'"))
                })
            };
            let k_px = Intrinsics {
                fx: need("fl_x")?,
                fy: need("fl_y")?,
                cx: need("cx")?,
                cy: need("cy")?,
            };
            Ok(Camera::from_opengl_c2w(m, k_px, w, h))
        })
        .collect()
}
