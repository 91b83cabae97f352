//! Run configuration as data (`configs/*.json`): every key is known, typed and range-checked,
//! and any error names the key (`train.lr: invalid type ...`).
//!
//! Owns: the config schema, its defaults (the reference's constants, except the named
//! departures, each with its page in `docs/departures/`), validation, and the derivation of
//! every seed of a run (`Seeds`). Must not touch: what the stages do with it.

use anyhow::{Context, Result, bail};
use fipt_bake::integrators::bake::BakeConfig;
use fipt_bake::integrators::refine::RefineConfig;
use fipt_core::model::hashgrid::{MaxResolution, ResolutionKeyword};
use fipt_core::model::step::SegMode;
use fipt_core::model::{
    BackendKind, EmissionMaskConfig, HashGridConfig, MaterialFieldConfig, PartColumns, TrainConfig,
};
use serde::{Deserialize, Serialize};
use std::path::Path;

/// The whole pipeline's configuration.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct Config {
    pub seed: u64,
    pub backend: BackendKind,
    pub bake: BakeConfig,
    pub train: TrainSection,
    pub emitters: EmitterSection,
    pub refine: RefineSection,
    pub maps: MapsSection,
    pub render: RenderSection,
    pub checkpoint: CheckpointSection,
    /// What changes for LDR photos (read only when the scene's photos are PNG or JPEG).
    pub ldr: LdrSection,
}

/// Shading refinement and the alternation (paper §4.3; reference §2.5–2.6).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct RefineSection {
    /// Refine-then-fit rounds after round 0 (reference: 2).
    pub rounds: usize,
    /// Each round's fit continues the previous model instead of starting afresh (the
    /// reference re-initialises).
    pub warm_start: bool,
    /// λ_d (Eq. 17) of the fits on refined shadings (None: `train.lambda_d`, the reference).
    pub lambda_d: Option<f32>,
    /// `train.lambda_d_warmup` of the fits on refined shadings (None: the train section's).
    pub lambda_d_warmup: Option<f32>,
    /// Weight of Eq. 17's m term in the fits on refined shadings (None: the same λ_d as its σ
    /// term, the reference).
    pub lambda_m: Option<f32>,
    /// The segments `lambda_m` weighs: all of them, or only those the previous round left
    /// dielectric (`MetalPriorOn`).
    pub lambda_m_on: MetalPriorOn,
    /// The fits on refined shadings (and the refinement's material cache) leave out the pixels
    /// within this many pixels of one that shows an extracted emitter (0: none, the
    /// reference's); `pipeline::pixels::near_emitters`.
    pub emitter_margin: usize,
    /// The fits on refined shadings keep the pixels that show an extracted emitter, composited
    /// with the emission mask (true: the reference's). False leaves them out with the margin
    /// (`pipeline::pixels::on_or_near_emitters`): the emitters are fixed after round 0, and the
    /// composite pulls the material field on their surface towards white, which the field
    /// carries into the surfaces next to them.
    pub emitter_pixels: bool,
    /// The path-traced estimators.
    pub paths: RefineConfig,
}

/// Which segments `refine.lambda_m` weighs in a refined round's fit.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum MetalPriorOn {
    /// Every pixel.
    #[default]
    All,
    /// The pixels of the segments whose mean m the previous round's model left below 0.5; the
    /// others keep the round's λ_d on m, so that a metal found before is not priced out.
    Dielectrics,
}

impl Default for RefineSection {
    /// The reference's two rounds with fresh fits; the estimators with light samples at the
    /// first hit and half the reference's BRDF samples (see `RefineConfig::light_samples`),
    /// emitters emitting from the sides the photos saw (`RefineConfig::observed_sides`).
    fn default() -> Self {
        Self {
            rounds: 2,
            warm_start: false,
            // A weaker diffuse prior on refined shadings (the reference keeps 5e-4);
            // `docs/departures/refine-lambda-d.md`.
            lambda_d: Some(1e-4),
            lambda_d_warmup: None,
            lambda_m: None,
            lambda_m_on: MetalPriorOn::All,
            // The pixels next to the emitters left out (the reference keeps every pixel);
            // `docs/departures/emitter-margin.md`.
            emitter_margin: 1,
            // And the pixels on the emitters (the reference keeps them);
            // `docs/departures/emitter-pixels.md`.
            emitter_pixels: false,
            paths: RefineConfig {
                samples: fipt_bake::integrators::bake::BakeSamples {
                    diffuse: 64,
                    specular: [32; 6],
                },
                light_samples: 32,
                observed_sides: true,
                // L′ without the pixels on and next to the emitters as the refinement's
                // radiance cache (the reference keeps them); `docs/departures/cache-margin.md`.
                cache_margin: 1,
                // L′ from the photos less the last fit's predicted specular before each
                // refinement (the reference keeps the photos); `docs/departures/cache-diffuse.md`.
                cache_diffuse: true,
                // The sharp lobes (levels 0 and 1) left unfiltered, as the bake leaves them
                // (the reference filters all six); `docs/departures/bake-filter.md`.
                filter: fipt_bake::filter::FilterConfig::default(),
                // The pixels of parts seen in fewer than 16384 pixels path-traced again, up to
                // 16 times (the reference traces each once); `docs/departures/small-parts.md`.
                small_parts: 16384,
                // 128 paths on the two sharp levels for the pixels fitted below level 2's σ
                // (the reference gives every pixel 64 a level);
                // `docs/departures/light-samples.md`.
                sharp: Some(fipt_bake::integrators::refine::SharpSamples {
                    below: 0.412,
                    specular: [128, 128, 32, 32, 32, 32],
                }),
                ..RefineConfig::default()
            },
        }
    }
}

impl Default for Config {
    fn default() -> Self {
        Self {
            seed: 0,
            backend: BackendKind::DEFAULT,
            bake: BakeConfig::default(),
            train: TrainSection::default(),
            emitters: EmitterSection::default(),
            refine: RefineSection::default(),
            maps: MapsSection::default(),
            render: RenderSection::default(),
            checkpoint: CheckpointSection::default(),
            ldr: LdrSection::default(),
        }
    }
}

/// LDR photos (`crate::ldr`, `docs/ldr.md`).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct LdrSection {
    /// Estimate the exposure of frames whose capture does not give one (false: all 1).
    pub estimate_exposure: bool,
    /// Solve the radiance of clipped emitters from the pixels they light (false: keep the clip
    /// level, IRIS's extraction before its optimisation).
    pub solve_emitters: bool,
    /// Estimate the camera response (one γ on the sRGB curve) from the pixels on the
    /// occluding contours between surfaces (`crate::ldr::edges`) before anything reads the
    /// photos; the sRGB curve where a channel has fewer than 50 such pixels, and when false
    /// (the default: on a `gamma:1.8` twin the estimate, 0.012 RMS off, gives k_d 4.8 dB below
    /// the sRGB curve's and 7.7 dB below the true curve's; `docs/departures/response-edges.md`).
    pub edge_response: bool,
    /// The contours' estimate replaces the sRGB curve only where it departs from it by more
    /// than this RMS (over the forward curves): closer, it does not tell the two apart.
    pub edge_tolerance: f64,
    /// Estimate the camera response instead with the emitter solve (`crate::ldr::response`)
    /// where lamps are clipped and it has 1,000 pixels or more (false, the default). On
    /// rendered twins that estimate is 0.05–0.07 RMS off (`docs/ldr.md`).
    pub estimate_response: bool,
    /// Pixels of the emitter solve.
    pub solve_pixels: usize,
    /// Light samples per pixel and lamp in the emitter solve.
    pub light_samples: usize,
    /// The emitter solve estimates its light terms from two independent halves of their
    /// samples, each the instrument of the other's, against the bias that their Monte Carlo
    /// noise gives least squares (false: ordinary least squares; `docs/ldr.md`).
    pub solve_instruments: bool,
    /// The emitter solve after round 0 reads L′ with the clipped channels of surface pixels
    /// (not lamps) raised to round 0's render there: a clipped channel records only its clip
    /// level, and the solve would give the light those surfaces lack to the lamps.
    pub fill_clipped_surfaces: bool,
    /// The emitter solve after round 0 reads L′ without the pixels on and within
    /// `refine.paths.cache_margin` of an emitter, as the refinement does.
    pub solve_without_emitters: bool,
    /// JPEG photos: their code values reconstructed within the file's quantisation (the image
    /// of least total variation whose DCT coefficients round to the stored ones;
    /// `fipt_core::scene::jpeg`) before anything reads them. False, the default: the decoder's
    /// codes (of two held-out suite rooms it raises one's k_d and loses another's parts;
    /// `docs/departures/jpeg-reconstruct.md`).
    pub jpeg_reconstruct: bool,
    /// Projected gradient steps of that reconstruction.
    pub jpeg_iterations: usize,
}

impl Default for LdrSection {
    fn default() -> Self {
        Self {
            estimate_exposure: true,
            solve_emitters: true,
            edge_response: false,
            edge_tolerance: 0.02,
            estimate_response: false,
            solve_pixels: 20_000,
            light_samples: 512,
            solve_instruments: true,
            fill_clipped_surfaces: true,
            solve_without_emitters: true,
            jpeg_reconstruct: false,
            jpeg_iterations: 15,
        }
    }
}

/// Which segmentation loss: `auto` takes the part loss where `IndexMA` exists, else semantic.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum SegChoice {
    Auto,
    Part,
    Semantic,
    None,
}

/// Where the hash grid lives during the fit (`fipt_core::model::hashgrid_device`).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum GridPlace {
    /// On the device for the GPU backend (wgpu), the fused host op on the CPU backends.
    Auto,
    /// The fused host op with its sparse Adam (the CPU path).
    Host,
    /// Resident on the device: table, hashing, gather, scatter and a dense Adam as tensor ops,
    /// the pixels on the device too.
    Device,
}

impl std::str::FromStr for GridPlace {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match s {
            "auto" => Ok(GridPlace::Auto),
            "host" => Ok(GridPlace::Host),
            "device" => Ok(GridPlace::Device),
            _ => Err(format!(
                "unknown grid place '{s}' (expected auto, host or device)"
            )),
        }
    }
}

impl GridPlace {
    /// Whether the grid goes on the device with `backend`.
    pub fn on_device(self, backend: BackendKind) -> bool {
        match self {
            GridPlace::Auto => backend.is_gpu(),
            GridPlace::Host => false,
            GridPlace::Device => true,
        }
    }
}

/// The fit (`train`): its schedule, its losses, the model's sizes, the basin hop.
///
/// The schedule: the reference trains `epochs` epochs of ceil(N / batch) steps at a constant
/// learning rate (its milestone never fires), which is ~10k steps on its 41 M-pixel kitchen but
/// ~226 on a 0.9 M-pixel scene. `min_steps` puts a floor under the step count so that the
/// schedule transfers between scenes of different pixel counts, `lr_end` decays the learning
/// rate exponentially to `lr_end × lr` at the last step, and `balance` draws that share of every
/// batch uniformly over segments (then uniformly within the segment), so that small parts are
/// seen. `TrainSection::reference` is the reference's schedule.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct TrainSection {
    pub epochs: usize,
    pub batch: usize,
    /// Floor on the steps of a fit (0: the reference's `epochs` epochs only).
    pub min_steps: usize,
    pub lr: f64,
    /// Learning rate at the last step as a fraction of `lr`, decayed exponentially (1: constant,
    /// the reference).
    pub lr_end: f64,
    /// Share of each batch drawn uniformly over segments (0: the reference's uniform pixels).
    pub balance: f32,
    /// λ_d at the last step as a fraction of `lambda_d`, reached linearly (1: constant, the
    /// reference).
    pub lambda_d_end: f32,
    /// Share of each fit's steps over which λ_d first rises linearly from 0 (0: none, the
    /// reference).
    pub lambda_d_warmup: f32,
    /// Smallest share of a training pixel's square that the part its centre ray hits must
    /// cover for the pixel to enter the fits (`pipeline::pixels::coverage`; 0: every pixel,
    /// the reference).
    pub min_coverage: f32,
    /// With `min_coverage`: a sub-pixel ray counts for the centre's part only where the
    /// triangle it hits faces within this many degrees of the centre's (180: any, the part
    /// alone), so that a pixel on a box's edge, which averages two faces' reflections, is
    /// split too (`pipeline::pixels::CoverKeys`).
    pub coverage_crease: f32,
    pub seg: SegChoice,
    pub lambda_e: f32,
    pub lambda_d: f32,
    /// σ₀ of Eq. 17: the roughness its prior pulls every point towards (1: the paper's).
    pub prior_sigma: f32,
    pub lambda_part: f32,
    /// Soft bound on the σ and m logits (`loss::logit_bound_loss`; null: none, the reference).
    pub logit_bound: Option<f32>,
    /// Weight of the logit bound's penalty.
    pub lambda_logit: f32,
    pub lambda_sem: f32,
    pub sem_partners: usize,
    /// The hash grid (one schema with the model's `HashGridConfig`).
    pub grid: HashGridConfig,
    pub mlp_hidden: usize,
    pub mlp_layers: usize,
    pub emission_freqs: usize,
    pub emission_depth: usize,
    pub emission_width: usize,
    /// A learned offset of the material head's five logits per segment of the labels, added
    /// at every point of the triangles the segment covers (`fipt_core::model::part_offsets`;
    /// false: none, the reference). Needs part or semantic labels.
    pub part_offsets: bool,
    /// Which logits the part offsets move: `all` (a, σ, m), `roughness_metallic` or
    /// `roughness`.
    pub part_offset_columns: PartColumns,
    /// Where the hash grid lives (`auto`: on the device for wgpu, on the host for the CPU
    /// backends).
    pub grid_place: GridPlace,
    /// The basin hop on σ after every fit (`pipeline::hop`; null: none, the reference).
    pub hop: Option<HopConfig>,
}

impl Default for TrainSection {
    fn default() -> Self {
        Self {
            epochs: 2,
            batch: 8192,
            min_steps: 1000,
            lr: 1e-2,
            lr_end: 0.1,
            balance: 0.25,
            lambda_d_end: 1.0,
            // λ_d rises over the first three quarters of each fit and the σ, m logits are
            // bounded (the reference has neither); `docs/departures/`.
            lambda_d_warmup: 0.75,
            // The pixels that their centre's face covers less than three quarters of left out
            // of the fits (the reference keeps every pixel); `docs/departures/min-coverage.md`.
            min_coverage: 0.75,
            coverage_crease: 30.0,
            seg: SegChoice::Auto,
            lambda_e: 1.0,
            lambda_d: 5e-4,
            // Eq. 17's σ₀ inside the range of rough walls (the paper's is 1);
            // `docs/departures/prior-sigma.md`.
            prior_sigma: 0.9,
            lambda_part: 5e-3,
            logit_bound: Some(5.0),
            lambda_logit: 1e-3,
            lambda_sem: 1e-3,
            sem_partners: 1024,
            // Levels finer than 0.6 cells per pixel footprint dropped (the reference keeps all
            // 32); `docs/departures/grid-max-resolution.md`.
            grid: HashGridConfig {
                max_resolution: MaxResolution::Keyword(ResolutionKeyword::Auto),
                cells_per_footprint: 0.6,
                ..HashGridConfig::default()
            },
            mlp_hidden: 64,
            mlp_layers: 2,
            emission_freqs: 10,
            emission_depth: 6,
            emission_width: 128,
            part_offsets: false,
            part_offset_columns: PartColumns::All,
            grid_place: GridPlace::Auto,
            hop: Some(HopConfig::default()),
        }
    }
}

/// Every seed of a run, each derived from the config's `seed` here and nowhere else.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Seeds(pub u64);

impl Seeds {
    /// The bake's samples, the trainer's initial model, the emitter extraction and the
    /// re-renders.
    pub fn base(self) -> u64 {
        self.0
    }

    /// Round `r`'s batch sampler: the base seed, or with a warm start a new one per round.
    pub fn fit(self, r: usize, warm: bool) -> u64 {
        if warm {
            self.0.wrapping_add(r as u64)
        } else {
            self.0
        }
    }

    /// Round `r`'s basin hop.
    pub fn hop(self, r: usize) -> u64 {
        self.0 ^ ((r as u64) << 40)
    }

    /// Refinement `r`'s path tracer.
    pub fn refine(self, r: usize) -> u64 {
        self.0 ^ ((r as u64) << 32)
    }

    /// The oracle shadings' path tracer.
    pub fn oracle(self) -> u64 {
        self.0 ^ 0x0_7ac1e
    }

    /// The Monte Carlo albedo of view `k`'s predicted maps.
    pub fn view_maps(self, k: usize) -> u64 {
        self.0 ^ k as u64
    }
}

impl Config {
    /// The run's seeds.
    pub fn seeds(&self) -> Seeds {
        Seeds(self.seed)
    }

    /// Whether round `r`'s fit continues the last round's model (`refine.warm_start`).
    pub fn warm_start(&self, r: usize) -> bool {
        r > 0 && self.refine.warm_start
    }

    /// The bake's config with the run's seed.
    pub fn bake_config(&self) -> BakeConfig {
        BakeConfig {
            seed: self.seeds().base(),
            ..self.bake.clone()
        }
    }

    /// The path tracer's config of refinement `r` (its seed set).
    pub fn refine_paths(&self, r: usize) -> RefineConfig {
        RefineConfig {
            seed: self.seeds().refine(r),
            ..self.refine.paths.clone()
        }
    }

    /// The path tracer's config of the oracle shadings.
    pub fn oracle_paths(&self) -> RefineConfig {
        RefineConfig {
            seed: self.seeds().oracle(),
            // The oracle reads the true materials everywhere.
            unseen_cell: 0,
            ..self.refine.paths.clone()
        }
    }
}

impl Config {
    /// The train section as round `r`'s fit uses it: round 0's as written; the refined rounds'
    /// with `refine.lambda_d` and `refine.lambda_d_warmup` in place of the train section's.
    pub fn train_for_round(&self, r: usize) -> TrainSection {
        let mut t = self.train.clone();
        if r > 0 {
            if let Some(l) = self.refine.lambda_d {
                t.lambda_d = l;
            }
            if let Some(w) = self.refine.lambda_d_warmup {
                t.lambda_d_warmup = w;
            }
        }
        t
    }

    /// Round `r`'s weight of Eq. 17's m term as a multiple of its λ_d
    /// (`TrainConfig::metallic_scale`): 1, except in the refined rounds with `refine.lambda_m`.
    pub fn metallic_scale(&self, r: usize) -> f32 {
        match self.refine.lambda_m {
            Some(m) if r > 0 => m / self.train_for_round(r).lambda_d,
            _ => 1.0,
        }
    }
}

impl TrainSection {
    /// The reference's schedule (`epochs` epochs of ceil(N / batch) steps at a constant `lr`,
    /// uniform batches, a constant λ_d) with the other keys at their defaults.
    pub fn reference(epochs: usize, batch: usize, lr: f64) -> Self {
        Self {
            epochs,
            batch,
            min_steps: 0,
            lr,
            lr_end: 1.0,
            balance: 0.0,
            lambda_d_end: 1.0,
            lambda_d_warmup: 0.0,
            ..Self::default()
        }
    }

    /// The factor on λ_d at step `s` of `total`.
    pub fn lambda_d_at(&self, s: usize, total: usize) -> f32 {
        let f = if total > 1 {
            s as f32 / (total - 1) as f32
        } else {
            0.0
        };
        let ramp = if self.lambda_d_warmup > 0.0 {
            (f / self.lambda_d_warmup).min(1.0)
        } else {
            1.0
        };
        ramp * (1.0 + (self.lambda_d_end - 1.0) * f)
    }

    /// Steps of a fit over `n` pixels.
    pub fn steps(&self, n: usize) -> usize {
        (self.epochs * n.div_ceil(self.batch.max(1))).max(self.min_steps)
    }

    /// The learning rate of step `s` of `total`.
    pub fn lr_at(&self, s: usize, total: usize) -> f64 {
        let f = if total > 1 {
            s as f64 / (total - 1) as f64
        } else {
            0.0
        };
        self.lr * self.lr_end.powf(f)
    }

    /// The model's burn config, with `levels` hash-grid levels (see `HashGridConfig::levels_for`),
    /// for a fit on `backend` (which decides where `grid_place: auto` puts the grid).
    pub fn model_config(&self, levels: usize, backend: BackendKind) -> TrainConfig {
        TrainConfig::new()
            .with_device_grid(self.grid_place.on_device(backend))
            .with_part_columns(self.part_offset_columns)
            .with_lr(self.lr)
            .with_lambda_e(self.lambda_e)
            .with_lambda_d(self.lambda_d)
            .with_prior_sigma(self.prior_sigma)
            .with_lambda_part(self.lambda_part)
            .with_logit_bound(self.logit_bound)
            .with_lambda_logit(self.lambda_logit)
            .with_lambda_sem(self.lambda_sem)
            .with_sem_partners(self.sem_partners)
            .with_material(
                MaterialFieldConfig::new()
                    .with_grid(self.grid.clone().with_levels(levels))
                    .with_hidden(self.mlp_hidden)
                    .with_hidden_layers(self.mlp_layers),
            )
            .with_emission(
                EmissionMaskConfig::new()
                    .with_freqs(self.emission_freqs)
                    .with_depth(self.emission_depth)
                    .with_width(self.emission_width),
            )
    }

    /// The segmentation loss to use given which label maps exist.
    pub fn seg_mode(&self, has_part: bool, has_semantic: bool) -> SegMode {
        match self.seg {
            SegChoice::Part => SegMode::Part,
            SegChoice::Semantic => SegMode::Semantic,
            SegChoice::None => SegMode::None,
            SegChoice::Auto if has_part => SegMode::Part,
            SegChoice::Auto if has_semantic => SegMode::Semantic,
            SegChoice::Auto => SegMode::None,
        }
    }
}

/// The basin hop's keys (`train.hop`, run by `pipeline::hop`; null: no hop, the reference).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct HopConfig {
    /// Relative drop of a segment's objective at the sweep's best σ that calls for a hop.
    pub gain: f32,
    /// Smallest |best σ − mean fitted σ| that calls for a hop.
    pub min_move: f32,
    /// Steps of each phase (pull, then release) as a share of the fit's steps.
    pub steps: f32,
    /// Weight of the pull (`loss::sigma_pull_loss`).
    pub pull: f32,
    /// Pixels per segment in the sweep and the decision.
    pub pixels: usize,
    /// Share of the fit's final λ_d that the check and the decision hold (1: the fit's own
    /// objective, Eq. 15 + 17; 0: the data term alone, Eq. 15).
    pub prior: f32,
    /// Also try each non-metallic segment as a metal (m = 1, one base colour per segment,
    /// swept over σ), and pull m with σ when that hypothesis wins.
    pub metal: bool,
    /// Also score the last round's material on each segment under this round's shadings, and
    /// hop back to it where it explains the photos better (rounds after 0).
    pub carry: bool,
    /// Also sweep σ with the base colour solved per surface patch (`pipeline::patches`), in
    /// cubes of this many pixel footprints (0: off).
    pub patch: f32,
    /// Relative drop of a segment's patch objective that calls for a hop, and that the hop must
    /// reach for its patch candidates to be kept.
    pub patch_gain: f32,
    /// Smallest |best σ − mean fitted σ| of the patch sweep that calls for a hop (the fit's
    /// free colour keeps descent from nearer minima too).
    pub patch_min_move: f32,
    /// Weight of a pull that holds every segment not hopping at its mean σ and m from before
    /// the hop, through both phases (0: off; the hop's extra steps then move them freely).
    pub anchor: f32,
    /// A segment whose winning hypothesis is not the patch's, where that first hop is undone,
    /// hops with the patch candidates if its patch hypothesis counts too.
    pub patch_fallback: bool,
    /// Where `anchor` > 0, in the rounds on refined shadings: a dielectric segment not hopping
    /// whose patch sweep scores lower than its fit at a σ within `min_move` of its fitted σ is
    /// held at that σ and m 0 (the patch hypothesis, a dielectric's) instead of at its fitted
    /// σ and m (its data is flat there, and the prior put it where the fit left it).
    pub settle: bool,
    /// A patch candidate hops as the dielectric its hypothesis was solved as: m pulled to 0
    /// with σ to its target (false: σ alone, m left where the fit had it).
    pub patch_dielectric: bool,
    /// Weight of the pull that holds a candidate hopping as a metal (its target names m ≥ 0.5,
    /// or it names no m and the fit has it at m ≥ 0.5) at its target σ, and m where the target
    /// names one, through the release phase in place of releasing it (0: released, like every
    /// other candidate but the patch candidates).
    pub hold_metals: f32,
    /// A patch hypothesis counts only where about half or more of its segment's surface prefers
    /// it: the share of its pixels whose cube (`patch`) scores lower at the hypothesis than at
    /// the fit may lie at most this many standard errors (0.5 / √cubes) below a half (0: a half;
    /// null: off).
    pub patch_majority: Option<f32>,
    /// Also solve the patch hypothesis for the segments fitted metallic (mean m ≥ 0.5), as a
    /// metal (m = 1, the colour per cube its F0), and hop them as the metal it was solved as
    /// (false: dielectrics only).
    pub patch_metals: bool,
    /// A kept hop that harmed a segment not hopping (its objective up by more than the hop's
    /// `gain`, its mean σ moved by at least the hop's `min_move` from where it was held) runs
    /// again from the same start with that segment pulled where it was, at `pull` (false: the
    /// hop is judged on its candidates alone).
    pub guard: bool,
    /// A metal hypothesis gives way to a carried material that counts for the same segment
    /// (false: the larger relative gain wins). The metal's gain is against one colour per
    /// segment, the carried material's against the fit, so the two gains are not comparable.
    pub carried_first: bool,
    /// A metal hypothesis that counts and whose one colour per segment scores within `gain` of
    /// the fit's objective (the fit's colour free at every point) is plain: where the first
    /// hop, which its segment was part of with this or another hypothesis, is undone, the
    /// segment hops again as that metal, alone, held at its target through the release, and is
    /// kept where its one colour still scores within `gain` of the fit's (false: an undone
    /// first hop is final but for the patch fallback). A dielectric whose colour varies over
    /// the part explains a metal's highlights as well as one metal colour does; the metal needs
    /// no such freedom.
    pub plain_metal: bool,
}

impl Default for HopConfig {
    fn default() -> Self {
        Self {
            gain: 0.05,
            min_move: 0.25,
            steps: 0.15,
            pull: 0.1,
            pixels: 4096,
            prior: 0.0,
            metal: true,
            carry: true,
            patch: 2.0,
            patch_gain: 0.01,
            patch_min_move: 0.15,
            anchor: 1e-2,
            patch_fallback: true,
            settle: true,
            patch_dielectric: true,
            hold_metals: 0.1,
            patch_majority: Some(0.0),
            patch_metals: false,
            guard: true,
            carried_first: true,
            plain_metal: true,
        }
    }
}

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct EmitterSection {
    pub samples_per_triangle: usize,
    /// Mean α above which a triangle is a candidate (reference: 0.01).
    pub threshold: f32,
    /// A candidate must leave at least this median share of its observed radiance unexplained
    /// by reflection (0 = the reference rule; see `fipt_bake::emitters` and
    /// `docs/departures/min-unexplained.md`).
    pub min_unexplained: f32,
    /// Candidates no photo saw, next to an emitter, take its radiance instead of being dropped
    /// (false: the reference). See `fipt_bake::emitters`.
    pub fill_unseen: bool,
    /// A triangle's radiance is the median of its interior photo pixels, not of the outline
    /// pixels that mix it with what lies behind, and a triangle seen only beside another
    /// emitter's pixels is dropped (false: every pixel, the reference). See
    /// `fipt_bake::emitters` and `docs/departures/emitter-interior.md`.
    pub interior: bool,
}

impl Default for EmitterSection {
    fn default() -> Self {
        Self {
            samples_per_triangle: 100,
            threshold: 0.01,
            min_unexplained: 0.5,
            fill_unseen: true,
            interior: true,
        }
    }
}

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct MapsSection {
    /// Monte Carlo samples of the directional albedo a′ per pixel.
    pub albedo_samples: usize,
}

impl Default for MapsSection {
    fn default() -> Self {
        Self {
            albedo_samples: 128,
        }
    }
}

/// The re-renders of `run` (view synthesis of the val views and, where the scene has
/// `relight.json` and `val/Relight`, relighting), scored as `view_psnr` and `relight_psnr`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct RenderSection {
    /// Render and score the val views in `run`.
    pub val: bool,
    /// Samples per pixel of view synthesis (the reference's demo: 512).
    pub spp: usize,
    /// Samples per pixel of relighting (the reference's demo: 32, in Mitsuba).
    pub relight_spp: usize,
    /// Maximum path length in segments (the reference: 7).
    pub max_depth: usize,
    /// View synthesis takes L′ on rough secondary hits (the reference's scheme; relighting
    /// never does).
    pub cache: bool,
    /// Hits after the first segment read the learned field through a voxel cache (camera hits
    /// read it exactly); see `rerender::RecoveredOptions`.
    pub material_cache: bool,
    /// Relighting: switched-off emitters reflect with the learned field (a departure from the
    /// reference, which makes them black; see `rerender::RecoveredOptions::off_reflect`).
    pub off_reflect: bool,
    /// Fixed sub-pixel positions per pixel (a square; 0: continuous jitter), so camera hits
    /// repeat and the exact field is queried once per position (`PathConfig::pixel_positions`).
    pub pixel_positions: usize,
}

impl Default for RenderSection {
    fn default() -> Self {
        Self {
            val: true,
            spp: 256,
            relight_spp: 64,
            max_depth: 7,
            cache: true,
            material_cache: true,
            off_reflect: true,
            pixel_positions: 16,
        }
    }
}

/// The resumable state of `run` (`pipeline::checkpoint`): how often a running fit saves it.
/// Changes no result.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct CheckpointSection {
    /// Save the running fit every this many steps (0: only when it ends and on Ctrl-C).
    pub every_steps: usize,
}

impl Default for CheckpointSection {
    fn default() -> Self {
        Self { every_steps: 200 }
    }
}

fn check(ok: bool, key: &str, what: &str) -> Result<()> {
    if !ok {
        bail!("{key}: {what}");
    }
    Ok(())
}

impl Config {
    /// Parses JSON text; errors name the offending key (and, for a number out of its range,
    /// the range: `fipt_core::ranges`).
    pub fn from_json(text: &str) -> Result<Config> {
        let de = &mut serde_json::Deserializer::from_str(text);
        let cfg: Config = serde_path_to_error::deserialize(de).map_err(|e| {
            let path = e.path().to_string();
            anyhow::anyhow!("{path}: {}", e.into_inner())
        })?;
        let v: serde_json::Value = serde_json::from_str(text)?;
        fipt_core::ranges::check_value(fipt_core::ranges::Kind::Config, &v)
            .map_err(anyhow::Error::msg)?;
        cfg.validate()?;
        Ok(cfg)
    }

    pub fn load(path: &Path) -> Result<Config> {
        let text = std::fs::read_to_string(path)
            .with_context(|| format!("{}: cannot read", path.display()))?;
        Self::from_json(&text).with_context(|| format!("{}: bad config", path.display()))
    }

    /// Range checks.
    pub fn validate(&self) -> Result<()> {
        validate_render(&self.render)?;
        validate_bake(&self.bake)?;
        self.train.validate(self.refine.lambda_d_warmup)?;
        self.emitters.validate()?;
        validate_refine(&self.refine, self.train.lambda_d)?;
        check(
            self.maps.albedo_samples >= 1,
            "maps.albedo_samples",
            "must be >= 1",
        )?;
        Ok(())
    }
}

/// The `render` section's ranges.
fn validate_render(r: &RenderSection) -> Result<()> {
    check(
        (1..=1 << 16).contains(&r.spp) && (1..=1 << 16).contains(&r.relight_spp),
        "render.spp",
        "sample counts must be in [1, 65536]",
    )?;
    check(
        r.pixel_positions.isqrt().pow(2) == r.pixel_positions && r.pixel_positions <= 4096,
        "render.pixel_positions",
        "must be a square (0, 1, 4, 9, 16, ...) up to 4096",
    )?;
    check(
        (1..=64).contains(&r.max_depth),
        "render.max_depth",
        "must be in [1, 64]",
    )?;
    Ok(())
}

/// The `bake` section's ranges.
fn validate_bake(b: &BakeConfig) -> Result<()> {
    check(
        b.voxel_res >= 8 && b.voxel_res.is_multiple_of(8) && b.voxel_res <= 4096,
        "bake.voxel_res",
        "must be a multiple of 8 in [8, 4096]",
    )?;
    check(b.fill_rings <= 64, "bake.fill_rings", "must be in [0, 64]")?;
    check(b.footprint <= 8, "bake.footprint", "must be in [0, 8]")?;
    check(
        b.samples.diffuse >= 1,
        "bake.samples.diffuse",
        "must be >= 1",
    )?;
    check(
        b.samples.specular.iter().all(|&s| s >= 1),
        "bake.samples.specular",
        "every count must be >= 1",
    )?;
    check(
        b.filter.specular_levels.iter().all(|&j| j < 6),
        "bake.filter.specular_levels",
        "levels are 0..5",
    )?;
    check(
        b.filter.sigma_px > 0.0 && b.filter.sigma_plane_px > 0.0,
        "bake.filter.sigma_px",
        "filter scales must be > 0",
    )?;
    check(
        b.filter.normal_power >= 0.0,
        "bake.filter.normal_power",
        "must be >= 0",
    )?;
    Ok(())
}

impl TrainSection {
    /// The `train` section's ranges (with the refined rounds' λ_d warm-up override, a share
    /// like the train section's own).
    fn validate(&self, refine_warmup: Option<f32>) -> Result<()> {
        let t = self;
        check(t.epochs >= 1, "train.epochs", "must be >= 1")?;
        check(t.batch >= 1, "train.batch", "must be >= 1")?;
        check(t.lr > 0.0 && t.lr.is_finite(), "train.lr", "must be > 0")?;
        check(
            t.lr_end > 0.0 && t.lr_end <= 1.0,
            "train.lr_end",
            "must be in (0, 1]",
        )?;
        // Shares and fractions (the refined rounds' warm-up override with the train section's).
        let warmup_override = refine_warmup.map(|w| ("refine.lambda_d_warmup", w));
        for (k, v) in [
            ("train.lambda_d_end", t.lambda_d_end),
            ("train.lambda_d_warmup", t.lambda_d_warmup),
            ("train.balance", t.balance),
            ("train.prior_sigma", t.prior_sigma),
            ("train.min_coverage", t.min_coverage),
        ]
        .into_iter()
        .chain(warmup_override)
        {
            check((0.0..=1.0).contains(&v), k, "must be in [0, 1]")?;
        }
        check(
            (0.0..=180.0).contains(&t.coverage_crease),
            "train.coverage_crease",
            "must be in [0, 180] degrees",
        )?;
        check(
            t.logit_bound.is_none_or(|z| z > 0.0 && z.is_finite()),
            "train.logit_bound",
            "must be > 0 (or null)",
        )?;
        for (k, v) in [
            ("train.lambda_e", t.lambda_e),
            ("train.lambda_d", t.lambda_d),
            ("train.lambda_part", t.lambda_part),
            ("train.lambda_logit", t.lambda_logit),
            ("train.lambda_sem", t.lambda_sem),
        ] {
            check(v >= 0.0 && v.is_finite(), k, "must be >= 0")?;
        }
        check(t.sem_partners >= 1, "train.sem_partners", "must be >= 1")?;
        if let Some(h) = &t.hop {
            h.validate()?;
        }
        self.validate_model()
    }

    /// The model's sizes: the hash grid and the MLPs.
    fn validate_model(&self) -> Result<()> {
        let t = self;
        let g = &t.grid;
        // A training table of at least 2^8 entries and a base of at least 2 cells; the rest
        // of the grid's ranges are `HashGridConfig::check`'s (also applied to saved models).
        check(
            (8..=24).contains(&g.log2_table),
            "train.grid.log2_table",
            "must be in [8, 24]",
        )?;
        check(
            g.base_resolution >= 2.0,
            "train.grid.base_resolution",
            "must be >= 2",
        )?;
        if let MaxResolution::Fixed(r) = g.max_resolution {
            check(
                r.is_finite() && r >= 1.0,
                "train.grid.max_resolution",
                "must be \"auto\", \"none\" or a number >= 1",
            )?;
        }
        g.check().map_err(|e| anyhow::anyhow!("train.{e}"))?;
        check(
            t.mlp_hidden >= 1 && t.mlp_layers >= 1,
            "train.mlp_hidden",
            "MLP sizes must be >= 1",
        )?;
        check(
            t.emission_depth >= 1 && t.emission_width >= 1,
            "train.emission_depth",
            "MLP sizes must be >= 1",
        )?;
        Ok(())
    }
}

impl HopConfig {
    /// The `train.hop` keys' ranges.
    fn validate(&self) -> Result<()> {
        let h = self;
        for (k, v) in [
            ("train.hop.gain", h.gain),
            ("train.hop.min_move", h.min_move),
            ("train.hop.prior", h.prior),
            ("train.hop.patch_gain", h.patch_gain),
            ("train.hop.patch_min_move", h.patch_min_move),
        ] {
            check((0.0..=1.0).contains(&v), k, "must be in [0, 1]")?;
        }
        check(
            h.patch >= 0.0 && h.patch.is_finite(),
            "train.hop.patch",
            "must be a finite number >= 0",
        )?;
        check(
            h.steps > 0.0 && h.steps <= 1.0,
            "train.hop.steps",
            "must be in (0, 1]",
        )?;
        for (k, v) in [
            ("train.hop.pull", h.pull),
            ("train.hop.anchor", h.anchor),
            ("train.hop.hold_metals", h.hold_metals),
        ] {
            check(v >= 0.0 && v.is_finite(), k, "must be >= 0")?;
        }
        check(h.pixels >= 1, "train.hop.pixels", "must be >= 1")?;
        check(
            h.patch_majority.is_none_or(|z| (0.0..=10.0).contains(&z)),
            "train.hop.patch_majority",
            "must be in [0, 10] or null",
        )?;
        Ok(())
    }
}

impl EmitterSection {
    /// The `emitters` section's ranges.
    fn validate(&self) -> Result<()> {
        check(
            self.samples_per_triangle >= 1,
            "emitters.samples_per_triangle",
            "must be >= 1",
        )?;
        check(
            (0.0..1.0).contains(&self.threshold),
            "emitters.threshold",
            "must be in [0, 1)",
        )?;
        check(
            (0.0..=1.0).contains(&self.min_unexplained),
            "emitters.min_unexplained",
            "must be in [0, 1]",
        )?;
        Ok(())
    }
}

/// The `refine` section's ranges.
fn validate_refine(refine: &RefineSection, train_lambda_d: f32) -> Result<()> {
    let r = &refine.paths;
    check(
        r.samples.diffuse >= 1 && r.samples.specular.iter().all(|&s| s >= 1),
        "refine.paths.samples",
        "every count must be >= 1",
    )?;
    check(
        (2..=64).contains(&r.max_depth),
        "refine.paths.max_depth",
        "must be in [2, 64]",
    )?;
    check(
        r.cache_roughness.is_finite() && r.cache_roughness >= 0.0,
        "refine.paths.cache_roughness",
        "must be >= 0",
    )?;
    check(
        r.filter.specular_levels.iter().all(|&j| j < 6),
        "refine.paths.filter.specular_levels",
        "levels are 0..5",
    )?;
    check(r.wave >= 1, "refine.paths.wave", "must be >= 1")?;
    check(
        r.footprint <= 8,
        "refine.paths.footprint",
        "must be in [0, 8]",
    )?;

    if let Some(l) = refine.lambda_d {
        check(l >= 0.0 && l.is_finite(), "refine.lambda_d", "must be >= 0")?;
    }
    if let Some(m) = refine.lambda_m {
        check(m >= 0.0 && m.is_finite(), "refine.lambda_m", "must be >= 0")?;
        // It is held as a multiple of the refined rounds' λ_d.
        let ld = refine.lambda_d.unwrap_or(train_lambda_d);
        check(
            ld > 0.0,
            "refine.lambda_m",
            "needs a refined λ_d > 0 (refine.lambda_d, else train.lambda_d)",
        )?;
    }
    check(
        refine.emitter_margin <= 8,
        "refine.emitter_margin",
        "must be in [0, 8]",
    )?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The reference schedule: epochs × ceil(N/B) steps at a constant rate; the floor and the
    /// decay as documented.
    #[test]
    fn schedule_steps_and_rates() {
        let r = TrainSection::reference(2, 8192, 1e-3);
        assert_eq!(r.steps(921_600), 226);
        assert_eq!(r.lr_at(0, 226), 1e-3);
        assert_eq!(r.lr_at(225, 226), 1e-3);
        let s = TrainSection {
            min_steps: 1000,
            lr_end: 0.1,
            ..r.clone()
        };
        assert_eq!(s.steps(921_600), 1000);
        assert_eq!(s.steps(50_000_000), 2 * 6104);
        assert!((s.lr_at(999, 1000) - 1e-4).abs() < 1e-12);
        assert!((s.lr_at(0, 1000) - 1e-3).abs() < 1e-15);
        let mid = s.lr_at(500, 1000) / 1e-3;
        assert!((mid - 0.1f64.powf(500.0 / 999.0)).abs() < 1e-12);
        // λ_d: 0 at the first step, linear to full at `lambda_d_warmup` of the steps, then the
        // `lambda_d_end` line.
        let w = TrainSection {
            lambda_d_warmup: 0.5,
            lambda_d_end: 0.5,
            ..r.clone()
        };
        assert_eq!(w.lambda_d_at(0, 101), 0.0);
        assert!((w.lambda_d_at(25, 101) - 0.5 * (1.0 - 0.5 * 0.25)).abs() < 1e-6);
        assert!((w.lambda_d_at(50, 101) - (1.0 - 0.5 * 0.5)).abs() < 1e-6);
        assert!((w.lambda_d_at(100, 101) - 0.5).abs() < 1e-6);
        assert_eq!(r.lambda_d_at(0, 101), 1.0);
    }

    #[test]
    fn errors_name_the_key() {
        let e = Config::from_json(r#"{"train": {"lr": "fast"}}"#)
            .unwrap_err()
            .to_string();
        assert!(e.contains("train.lr") && e.contains("invalid type"), "{e}");
        let e = Config::from_json(r#"{"train": {"grid": {"levls": 3}}}"#)
            .unwrap_err()
            .to_string();
        assert!(e.contains("train.grid") && e.contains("levls"), "{e}");
        let e = Config::from_json(r#"{"bake": {"voxel_res": 100}}"#)
            .unwrap_err()
            .to_string();
        assert!(e.contains("bake.voxel_res"), "{e}");
        let e = Config::from_json(r#"{"emitters": {"threshold": 2.0}}"#)
            .unwrap_err()
            .to_string();
        assert!(e.contains("emitters.threshold"), "{e}");
        let e = Config::from_json(r#"{"train": {"hop": {"min_move": 1.5}}}"#)
            .unwrap_err()
            .to_string();
        assert!(e.contains("train.hop.min_move"), "{e}");
        let e = Config::from_json(r#"{"train": {"hop": {"prior": -0.5}}}"#)
            .unwrap_err()
            .to_string();
        assert!(e.contains("train.hop.prior"), "{e}");
        let e = Config::from_json(r#"{"train": {"hop": {"gian": 0.1}}}"#)
            .unwrap_err()
            .to_string();
        assert!(e.contains("train.hop") && e.contains("gian"), "{e}");
        // null turns the hop off (the reference).
        let off = Config::from_json(r#"{"train": {"hop": null}}"#).unwrap();
        assert!(off.train.hop.is_none());
        let e = Config::from_json(r#"{"backend": "opencl"}"#)
            .unwrap_err()
            .to_string();
        assert!(e.contains("backend"), "{e}");
        assert_eq!(Config::from_json("{}").unwrap(), Config::default());
    }

    /// `refine.lambda_m` weighs Eq. 17's m term in the refined rounds alone, as a multiple of
    /// their λ_d; a bad value or a refined λ_d of 0 is refused naming the key.
    #[test]
    fn refine_lambda_m_scales_the_m_term_of_refined_rounds() {
        let c = Config::from_json(r#"{"refine": {"lambda_d": 1e-4, "lambda_m": 5e-4}}"#).unwrap();
        assert_eq!(c.metallic_scale(0), 1.0);
        assert!((c.metallic_scale(1) - 5.0).abs() < 1e-5);
        assert!((c.metallic_scale(2) - 5.0).abs() < 1e-5);
        // Without refine.lambda_d the refined rounds hold train.lambda_d.
        let c = Config::from_json(r#"{"refine": {"lambda_d": null, "lambda_m": 1e-3}}"#).unwrap();
        assert!((c.metallic_scale(1) - 1e-3 / 5e-4).abs() < 1e-5);
        assert_eq!(Config::default().metallic_scale(1), 1.0);
        let c = Config::from_json(r#"{"refine": {"lambda_m_on": "dielectrics"}}"#).unwrap();
        assert_eq!(c.refine.lambda_m_on, MetalPriorOn::Dielectrics);
        assert_eq!(Config::default().refine.lambda_m_on, MetalPriorOn::All);
        let e = Config::from_json(r#"{"refine": {"lambda_m_on": "metals"}}"#)
            .unwrap_err()
            .to_string();
        assert!(e.contains("refine.lambda_m_on"), "{e}");
        for bad in [
            r#"{"refine": {"lambda_m": -1e-4}}"#,
            r#"{"refine": {"lambda_d": 0.0, "lambda_m": 5e-4}}"#,
        ] {
            let e = Config::from_json(bad).unwrap_err().to_string();
            assert!(e.contains("refine.lambda_m"), "{bad}: {e}");
        }
    }

    #[test]
    fn shipped_configs_parse() {
        let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("../configs");
        for name in ["default.json", "fast.json"] {
            Config::load(&dir.join(name)).unwrap();
        }
        // default.json holds the defaults (the reference's constants but the named departures).
        assert_eq!(
            Config::load(&dir.join("default.json")).unwrap(),
            Config::default()
        );
    }
}
