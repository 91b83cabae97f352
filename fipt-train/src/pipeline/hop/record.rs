//! What a hop records in `metrics.json` (`rounds[r].hop`): its candidates, every segment's
//! check, and whether each of its hops was kept.
//!
//! Owns: the record types. Must not touch: how they are computed.

use serde::{Deserialize, Serialize};

/// A segment the sweep sent hopping.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct HopCandidate {
    /// Segment id (part or semantic label).
    pub segment: i32,
    /// Its pixels in the store.
    pub pixels: usize,
    /// Mean fitted σ before the hop, the target, and the mean σ after it.
    pub sigma: f64,
    pub target: f64,
    pub sigma_after: f64,
    /// Which hypothesis proposed the target (`Hypothesis`).
    #[serde(default)]
    pub source: Hypothesis,
    /// Mean fitted m before the hop, its target (None: m is not pulled) and after it.
    #[serde(default)]
    pub metallic: f64,
    #[serde(default)]
    pub target_metallic: Option<f64>,
    #[serde(default)]
    pub metallic_after: f64,
    /// The segment's objective at the fit, at the target σ (fitted a and m) and after the hop.
    pub objective: f64,
    pub objective_target: f64,
    pub objective_after: f64,
    /// A metal hypothesis whose one colour scores within `gain` of the fit
    /// (`train.hop.plain_metal`). In the plain metals' own hop, `objective_after` is the
    /// hopped segment's objective at one colour per segment.
    #[serde(default)]
    pub plain: bool,
    /// This record is the plain metal's second hop, alone, after the first was undone (kept
    /// or undone by `HopReport::plain_accepted`).
    #[serde(default)]
    pub alone: bool,
}

/// A segment at the hop's check: its mean fitted σ and objective, the sweep's best σ and
/// objective there, and its objective after the hop (None where none ran).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct SegmentObjective {
    pub segment: i32,
    pub pixels: usize,
    pub sigma: f64,
    pub before: f64,
    pub best_sigma: f64,
    pub best: f64,
    pub after: Option<f64>,
    /// Mean σ and m after the hop (the model kept).
    #[serde(default)]
    pub sigma_after: Option<f64>,
    #[serde(default)]
    pub metallic_after: Option<f64>,
    /// Mean fitted m.
    #[serde(default)]
    pub metallic: f64,
    /// The metal hypothesis's best σ and objective, and the objective of one colour per
    /// segment at the fitted mean σ and m, which it is measured against (`train.hop.metal`;
    /// None: not tried).
    #[serde(default)]
    pub metal: Option<(f64, f64, f64)>,
    /// The last round's material on this segment under these shadings: its mean σ and m, and
    /// its objective (`train.hop.carry`; None: round 0, or off).
    #[serde(default)]
    pub carried: Option<(f64, f64, f64)>,
    /// With the base colour solved per patch over all the segment's pixels
    /// (`train.hop.patch`), at one common σ as a dielectric (as a metal for a segment fitted
    /// metallic, with `train.hop.patch_metals`): the best swept σ, the objective there, and the
    /// objective at the fitted mean σ (None: not tried).
    #[serde(default)]
    pub patch: Option<(f64, f64, f64)>,
    /// How many of the patch hypothesis's cubes prefer its best σ to the fitted mean σ
    /// (`patches::preference`): the share of the segment's pixels in those cubes, and the
    /// effective number of cubes (None: not tried).
    #[serde(default)]
    pub patch_share: Option<(f64, f64)>,
    /// The σ the anchor held it at in place of its fitted one, with m 0 (`train.hop.settle`;
    /// None: its fitted σ and m, or not held).
    #[serde(default)]
    pub settled: Option<f64>,
}

/// What proposed a hop's target.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Hypothesis {
    /// The sweep over σ at the fitted base colour (scaled) and metallic.
    #[default]
    Sweep,
    /// The sweep over σ of a metal (m = 1) with one base colour per segment.
    Metal,
    /// The last round's material (σ and m) on the segment.
    Carried,
    /// The sweep over σ with the base colour solved per surface patch (`patches`).
    Patch,
}

/// What a hop did: the candidates, whether the hopped model was kept (the candidates'
/// size-weighted objective fell by `gain`), and for the record every segment's check and the whole
/// objective (every segment, size-weighted) before and after.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct HopReport {
    pub candidates: Vec<HopCandidate>,
    #[serde(default)]
    pub segments: Vec<SegmentObjective>,
    pub objective_before: f64,
    pub objective_after: Option<f64>,
    pub accepted: bool,
    /// Whether the plain metals' hop, run after an undone first hop, was kept (None: none
    /// ran; `train.hop.plain_metal`).
    #[serde(default)]
    pub plain_accepted: Option<bool>,
    /// Whether the patch candidates' hop, run after the others, was kept (None: none ran).
    #[serde(default)]
    pub patch_accepted: Option<bool>,
    /// Steps run (both phases of each hop).
    pub steps: usize,
    /// The λ_d the objectives above hold (`prior` × the fit's final λ_d; 0: the data term).
    #[serde(default)]
    pub lambda_d: f64,
    /// The segments a kept hop harmed, held where they were on its second try
    /// (`train.hop.guard`).
    #[serde(default)]
    pub guarded: Vec<i32>,
}
