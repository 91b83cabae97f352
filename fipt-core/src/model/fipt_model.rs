//! The recovered scene model: the material field (hash grid + MLP) and the emission mask of
//! Eq. 14, with the scene box that maps world positions into the grid's unit cube.
//!
//! Owns: inference (batched queries of a, σ, m and α), save and load. Must not touch:
//! optimisation (`step::Trainer` holds a `FiptModel` and its optimisers).

use super::fields::{
    EmissionMask, EmissionMaskConfig, MaterialFieldConfig, Mlp, alpha_from_raw, decode_material,
};
use super::hashgrid::HashGrid;
use super::hashgrid_device::{self, GridTables};
use super::part_offsets::{PartColumns, PartMap, PartOffsets};
use crate::scene::SceneBox;
use burn::module::{Module, ModuleVisitor, Param};
use burn::tensor::{Device, Tensor, TensorData};
use std::path::Path;

/// The optimised networks (everything but the host hash table).
#[derive(Module, Debug)]
pub struct Nets {
    pub material: Mlp,
    pub emission: EmissionMask,
    /// Per-part offsets of the material head (`ModelSpec::parts` rows; None when 0).
    pub part_offsets: Option<PartOffsets>,
}

/// What a saved model needs to be rebuilt before its parameters are read: the field configs
/// and the scene box (`model.json`).
#[derive(Clone, Debug, serde::Serialize, serde::Deserialize)]
pub struct ModelSpec {
    pub material: MaterialFieldConfig,
    pub emission: EmissionMaskConfig,
    pub scene_box: SceneBox,
    /// Rows of the per-part offset table (`part_offsets`; 0: none, the reference's field).
    #[serde(default, skip_serializing_if = "is_zero")]
    pub parts: usize,
    /// The logits the part offsets move (absent: all five, as models saved before the key).
    #[serde(default, skip_serializing_if = "is_all")]
    pub part_columns: PartColumns,
}

fn is_zero(n: &usize) -> bool {
    *n == 0
}

fn is_all(c: &PartColumns) -> bool {
    *c == PartColumns::All
}

impl ModelSpec {
    /// Range checks before anything is built from a saved spec: the hash grid's
    /// (`HashGridConfig::check`), networks of at most 1024 units and 32 layers, at most 32
    /// frequencies, a finite scene box.
    pub fn check(&self) -> Result<(), String> {
        self.material.grid.check()?;
        let m = &self.material;
        if !(1..=1024).contains(&m.hidden) || !(1..=32).contains(&m.hidden_layers) {
            return Err("material: hidden must be in [1, 1024], hidden_layers in [1, 32]".into());
        }
        let e = &self.emission;
        if !(1..=1024).contains(&e.width) || !(1..=32).contains(&e.depth) || e.freqs > 32 {
            return Err(
                "emission: width must be in [1, 1024], depth in [1, 32], freqs at most 32".into(),
            );
        }
        if self.parts > 1 << 20 {
            return Err("parts: at most 2^20".into());
        }
        let b = &self.scene_box;
        if !(b.min.is_finite() && b.max.is_finite() && b.min < b.max) {
            return Err("scene_box: min and max must be finite, min < max".into());
        }
        Ok(())
    }
}

/// The two fields of Eq. 14 and the scene box.
#[derive(Clone)]
pub struct FiptModel {
    pub spec: ModelSpec,
    pub grid: HashGrid,
    pub nets: Nets,
    /// The triangle → row map of the part offsets (`spec.parts` parts; empty without them).
    pub part_map: PartMap,
    /// The table resident on the device (`hashgrid_device`), when the model was fitted or is
    /// queried there; `grid.table` then holds its last host copy (`sync_host_table`).
    pub device_grid: Option<GridTables>,
    /// The device the networks live on (an autodiff device while training).
    pub device: Device,
}

/// Host-side material values: base colour (3 per point), roughness and metallic (1 per point).
#[derive(Clone, Debug, Default)]
pub struct MaterialValues {
    pub a: Vec<f32>,
    pub sigma: Vec<f32>,
    pub metallic: Vec<f32>,
}

/// Points per inference batch.
const INFER_CHUNK: usize = 1 << 16;

fn tensor2(v: Vec<f32>, shape: [usize; 2], dev: &Device) -> Tensor<2> {
    Tensor::from_data(TensorData::new(v, shape), dev)
}

/// Model files inside a model folder.
const NETS_FILE: &str = "fields.bpk";
const GRID_FILE: &str = "hashgrid.bin";
const GRID_FILE_F16: &str = "hashgrid.f16";
/// The part offsets' triangle → row map (`PartMap::to_bytes`), where the model has them.
const PARTS_FILE: &str = "parts.bin";

/// How `save` stores the hash table.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum TableFormat {
    /// Raw little-endian f32 (`hashgrid.bin`): exact.
    F32,
    /// Little-endian IEEE half (`hashgrid.f16`), as tiny-cuda-nn keeps the table on the GPU:
    /// half the size; the entries are small feature values (|x| ≲ 1), where half's 11-bit
    /// mantissa leaves a relative error ≤ 2^-11.
    F16,
}
const SPEC_FILE: &str = "model.json";

impl FiptModel {
    /// A fresh model on `device`, every parameter initialised on the host from `seed` (so a
    /// seed gives the same model on every backend).
    /// With `spec.parts` > 0 the part offsets start at zero and `part_map` is empty (every
    /// triangle reads no offset) until the caller sets it.
    pub fn init(spec: ModelSpec, device: &Device, seed: u64) -> Self {
        let field = spec.material.init(device, seed);
        let emission = spec.emission.init(device, seed);
        let part_offsets =
            (spec.parts > 0).then(|| PartOffsets::zeros(spec.parts, spec.part_columns, device));
        let part_map = PartMap {
            tri_row: Vec::new(),
            parts: spec.parts,
        };
        Self {
            spec,
            grid: field.grid,
            nets: Nets {
                material: field.mlp,
                emission,
                part_offsets,
            },
            part_map,
            device_grid: None,
            device: device.clone(),
        }
    }

    /// Uploads the table onto the networks' device, so that queries encode there
    /// (`hashgrid_device`) instead of on the host. For inference, or for a `Trainer` on the
    /// device path (which trains this copy); a host-path trainer trains `grid.table` and drops
    /// a device copy when it is built.
    pub fn upload_table(&mut self) {
        self.device_grid = Some(GridTables::from_host(&self.grid, &self.device));
    }

    /// Copies a device-resident table into `grid.table`.
    pub fn sync_host_table(&mut self) {
        if let Some(t) = &self.device_grid {
            self.grid.table = t.to_host();
        }
    }

    /// The table in the host layout, from the device if it lives there.
    pub fn current_table(&self) -> Vec<f32> {
        match &self.device_grid {
            Some(t) => t.to_host(),
            None => self.grid.table.clone(),
        }
    }

    /// The material field at unit-cube points (inference, batched, no autodiff), each point
    /// with the part offset of its row (`PartMap::rows`; `rows` empty: no offsets). The encoding
    /// runs on the device when the table is there (`device_grid`), else on the host.
    pub fn material(&self, x_unit: &[[f32; 3]], rows: &[u32]) -> MaterialValues {
        assert!(
            rows.is_empty() || rows.len() == x_unit.len(),
            "one part row per point"
        );
        let mlp = self.nets.material.valid();
        let offsets = match &self.nets.part_offsets {
            Some(po) if !rows.is_empty() => Some(po.valid()),
            _ => None,
        };
        let tables = self.device_grid.as_ref().map(|t| t.valid());
        let dev = self.inference_device();
        let mut out = MaterialValues::default();
        // On the device, larger batches (fewer launches; the gathers are chunked anyway).
        let chunk_len = if tables.is_some() {
            4 * INFER_CHUNK
        } else {
            INFER_CHUNK
        };
        for (k, chunk) in x_unit.chunks(chunk_len).enumerate() {
            let n = chunk.len();
            let enc = match &tables {
                Some(t) => {
                    let x = tensor2(chunk.iter().flatten().copied().collect(), [n, 3], &dev);
                    hashgrid_device::encode(&self.grid.levels, t, x)
                }
                None => tensor2(self.grid.encode(chunk), [n, self.grid.output_dim()], &dev),
            };
            let mut raw = mlp.forward(enc);
            if let Some(po) = &offsets {
                let r: Vec<i64> = rows[k * chunk_len..k * chunk_len + n]
                    .iter()
                    .map(|&r| r as i64)
                    .collect();
                raw = po.forward(raw, super::gather::index_tensor(&r, &dev));
            }
            let m = decode_material(raw);
            out.a.extend(m.a.try_into_vec_as::<f32>().expect("f32"));
            out.sigma
                .extend(m.sigma.try_into_vec_as::<f32>().expect("f32"));
            out.metallic
                .extend(m.metallic.try_into_vec_as::<f32>().expect("f32"));
        }
        out
    }

    /// Every network parameter in module order, as host vectors.
    pub fn net_params(&self) -> Vec<Vec<f32>> {
        struct Values(Vec<Vec<f32>>);
        impl ModuleVisitor for Values {
            fn visit_float<const D: usize>(&mut self, param: &Param<Tensor<D>>) {
                self.0
                    .push(param.val().try_into_vec_as::<f32>().expect("f32 parameter"));
            }
        }
        let mut v = Values(Vec::new());
        self.nets.visit(&mut v);
        v.0
    }

    /// The material field at world points on triangles `tris` of the mesh (`tris` empty: no
    /// part offsets).
    pub fn material_world(&self, x_world: &[glam::Vec3], tris: &[u32]) -> MaterialValues {
        let sb = self.spec.scene_box;
        let xs: Vec<[f32; 3]> = x_world.iter().map(|&p| sb.to_unit(p).to_array()).collect();
        self.material(&xs, &self.part_rows(tris))
    }

    /// The part-offset row of each triangle of `tris` (empty without part offsets).
    pub fn part_rows(&self, tris: &[u32]) -> Vec<u32> {
        if self.nets.part_offsets.is_none() {
            return Vec::new();
        }
        self.part_map.rows(tris)
    }

    /// The emission mask α at world points (inference, batched).
    pub fn alpha(&self, x_world: &[[f32; 3]]) -> Vec<f32> {
        let mask = self.nets.emission.valid();
        let dev = self.inference_device();
        let mut out = Vec::with_capacity(x_world.len());
        for chunk in x_world.chunks(INFER_CHUNK) {
            let x = tensor2(
                chunk.iter().flatten().copied().collect(),
                [chunk.len(), 3],
                &dev,
            );
            out.extend(
                alpha_from_raw(mask.raw(x))
                    .try_into_vec_as::<f32>()
                    .expect("f32"),
            );
        }
        out
    }

    /// The plain (non-autodiff) device of the networks.
    fn inference_device(&self) -> Device {
        self.device.clone().without_autodiff()
    }

    /// Saves the model into `dir`: `model.json` (configs and scene box), the networks as a burn
    /// record (`fields.bpk`), the hash table (`hashgrid.bin` as f32 or `hashgrid.f16`) and,
    /// with part offsets, their triangle map (`parts.bin`), each written to a temporary name
    /// first.
    pub fn save(&self, dir: &Path, format: TableFormat) -> Result<(), String> {
        std::fs::create_dir_all(dir).map_err(|e| format!("{}: {e}", dir.display()))?;
        let spec = serde_json::to_string_pretty(&self.spec).map_err(|e| e.to_string())?;
        crate::io::write_bytes_atomic(&dir.join(SPEC_FILE), spec.as_bytes())
            .map_err(|e| e.to_string())?;
        let tmp = dir.join("fields.tmp.bpk");
        self.nets
            .clone()
            .save_file(&tmp)
            .map_err(|e| format!("{}: {e:?}", tmp.display()))?;
        std::fs::rename(&tmp, dir.join(NETS_FILE)).map_err(|e| e.to_string())?;
        if self.spec.parts > 0 {
            crate::io::write_bytes_atomic(&dir.join(PARTS_FILE), &self.part_map.to_bytes())
                .map_err(|e| e.to_string())?;
        } else {
            let _ = std::fs::remove_file(dir.join(PARTS_FILE));
        }
        // Only one table file: a stale one of the other format would be ambiguous.
        let (name, other) = match format {
            TableFormat::F32 => (GRID_FILE, GRID_FILE_F16),
            TableFormat::F16 => (GRID_FILE_F16, GRID_FILE),
        };
        let _ = std::fs::remove_file(dir.join(other));
        let path = dir.join(name);
        let device_table = self.device_grid.as_ref().map(|t| t.to_host());
        let table = device_table.as_deref().unwrap_or(&self.grid.table);
        match format {
            TableFormat::F32 => {
                crate::io::write_parts_atomic(&path, &[crate::io::Part::F32s(table)])
            }
            TableFormat::F16 => {
                let bytes: Vec<u8> = table
                    .iter()
                    .flat_map(|&x| half::f16::from_f32(x).to_le_bytes())
                    .collect();
                crate::io::write_bytes_atomic(&path, &bytes)
            }
        }
        .map_err(|e| e.to_string())
    }

    /// Loads a model saved by `save` onto `device`. Errors name the file and the problem
    /// (missing, malformed, or sizes that do not match `model.json`).
    pub fn load(dir: &Path, device: &Device) -> Result<Self, String> {
        let spec_path = dir.join(SPEC_FILE);
        let text = std::fs::read_to_string(&spec_path)
            .map_err(|e| format!("{}: cannot read: {e}", spec_path.display()))?;
        let spec: ModelSpec = serde_json::from_str(&text)
            .map_err(|e| format!("{}: malformed: {e}", spec_path.display()))?;
        spec.check()
            .map_err(|e| format!("{}: {e}", spec_path.display()))?;
        let mut model = Self::init(spec, device, 0);
        let nets_path = dir.join(NETS_FILE);
        if !nets_path.is_file() {
            return Err(format!("{}: missing", nets_path.display()));
        }
        model.nets = model
            .nets
            .try_load_file(&nets_path)
            .map_err(|e| format!("{}: cannot load the networks: {e:?}", nets_path.display()))?;
        let (grid_path, width) = if dir.join(GRID_FILE_F16).is_file() {
            (dir.join(GRID_FILE_F16), 2)
        } else {
            (dir.join(GRID_FILE), 4)
        };
        let len = std::fs::metadata(&grid_path)
            .map_err(|e| format!("{}: cannot read: {e}", grid_path.display()))?
            .len();
        let want = (model.grid.table.len() * width) as u64;
        if len != want {
            return Err(format!(
                "{}: {len} bytes, but the grid of model.json needs {want}",
                grid_path.display()
            ));
        }
        let bytes = std::fs::read(&grid_path)
            .map_err(|e| format!("{}: cannot read: {e}", grid_path.display()))?;
        let table = &mut model.grid.table;
        if width == 2 {
            for (v, b) in table.iter_mut().zip(bytes.chunks_exact(2)) {
                *v = half::f16::from_le_bytes([b[0], b[1]]).to_f32();
            }
        } else {
            for (v, b) in table.iter_mut().zip(bytes.chunks_exact(4)) {
                *v = f32::from_le_bytes(b.try_into().expect("4 bytes"));
            }
        }
        if let Some(i) = table.iter().position(|v| !v.is_finite()) {
            return Err(format!("{}: entry {i} is not finite", grid_path.display()));
        }
        if model.spec.parts > 0 {
            let path = dir.join(PARTS_FILE);
            let bytes = std::fs::read(&path)
                .map_err(|e| format!("{}: cannot read: {e}", path.display()))?;
            model.part_map = PartMap::from_bytes(&bytes, model.spec.parts)
                .map_err(|e| format!("{}: {e}", path.display()))?;
        }
        Ok(model)
    }
}
