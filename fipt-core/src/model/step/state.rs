//! Checkpoints of the fit: `Trainer::save_state` writes everything a fit needs to continue
//! into a folder, and `Trainer::restore` continues from it exactly.
//!
//! Owns: the checkpoint's trainer files (names and contents). Must not touch: the model's own
//! files (`FiptModel::save`), the step.

use super::config::TrainConfig;
use super::trainer::{GridOpt, Trainer};
use crate::model::fipt_model::{FiptModel, TableFormat};
use crate::model::hashgrid_device::GridTables;
use burn::module::Module;
use burn::tensor::Device;
use std::path::Path;

const OPTIM_FILE: &str = "optim.bpk";
const TABLE_ADAM_FILE: &str = "table_adam.bin";
/// The device path's table (a burn record, which keeps the parameter ids its Adam state refers
/// to) and that Adam state.
const GRID_TABLES_FILE: &str = "grid_tables.bpk";
const GRID_OPTIM_FILE: &str = "grid_optim.bpk";
const TRAINER_FILE: &str = "trainer.json";

impl Trainer {
    /// Writes the whole state of the fit between two steps into `dir` (a checkpoint): the model
    /// with its f32 table (`FiptModel::save`), burn's Adam state of the networks (`optim.bpk`),
    /// and the table's optimiser state: the host path's moments (`table_adam.bin`), or the
    /// device path's table record and burn Adam state (`grid_tables.bpk`, `grid_optim.bpk`);
    /// and the step count (`trainer.json`). Each file goes through a temporary name; the caller
    /// makes the folder appear atomically.
    pub fn save_state(&self, dir: &Path) -> Result<(), String> {
        self.model.save(dir, TableFormat::F32)?;
        let record_bytes = |r: burn::optim::OptimizerRecord, name: &str| {
            r.into_bytes()
                .map_err(|e| format!("{}: {e:?}", dir.join(name).display()))
        };
        let optim = record_bytes(self.optim.to_record(), OPTIM_FILE)?;
        crate::io::write_bytes_atomic(&dir.join(OPTIM_FILE), &optim).map_err(|e| e.to_string())?;
        match &self.grid_opt {
            GridOpt::Host { adam, .. } => adam
                .save(&dir.join(TABLE_ADAM_FILE))
                .map_err(|e| e.to_string())?,
            GridOpt::Device { optim } => {
                let tables = self.model.device_grid.as_ref().expect("device table");
                let tmp = dir.join("grid_tables.tmp.bpk");
                tables
                    .clone()
                    .save_file(&tmp)
                    .map_err(|e| format!("{}: {e:?}", tmp.display()))?;
                std::fs::rename(&tmp, dir.join(GRID_TABLES_FILE)).map_err(|e| e.to_string())?;
                let bytes = record_bytes(optim.to_record(), GRID_OPTIM_FILE)?;
                crate::io::write_bytes_atomic(&dir.join(GRID_OPTIM_FILE), &bytes)
                    .map_err(|e| e.to_string())?;
            }
        }
        let state = serde_json::json!({ "steps": self.steps });
        crate::io::write_bytes_atomic(&dir.join(TRAINER_FILE), state.to_string().as_bytes())
            .map_err(|e| e.to_string())
    }

    /// The trainer `save_state` wrote into `dir`, on `device` (plain; autodiff is added here),
    /// continuing exactly where it stopped: the next `step` gives what the uninterrupted fit's
    /// would. `cfg` and `seed` must be the fit's own; a model of another shape is refused.
    pub fn restore(
        cfg: TrainConfig,
        device: &Device,
        seed: u64,
        dir: &Path,
    ) -> Result<Self, String> {
        let ad = device.clone().autodiff();
        let mut model = FiptModel::load(dir, &ad)?;
        let same = |a: serde_json::Result<serde_json::Value>,
                    b: serde_json::Result<serde_json::Value>| {
            matches!((a, b), (Ok(a), Ok(b)) if a == b)
        };
        if !same(
            serde_json::to_value(&model.spec.material),
            serde_json::to_value(&cfg.material),
        ) || !same(
            serde_json::to_value(&model.spec.emission),
            serde_json::to_value(&cfg.emission),
        ) {
            return Err(format!(
                "{}: the checkpoint's networks differ from the config's",
                dir.join("model.json").display()
            ));
        }
        let load_record = |name: &str| -> Result<burn::optim::OptimizerRecord, String> {
            let path = dir.join(name);
            if !path.is_file() {
                return Err(format!("{}: missing", path.display()));
            }
            burn::optim::OptimizerRecord::load(&path)
                .map_err(|e| format!("{}: cannot read: {e:?}", path.display()))
        };
        let record = load_record(OPTIM_FILE)?;
        let state_path = dir.join(TRAINER_FILE);
        let text = crate::io::read_text(&state_path).map_err(|e| e.to_string())?;
        let steps = serde_json::from_str::<serde_json::Value>(&text)
            .ok()
            .and_then(|v| v.get("steps")?.as_u64())
            .ok_or_else(|| format!("{}: no step count", state_path.display()))?;
        let grid_record = if cfg.device_grid {
            let path = dir.join(GRID_TABLES_FILE);
            if !path.is_file() {
                return Err(format!("{}: missing", path.display()));
            }
            let tables = GridTables::from_host(&model.grid, &ad)
                .try_load_file(&path)
                .map_err(|e| format!("{}: cannot load the table: {e:?}", path.display()))?;
            if tables.to_host() != model.grid.table {
                return Err(format!(
                    "{}: differs from the checkpoint's hashgrid.bin",
                    path.display()
                ));
            }
            model.device_grid = Some(tables);
            Some(load_record(GRID_OPTIM_FILE)?)
        } else {
            None
        };
        let mut t = Self::assemble(cfg, ad, model, seed, Some(record), grid_record);
        if let GridOpt::Host { adam, .. } = &mut t.grid_opt {
            let adam_path = dir.join(TABLE_ADAM_FILE);
            let bytes = crate::io::read_bytes(&adam_path).map_err(|e| e.to_string())?;
            adam.load_bytes(&bytes)
                .map_err(|e| format!("{}: {e}", adam_path.display()))?;
        }
        t.steps = steps;
        Ok(t)
    }
}
