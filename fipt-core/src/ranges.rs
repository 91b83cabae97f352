//! The allowed range of every numeric field of every JSON input file, in one table (`FIELDS`,
//! printed in `docs/inputs.md`), and the check every loader runs on a file before it reads it:
//! a value out of its range is an error naming the file, the field (its JSON path) and the
//! range. Fields a file may carry that fipt does not read are not checked.
//!
//! A path is the field's keys joined by `.`, `[]` for any element of an array, `*` for any key
//! of a map (`parts[].material.roughness`, `frames[].transform_matrix[][]`,
//! `emitters_scale.*`). A relight file's `new_emitters[]` take `new_emitter`'s ranges, and a
//! frame's own intrinsics (`frames[].fl_x`) the file's (`fl_x`).
//!
//! Owns: the table and the check. Must not touch: what the fields mean (their loaders).

use crate::io::FileError;
use serde_json::Value;
use std::path::Path;

/// The input files whose fields the table covers.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Kind {
    /// A run config (`configs/*.json`, `--config`, a run's or model's `config.json`).
    Config,
    /// `scene_meta.json`: the ground truth of a scene.
    SceneMeta,
    /// `relight.json`: emitters switched off or rescaled, new emitters.
    Relight,
    /// `render --insert FILE`: inserted objects.
    Insert,
    /// `transforms.json` of the FIPT synthetic or nerfstudio layout, and `render --cameras`.
    Transforms,
}

impl Kind {
    pub const ALL: [Kind; 5] = [
        Kind::Config,
        Kind::SceneMeta,
        Kind::Relight,
        Kind::Insert,
        Kind::Transforms,
    ];

    /// The file's name in the docs.
    pub fn file(self) -> &'static str {
        match self {
            Kind::Config => "config (`configs/*.json`)",
            Kind::SceneMeta => "`scene_meta.json`",
            Kind::Relight => "`relight.json`",
            Kind::Insert => "insert file (`render --insert`)",
            Kind::Transforms => "`transforms.json` (FIPT, nerfstudio, `render --cameras`)",
        }
    }
}

/// A closed or open interval of numbers, integers only where `integer`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Range {
    pub lo: f64,
    pub hi: f64,
    pub lo_open: bool,
    pub hi_open: bool,
    pub integer: bool,
}

impl Range {
    /// Whether `x` lies in the range.
    pub fn holds(&self, x: f64) -> bool {
        let above = if self.lo_open {
            x > self.lo
        } else {
            x >= self.lo
        };
        let below = if self.hi_open {
            x < self.hi
        } else {
            x <= self.hi
        };
        x.is_finite() && above && below && (!self.integer || x.fract() == 0.0)
    }

    /// Values just outside the range (for tests): below it, above it, and a fraction for an
    /// integer range.
    pub fn outside(&self) -> Vec<f64> {
        let step = if self.integer {
            1.0
        } else {
            (self.hi - self.lo).abs().clamp(1e-3, 1.0) * 0.5
        };
        let mut v = vec![
            if self.lo_open {
                self.lo
            } else {
                self.lo - step
            },
            if self.hi_open {
                self.hi
            } else {
                self.hi + step.max(self.hi.abs() * 0.5)
            },
        ];
        if self.integer {
            v.push(self.lo + 0.5);
        }
        v
    }
}

impl std::fmt::Display for Range {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let num = |x: f64| {
            if x == std::f64::consts::PI {
                "π".to_string()
            } else if x == u64::MAX as f64 {
                "2^64 − 1".to_string()
            } else if x.abs() >= 1e5 && x.fract() == 0.0 && (x.abs().log2().fract() == 0.0) {
                format!("2^{}", x.abs().log2() as i32)
            } else if x.abs() >= 1e5 {
                format!("{x:e}")
            } else {
                format!("{x}")
            }
        };
        write!(
            f,
            "{}{}{}, {}{}",
            if self.integer { "integer in " } else { "" },
            if self.lo_open { "(" } else { "[" },
            num(self.lo),
            num(self.hi),
            if self.hi_open { ")" } else { "]" },
        )
    }
}

const fn closed(lo: f64, hi: f64) -> Range {
    Range {
        lo,
        hi,
        lo_open: false,
        hi_open: false,
        integer: false,
    }
}

/// (lo, hi]: positive quantities.
const fn above(lo: f64, hi: f64) -> Range {
    Range {
        lo,
        hi,
        lo_open: true,
        hi_open: false,
        integer: false,
    }
}

const fn int(lo: f64, hi: f64) -> Range {
    Range {
        lo,
        hi,
        lo_open: false,
        hi_open: false,
        integer: true,
    }
}

const UNIT: Range = closed(0.0, 1.0);
const WEIGHT: Range = closed(0.0, 1e3);
const SAMPLES: Range = int(1.0, 65536.0);
const COORD: Range = closed(-1e6, 1e6);
const RADIANCE: Range = closed(0.0, 1e9);
const FILTER_PX: Range = above(0.0, 1e3);
const INDEX: Range = int(0.0, 4294967296.0);

/// One field of one file: its path and range, and why that range.
pub struct Field {
    pub kind: Kind,
    pub path: &'static str,
    pub range: Range,
    pub why: &'static str,
}

const fn f(kind: Kind, path: &'static str, range: Range, why: &'static str) -> Field {
    Field {
        kind,
        path,
        range,
        why,
    }
}

use Kind::{Config as C, Insert as I, Relight as R, SceneMeta as M, Transforms as T};

/// Every numeric field fipt reads from a JSON input, with its range.
#[rustfmt::skip]
pub const FIELDS: &[Field] = &[
    f(C, "seed", int(0.0, 18446744073709551615.0), "a u64"),
    f(C, "bake.voxel_res", int(8.0, 4096.0), "L′ grid, a multiple of 8"),
    f(C, "bake.fill_rings", int(0.0, 64.0), "rings of L′ hole filling"),
    f(C, "bake.samples.diffuse", SAMPLES, "rays per pixel"),
    f(C, "bake.samples.specular[]", SAMPLES, "rays per pixel"),
    f(C, "bake.footprint", int(0.0, 8.0), "n of an n×n ray grid per pixel; 0: the centre"),
    f(C, "bake.filter.radius", int(0.0, 32.0), "pixels; 0: no filter"),
    f(C, "bake.filter.sigma_px", FILTER_PX, "pixels"),
    f(C, "bake.filter.normal_power", closed(0.0, 1e4), "exponent"),
    f(C, "bake.filter.sigma_plane_px", FILTER_PX, "pixels"),
    f(C, "bake.filter.specular_levels[]", int(0.0, 5.0), "a roughness level"),
    f(C, "bake.filter.order", int(0.0, 1.0), "0: the mean; 1: the plane"),
    f(C, "train.epochs", int(1.0, 1000.0), "passes over the pixels"),
    f(C, "train.batch", int(1.0, 16777216.0), "pixels per step"),
    f(C, "train.min_steps", int(0.0, 1e7), "steps"),
    f(C, "train.lr", above(0.0, 1.0), "Adam's rate"),
    f(C, "train.lr_end", above(0.0, 1.0), "a fraction of lr"),
    f(C, "train.balance", UNIT, "a share"),
    f(C, "train.lambda_d_end", UNIT, "a fraction of λ_d"),
    f(C, "train.lambda_d_warmup", UNIT, "a share of the steps"),
    f(C, "train.min_coverage", UNIT, "a share of a pixel"),
    f(C, "train.coverage_crease", closed(0.0, 180.0), "degrees"),
    f(C, "train.lambda_e", WEIGHT, "a loss weight"),
    f(C, "train.lambda_d", WEIGHT, "a loss weight"),
    f(C, "train.prior_sigma", UNIT, "a roughness"),
    f(C, "train.lambda_part", WEIGHT, "a loss weight"),
    f(C, "train.logit_bound", above(0.0, 100.0), "a logit"),
    f(C, "train.lambda_logit", WEIGHT, "a loss weight"),
    f(C, "train.lambda_sem", WEIGHT, "a loss weight"),
    f(C, "train.sem_partners", int(1.0, 1048576.0), "pixels"),
    f(C, "train.grid.levels", int(1.0, 64.0), "hash grid levels"),
    f(C, "train.grid.features", int(1.0, 8.0), "features per level"),
    f(C, "train.grid.log2_table", int(8.0, 24.0), "log2 of entries"),
    f(C, "train.grid.base_resolution", closed(2.0, 1048576.0), "cells"),
    f(C, "train.grid.per_level_scale", closed(1.0, 16.0), "a factor"),
    f(C, "train.grid.max_resolution", closed(1.0, 1048576.0),
        "cells (or \"auto\", \"none\")",
    ),
    f(C, "train.grid.cells_per_footprint", above(0.0, 1024.0), "cells per pixel footprint"),
    f(
        C,
        "train.mlp_hidden",
        int(1.0, 1024.0), "what a saved model may hold"),
    f(C, "train.mlp_layers", int(1.0, 32.0), "what a saved model may hold"),
    f(C, "train.emission_freqs", int(0.0, 32.0), "what a saved model may hold"),
    f(C, "train.emission_depth", int(1.0, 32.0), "what a saved model may hold"),
    f(C, "train.emission_width", int(1.0, 1024.0), "what a saved model may hold"),
    f(C, "train.hop.gain", UNIT, "a relative gain"),
    f(C, "train.hop.min_move", UNIT, "a roughness distance"),
    f(C, "train.hop.steps", above(0.0, 1.0), "a share of the steps"),
    f(C, "train.hop.pull", WEIGHT, "a loss weight"),
    f(C, "train.hop.pixels", int(1.0, 16777216.0), "pixels"),
    f(C, "train.hop.prior", UNIT, "a weight"),
    f(C, "train.hop.patch", closed(0.0, 1e3), "pixel footprints (0: off)"),
    f(C, "train.hop.patch_gain", UNIT, "a relative gain"),
    f(C, "train.hop.patch_min_move", UNIT, "a roughness distance"),
    f(C, "train.hop.anchor", WEIGHT, "a loss weight (0: off)"),
    f(C, "train.hop.hold_metals", WEIGHT, "a loss weight (0: off)"),
    f(C, "train.hop.patch_majority", closed(0.0, 10.0), "standard errors (or null: off)"),
    f(C, "emitters.samples_per_triangle", int(1.0, 1e5), "points"),
    f(C, "emitters.threshold", Range {
            hi_open: true,
            ..UNIT
        }, "a mask value"),
    f(C, "emitters.min_unexplained", UNIT, "a share"),
    f(C, "ldr.solve_pixels", int(1.0, 1e7), "pixels"),
    f(C, "ldr.light_samples", int(1.0, 1e5), "rays per pixel and lamp"),
    f(C, "ldr.edge_tolerance", UNIT, "RMS over the response curves"),
    f(C, "ldr.jpeg_iterations", int(0.0, 1e4), "projected gradient steps"),
    f(C, "refine.rounds", int(0.0, 16.0), "rounds"),
    f(C, "refine.lambda_d", WEIGHT, "a loss weight (or null)"),
    f(C, "refine.lambda_d_warmup", UNIT, "a share of the steps (or null)"),
    f(C, "refine.lambda_m", WEIGHT, "a loss weight (or null)"),
    f(C, "refine.emitter_margin", int(0.0, 8.0), "pixels around an emitter's"),
    f(C, "refine.paths.samples.diffuse", SAMPLES, "paths per pixel"),
    f(C, "refine.paths.samples.specular[]", SAMPLES, "paths per pixel"),
    f(C, "refine.paths.max_depth", int(2.0, 64.0), "segments"),
    f(C, "refine.paths.cache_roughness", closed(0.0, 2.0), "σ; above 1: no cache"),
    f(C, "refine.paths.cache_margin", int(0.0, 8.0), "pixels around an emitter's"),
    f(C, "refine.paths.light_samples", int(0.0, 4096.0), "per pixel"),
    f(C, "refine.paths.footprint", int(0.0, 8.0), "n of an n×n ray grid per pixel; 0: the centre"),
    f(C, "refine.paths.small_parts", int(0.0, 1e8), "pixels of a part over all views; 0: off"),
    f(C, "refine.paths.unseen_cell", int(0.0, 1024.0), "L′ voxels a side; 0: off"),
    f(C, "refine.paths.sharp.below", UNIT, "σ (the key null: off)"),
    f(C, "refine.paths.sharp.specular[]", SAMPLES, "paths per pixel"),
    f(C, "refine.paths.filter.radius", int(0.0, 32.0), "pixels; 0: no filter"),
    f(C, "refine.paths.filter.sigma_px", FILTER_PX, "pixels"),
    f(C, "refine.paths.filter.normal_power", closed(0.0, 1e4), "exponent"),
    f(C, "refine.paths.filter.sigma_plane_px", FILTER_PX, "pixels"),
    f(C, "refine.paths.filter.specular_levels[]", int(0.0, 5.0), "a roughness level"),
    f(C, "refine.paths.filter.order", int(0.0, 1.0), "0: the mean; 1: the plane"),
    f(C, "refine.paths.wave", int(1.0, 16777216.0), "paths per wavefront"),
    f(C, "maps.albedo_samples", SAMPLES, "samples per pixel"),
    f(C, "render.spp", SAMPLES, "samples per pixel"),
    f(C, "render.relight_spp", SAMPLES, "samples per pixel"),
    f(C, "render.max_depth", int(1.0, 64.0), "segments"),
    f(C, "render.pixel_positions", int(0.0, 4096.0), "a square; 0: jitter"),
    f(C, "checkpoint.every_steps", int(0.0, 1e7), "steps; 0: at the end"),
    f(M, "parts[].id", INDEX, "an id"),
    f(M, "parts[].semantic_id", INDEX, "an id"),
    f(M, "parts[].triangles[]", INDEX, "triangle indices"),
    f(M, "parts[].area", closed(0.0, 1e12), "m²"),
    f(M, "parts[].material.base_color[]", UNIT, "a reflectance"),
    f(M, "parts[].material.roughness", UNIT, "GGX σ"),
    f(M, "parts[].material.metallic", UNIT, "a mix"),
    f(M, "parts[].material.texture.width", int(1.0, 1048576.0), "texels (recorded, not read)"),
    f(M, "parts[].material.texture.height", int(1.0, 1048576.0), "texels (recorded, not read)"),
    f(M, "parts[].material.texture.origin[]", COORD, "m"),
    f(M, "parts[].material.texture.axis_u[]", COORD, "a direction"),
    f(M, "parts[].material.texture.axis_v[]", COORD, "a direction"),
    f(M, "parts[].material.texture.size_u", above(0.0, 1e6), "m"),
    f(M, "parts[].material.texture.size_v", above(0.0, 1e6), "m"),
    f(M, "parts[].material.texture.mean_color[]", UNIT, "a reflectance (recorded, not read)"),
    f(M, "parts[].emission.radiance[]", RADIANCE, "W sr⁻¹ m⁻²"),
    f(M, "resolution[]", int(1.0, 32768.0), "pixels"),
    f(M, "camera_angle_x", Range {
            lo_open: true,
            hi_open: true,
            ..closed(0.0, std::f64::consts::PI)
        }, "radians"),
    f(R, "emitters_scale.*", closed(0.0, 1e6), "a factor"),
    f(R, "new_emitter.vertices[][]", COORD, "m"),
    f(R, "new_emitter.triangles[][]", INDEX, "vertex indices"),
    f(R, "new_emitter.radiance[]", RADIANCE, "W sr⁻¹ m⁻²"),
    f(R, "new_emitter.bsdf.base_color[]", UNIT, "a reflectance"),
    f(R, "new_emitter.bsdf.roughness", UNIT, "GGX σ"),
    f(R, "new_emitter.bsdf.metallic", UNIT, "a mix"),
    f(I, "objects[].scale", above(0.0, 1e4), "a factor"),
    f(I, "objects[].scale[]", above(0.0, 1e4), "a factor per axis"),
    f(I, "objects[].rotate_deg[]", closed(-3600.0, 3600.0), "degrees"),
    f(I, "objects[].translate[]", COORD, "m"),
    f(I, "objects[].material.base_color[]", UNIT, "a reflectance"),
    f(I, "objects[].material.roughness", UNIT, "GGX σ"),
    f(I, "objects[].material.metallic", UNIT, "a mix"),
    f(I, "objects[].emission[]", RADIANCE, "W sr⁻¹ m⁻²"),
    f(T, "camera_angle_x", Range {
            lo_open: true,
            hi_open: true,
            ..closed(0.0, std::f64::consts::PI)
        }, "radians"),
    f(T, "frames[].transform_matrix[][]", COORD, "camera to world"),
    f(T, "frames[].exposure", above(0.0, 1e6), "relative exposure of an LDR photo"),
    f(T, "fl_x", above(0.0, 1e6), "pixels"),
    f(T, "fl_y", above(0.0, 1e6), "pixels"),
    f(T, "cx", COORD, "pixels"),
    f(T, "cy", COORD, "pixels"),
    f(T, "w", int(1.0, 32768.0), "pixels"),
    f(T, "h", int(1.0, 32768.0), "pixels"),
];

/// The table entry of a concrete path (`parts[3].area` → `parts[].area`) in `kind`. Each of a
/// relight file's `new_emitters[]` reads as its `new_emitter`, and a frame's own intrinsics
/// (`frames[2].fl_x`) as the file's (`fl_x`).
pub fn field(kind: Kind, path: &str) -> Option<&'static Field> {
    let generic = strip_indices(path);
    let generic = match kind {
        Kind::Relight => generic.replacen("new_emitters[].", "new_emitter.", 1),
        Kind::Transforms
            if !generic.starts_with("frames[].transform_matrix")
                && generic != "frames[].exposure" =>
        {
            generic
                .strip_prefix("frames[].")
                .map_or(generic.clone(), str::to_string)
        }
        _ => generic,
    };
    FIELDS
        .iter()
        .find(|f| f.kind == kind && matches(f.path, &generic))
}

/// Whether the concrete `path` (indices, any keys) is an instance of `pattern`.
fn matches(pattern: &str, path: &str) -> bool {
    let generic = strip_indices(path);
    if !pattern.contains('*') {
        return pattern == generic;
    }
    let (p, g): (Vec<&str>, Vec<&str>) =
        (pattern.split('.').collect(), generic.split('.').collect());
    p.len() == g.len() && p.iter().zip(&g).all(|(a, b)| *a == "*" || a == b)
}

/// `a[3].b[0][1]` → `a[].b[][]`.
fn strip_indices(path: &str) -> String {
    let mut out = String::with_capacity(path.len());
    let mut in_index = false;
    for c in path.chars() {
        match c {
            '[' => {
                in_index = true;
                out.push('[');
            }
            ']' => {
                in_index = false;
                out.push(']');
            }
            _ if in_index => {}
            _ => out.push(c),
        }
    }
    out
}

/// Checks every numeric field of `value` (the JSON of `file`, a `kind`) that the table lists
/// against its range: an error naming the file, the field and the range for the first one out
/// of it.
pub fn check(kind: Kind, value: &Value, file: &Path) -> Result<(), FileError> {
    check_value(kind, value).map_err(|msg| FileError::new(file, msg))
}

/// `check` without the file: the message names the field and the range.
pub fn check_value(kind: Kind, value: &Value) -> Result<(), String> {
    let mut err = None;
    walk(value, &mut String::new(), &mut |path, x| {
        if err.is_some() {
            return;
        }
        if let Some(f) = field(kind, path) {
            let v = x.as_f64().unwrap_or(f64::INFINITY);
            // u64 values above 2^53 read exactly only as u64.
            let ok = f.range.holds(v)
                || (f.range.integer
                    && x.as_u64()
                        .is_some_and(|u| (u as f64) <= f.range.hi && (u as f64) >= f.range.lo));
            if !ok {
                err = Some(format!("{path}: {x} is out of its range {}", f.range));
            }
        }
    });
    err.map_or(Ok(()), Err)
}

/// Calls `leaf(path, number)` for every number in `v`.
pub fn walk(v: &Value, path: &mut String, leaf: &mut dyn FnMut(&str, &serde_json::Number)) {
    match v {
        Value::Number(n) => leaf(path, n),
        Value::Array(a) => {
            for (i, x) in a.iter().enumerate() {
                let len = path.len();
                path.push_str(&format!("[{i}]"));
                walk(x, path, leaf);
                path.truncate(len);
            }
        }
        Value::Object(m) => {
            for (k, x) in m {
                let len = path.len();
                if !path.is_empty() {
                    path.push('.');
                }
                path.push_str(k);
                walk(x, path, leaf);
                path.truncate(len);
            }
        }
        _ => {}
    }
}

/// The table as the Markdown of `docs/inputs.md`.
pub fn markdown_table() -> String {
    let mut s = String::from("| file | field | range | unit or meaning |\n|---|---|---|---|\n");
    for f in FIELDS {
        s.push_str(&format!(
            "| {} | `{}` | {} | {} |\n",
            f.kind.file(),
            f.path,
            f.range,
            f.why
        ));
    }
    s
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn paths_match_their_patterns_and_ranges_hold_their_ends() {
        assert!(matches(
            "parts[].material.roughness",
            "parts[12].material.roughness"
        ));
        assert!(matches(
            "frames[].transform_matrix[][]",
            "frames[0].transform_matrix[3][1]"
        ));
        assert!(matches("emitters_scale.*", "emitters_scale.lamp"));
        assert!(!matches("emitters_scale.*", "emitters_scale.a.b"));
        assert!(!matches("parts[].area", "parts[0].material.roughness"));
        for f in FIELDS {
            for x in f.range.outside() {
                assert!(!f.range.holds(x), "{} holds {x}", f.path);
            }
            assert!(!f.range.holds(f64::NAN) && !f.range.holds(f64::INFINITY));
        }
        let r = int(1.0, 64.0);
        assert!(r.holds(1.0) && r.holds(64.0) && !r.holds(1.5) && !r.holds(65.0));
        let e = check(
            Kind::SceneMeta,
            &serde_json::json!({"parts": [{"material": {"roughness": 0.5}}, {"material": {"roughness": 1.5}}]}),
            Path::new("x/scene_meta.json"),
        )
        .unwrap_err()
        .to_string();
        assert!(
            e.contains("x/scene_meta.json")
                && e.contains("parts[1].material.roughness")
                && e.contains("[0, 1]"),
            "{e}"
        );
    }
}
