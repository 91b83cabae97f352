//! The training objective (paper Eq. 15–20) on a step's network outputs: the factorised
//! render composited with the emission mask against the photo, the emission and diffuse priors
//! (with the logit bound and the σ pull where set) and the segmentation loss.
//!
//! Owns: which losses a step adds up, and their order. Must not touch: where the network
//! outputs come from (`paths`), the optimisers.

use super::batch::{Pixels, compact_ids};
use super::config::SegMode;
use super::copies::{download, upload2};
use super::trainer::Trainer;
use crate::model::brdf::reflectances;
use crate::model::fields::{alpha_from_raw, decode_material, sigma_metallic_logits};
use crate::model::loss;
use crate::model::render::{Shadings, composite, render};
use crate::model::transfer;
use crate::rng::Rng;
use burn::tensor::{Device, Tensor};

impl Trainer {
    /// The loss of the networks' raw outputs `raw_mat` (material) and `raw` (emission mask) on
    /// the step's pixels: the total, and the parts `[total, color, emission, diffuse, seg]`
    /// detached.
    pub(super) fn objective(
        &mut self,
        px: &Pixels,
        mode: SegMode,
        raw_mat: Tensor<2>,
        raw: Tensor<2>,
    ) -> (Tensor<1>, Tensor<1>) {
        let dev = self.device.clone();
        let raw_mat = match (&self.model.nets.part_offsets, &px.t.part) {
            (Some(po), Some(rows)) => po.forward(raw_mat, rows.clone()),
            _ => raw_mat,
        };
        let mat = decode_material(raw_mat.clone());
        let (kd, ks) = reflectances(mat.a.clone(), mat.metallic.clone());
        let sh = Shadings::from_packed(px.t.shadings.clone());
        let (pred, spec) = render(kd, ks, mat.sigma.clone(), &sh);
        let alpha = alpha_from_raw(raw.clone());
        let c = composite(pred, alpha, px.t.gt.clone());
        let lc = match &px.t.cap {
            None => loss::color_loss(c, px.t.gt.clone()),
            Some(cap) => loss::color_loss(loss::clip_to(c, cap.clone()), px.t.gt.clone()),
        };
        let le = loss::emission_loss(raw, self.cfg.lambda_e);
        // Eq. 17's m term with one s for every pixel, or s per segment (mean of s·m).
        let (metallic, scale) = if self.metallic_scales.is_empty() {
            (mat.metallic.clone(), self.cfg.metallic_scale)
        } else {
            let s = per_segment(px, &dev, "per-segment m weights", |k| {
                self.metallic_scales
                    .get(&k)
                    .copied()
                    .unwrap_or(self.cfg.metallic_scale)
            });
            (mat.metallic.clone() * s, 1.0)
        };
        let mut ld = loss::diffuse_loss(
            mat.sigma.clone(),
            metallic,
            self.cfg.lambda_d,
            scale,
            self.cfg.prior_sigma,
        );
        if let Some(z_max) = self.cfg.logit_bound {
            // Reported with the prior it bounds (the loss parts keep their five slots).
            let z = sigma_metallic_logits(raw_mat);
            ld = ld + loss::logit_bound_loss(z, z_max, self.cfg.lambda_logit);
        }
        for pull in [&self.pull, &self.anchor].into_iter().flatten() {
            // Each pulled segment's target, with weight 1; other segments' pixels weigh 0.
            let targets = |of: &std::collections::HashMap<i32, f32>| {
                let what = "the σ pull";
                (
                    per_segment(px, &dev, what, |k| of.get(&k).copied().unwrap_or(0.0)),
                    per_segment(
                        px,
                        &dev,
                        what,
                        |k| if of.contains_key(&k) { 1.0 } else { 0.0 },
                    ),
                )
            };
            let (t, w) = targets(&pull.target);
            ld = ld + loss::sigma_pull_loss(mat.sigma.clone(), t, w, pull.weight);
            if !pull.metallic.is_empty() {
                let (t, w) = targets(&pull.metallic);
                ld = ld + loss::sigma_pull_loss(mat.metallic.clone(), t, w, pull.weight);
            }
        }
        let lseg = self.seg_loss(px, mode, &mat, spec);
        let total = lc.clone() + le.clone() + ld.clone() + lseg.clone();
        let parts = Tensor::cat(vec![total.clone(), lc, le, ld, lseg], 0).detach();
        (total, parts)
    }

    fn seg_loss(
        &mut self,
        px: &Pixels,
        mode: SegMode,
        mat: &crate::model::fields::Material,
        spec: Tensor<2>,
    ) -> Tensor<1> {
        let dev = self.device.clone();
        match mode {
            SegMode::None => Tensor::<1>::zeros([1], &dev),
            SegMode::Part => loss::part_loss(
                mat.sigma.clone(),
                mat.metallic.clone(),
                spec,
                px.t.seg.clone(),
                px.t.n_seg,
                self.cfg.lambda_part,
            ),
            SegMode::Semantic => {
                // Partner draws and bilateral weights on the host: the batch's labels and
                // positions come from the host batch, the base colour is read back.
                let b = px.host.expect(
                    "the semantic loss needs the batch on the host (StepInput::Device { host })",
                );
                let (compact, n_labels) = compact_ids(&b.seg);
                let labels: Vec<i32> = compact.iter().map(|&k| k as i32).collect();
                let pairs = loss::semantic_pairs(
                    &labels,
                    self.cfg.sem_partners,
                    &mut Rng::new(self.seed ^ 0x5e9, self.steps),
                );
                let pos: Vec<f32> = b.x_unit.iter().flatten().map(|v| 2.0 * v - 1.0).collect();
                let a = download(mat.a.clone());
                let w = loss::semantic_weights(
                    &pairs,
                    &a,
                    &pos,
                    self.cfg.sem_sigma_a,
                    self.cfg.sem_sigma_p,
                );
                // The partner indices are counted where they are uploaded (`index_tensor`).
                transfer::upload(w.len() * 4);
                loss::semantic_loss(
                    mat.sigma.clone(),
                    mat.metallic.clone(),
                    &pairs,
                    &w,
                    &compact,
                    n_labels,
                    self.cfg.lambda_sem,
                )
            }
        }
    }
}

/// One value per pixel of the step, [N, 1] on `dev`, from each pixel's segment label
/// (`Batch::seg` of the host batch, which `what` needs): the per-segment weights and targets of
/// the m prior and the σ pulls.
fn per_segment(px: &Pixels, dev: &Device, what: &str, value: impl Fn(i32) -> f32) -> Tensor<2> {
    let b = px.host.unwrap_or_else(|| {
        panic!("{what} needs the batch on the host (StepInput::Device {{ host }})")
    });
    let v: Vec<f32> = b.seg.iter().map(|&k| value(k)).collect();
    upload2(v, [b.seg.len(), 1], dev)
}
