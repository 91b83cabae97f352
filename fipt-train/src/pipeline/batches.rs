//! The batches of a fit (and of the basin hop's steps): which pixels each step sees, drawn
//! by a seeded sampler whose state is saved with the fit, and one step on them.
//!
//! Owns: the sampler, the batch shape, the step on a batch. Must not touch: the schedule's
//! rates, the model maths.

use super::pixels::PixelStore;
use crate::config::TrainSection;
use fipt_core::model::Trainer;
use fipt_core::model::step::{DeviceStore, SegMode, StepInput, StepLoss};
use fipt_core::rng::Rng;

/// Draws batch indices: shuffled epochs over all pixels, and the balanced share by segment.
#[derive(Clone, Debug)]
pub(super) struct Sampler {
    rng: Rng,
    /// The current permutation of all pixels (each epoch shuffles the last one further).
    order: Vec<u32>,
    /// Position in `order`; past its end, the next draw shuffles first.
    next: usize,
    /// Pixel indices of each segment (derived from the store, not saved).
    segments: Vec<Vec<u32>>,
}

const SAMPLER_MAGIC: &[u8; 8] = b"FIPTSMP1";

impl Sampler {
    pub(super) fn new(store: &PixelStore, seed: u64, balanced: bool) -> Self {
        Self {
            rng: Rng::new(seed, 0x7a1),
            order: (0..store.len() as u32).collect(),
            next: usize::MAX,
            segments: Self::segments_of(store, balanced),
        }
    }

    /// Pixel indices of each segment, in segment-id order (none unless `balanced`).
    pub(super) fn segments_of(store: &PixelStore, balanced: bool) -> Vec<Vec<u32>> {
        if !balanced {
            return Vec::new();
        }
        let mut by: std::collections::BTreeMap<i32, Vec<u32>> = Default::default();
        for (i, &s) in store.pixels.seg.iter().enumerate() {
            by.entry(s).or_default().push(i as u32);
        }
        by.into_values().collect()
    }

    /// `uniform` pixels in epoch order (a new permutation whenever one is used up), then
    /// `balanced` pixels drawn segment-first.
    pub(super) fn draw(&mut self, uniform: usize, balanced: usize, out: &mut Vec<u32>) {
        out.clear();
        while out.len() < uniform {
            if self.next >= self.order.len() {
                self.rng.shuffle(&mut self.order);
                self.next = 0;
            }
            let take = (uniform - out.len()).min(self.order.len() - self.next);
            out.extend_from_slice(&self.order[self.next..self.next + take]);
            self.next += take;
        }
        if !self.segments.is_empty() {
            for _ in 0..balanced {
                let s = &self.segments[self.rng.below(self.segments.len() as u64) as usize];
                out.push(s[self.rng.below(s.len() as u64) as usize]);
            }
        }
    }

    /// The saved state: magic, RNG state, position, order length, the order (little-endian).
    pub(super) fn to_bytes(&self) -> Vec<u8> {
        let mut b = Vec::with_capacity(32 + 4 * self.order.len());
        b.extend_from_slice(SAMPLER_MAGIC);
        b.extend_from_slice(&self.rng.state().to_le_bytes());
        b.extend_from_slice(&(self.next as u64).to_le_bytes());
        b.extend_from_slice(&(self.order.len() as u64).to_le_bytes());
        for i in &self.order {
            b.extend_from_slice(&i.to_le_bytes());
        }
        b
    }

    /// The sampler `to_bytes` saved, for `store`; the reason when the bytes are not one (wrong
    /// magic, size, length, or an order that is not a permutation).
    pub(super) fn from_bytes(b: &[u8], store: &PixelStore, balanced: bool) -> Result<Self, String> {
        if b.len() < 32 || &b[..8] != SAMPLER_MAGIC {
            return Err("not a fipt sampler state".into());
        }
        let word = |i: usize| u64::from_le_bytes(b[8 + 8 * i..16 + 8 * i].try_into().unwrap());
        let (state, next, n) = (word(0), word(1), word(2));
        if n != store.len() as u64 || b.len() as u64 != 32 + 4 * n {
            return Err(format!(
                "holds {n} pixels in {} bytes, the fit has {}",
                b.len(),
                store.len()
            ));
        }
        let order: Vec<u32> = b[32..]
            .chunks_exact(4)
            .map(|c| u32::from_le_bytes(c.try_into().unwrap()))
            .collect();
        let mut seen = vec![false; order.len()];
        for &i in &order {
            match seen.get_mut(i as usize) {
                Some(s) if !*s => *s = true,
                _ => return Err("the pixel order is not a permutation".into()),
            }
        }
        let next = if next == u64::MAX {
            usize::MAX
        } else if next <= n {
            next as usize
        } else {
            return Err(format!("position {next} past the {n} pixels"));
        };
        Ok(Self {
            rng: Rng::from_state(state),
            order,
            next,
            segments: Self::segments_of(store, balanced),
        })
    }
}

/// The batch sizes and step counts of a fit over a store (also the basin hop's batches).
pub(super) struct Shape {
    pub(super) batch: usize,
    pub(super) balanced: usize,
    pub(super) steps: usize,
    pub(super) steps_per_epoch: usize,
}

impl Shape {
    pub(super) fn of(store: &PixelStore, mode: SegMode, schedule: &TrainSection) -> Self {
        let batch = schedule.batch.min(store.len()).max(1);
        let balanced = ((schedule.balance.clamp(0.0, 1.0) * batch as f32).round() as usize)
            .min(batch)
            * usize::from(mode != SegMode::None);
        Self {
            batch,
            balanced,
            steps: schedule.steps(store.len()),
            steps_per_epoch: store.len().div_ceil(batch).max(1),
        }
    }
}

/// One step on the entries `idx` of `store`: by index from its device copy `ds` when the grid
/// lives on the device (the loss left there; the semantic loss also gets the host batch), else
/// as a host batch.
pub fn step_entries(
    tr: &mut Trainer,
    ds: Option<&DeviceStore>,
    store: &PixelStore,
    idx: &[u32],
    mode: SegMode,
) -> StepLoss {
    match ds {
        Some(ds) => {
            // The semantic loss, a σ pull or anchor and per-segment m weights read the batch's
            // labels on the host.
            let host = (mode == SegMode::Semantic
                || tr.pull.is_some()
                || tr.anchor.is_some()
                || !tr.metallic_scales.is_empty())
            .then(|| store.batch(idx));
            let input = StepInput::Device {
                store: ds,
                idx,
                host: host.as_ref(),
            };
            tr.step_on(input, mode)
        }
        None => StepLoss::Ready(tr.step(&store.batch(idx), mode)),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::pipeline::test_data::store;

    /// A step by index from the device store with per-segment m weights set
    /// (`Trainer::metallic_scales`) reads the batch's labels on the host: it gives the diffuse
    /// part of the same entries stepped as a host batch, which the weights change.
    #[test]
    fn device_steps_read_the_labels_for_metallic_scales() {
        use crate::pipeline::test_data::{toy_fit, toy_store};
        let st = toy_store(200);
        let (cfg, _) = toy_fit();
        let make = |device_grid: bool| {
            let cfg = cfg
                .clone()
                .with_device_grid(device_grid)
                .with_metallic_scale(5.0);
            let unit = fipt_core::scene::SceneBox { min: 0.0, max: 1.0 };
            Trainer::new(cfg, unit, &burn::tensor::Device::flex(), 5)
        };
        let (host, mut dev) = (make(false), make(true));
        dev.model.grid.table.clone_from(&host.model.grid.table);
        dev.model.upload_table();
        assert!(dev.device_resident());
        let idx: Vec<u32> = (0..64).collect();
        let diffuse = |mut t: Trainer, ds: Option<&DeviceStore>, spared: bool| {
            if spared {
                t.metallic_scales = [(0, 1.0), (3, 0.0)].into_iter().collect();
            }
            step_entries(&mut t, ds, &st, &idx, SegMode::Part)
                .read()
                .diffuse
        };
        let ds = DeviceStore::upload(&st.pixels, &dev.device);
        let on_host = diffuse(host.clone(), None, true);
        let on_device = diffuse(dev, Some(&ds), true);
        let unweighted = diffuse(host, None, false);
        assert!(
            (on_device - on_host).abs() <= 1e-4 * on_host,
            "{on_device} vs {on_host}"
        );
        assert!(
            (unweighted - on_host).abs() > 1e-2 * on_host,
            "{unweighted} vs {on_host}"
        );
    }

    /// Uniform draws cover every pixel once per epoch; balanced draws give a 1 %-segment the
    /// same share as a 99 %-segment.
    #[test]
    fn sampler_epochs_and_balance() {
        let seg: Vec<i32> = (0..1000).map(|i| if i < 10 { 7 } else { 3 }).collect();
        let st = store(&seg);
        let mut sa = Sampler::new(&st, 1, false);
        let mut seen = vec![0u32; 1000];
        let mut idx = Vec::new();
        for _ in 0..10 {
            sa.draw(100, 0, &mut idx);
            for &i in &idx {
                seen[i as usize] += 1;
            }
        }
        assert!(seen.iter().all(|&c| c == 1));
        let mut sb = Sampler::new(&st, 1, true);
        let mut small = 0;
        for _ in 0..100 {
            sb.draw(0, 100, &mut idx);
            small += idx.iter().filter(|&&i| i < 10).count();
        }
        // Expected 5000 of 10000; uniform sampling would give 100.
        assert!((4700..5300).contains(&small), "{small}");
    }
}
