use super::choose::*;
use super::evaluate::*;
use super::patch::*;
use super::phases::*;
use super::*;
use crate::pipeline::batches::step_entries;
use crate::pipeline::landscape::SWEEP;
use crate::pipeline::landscape::sweep;
use crate::pipeline::test_data::{store, toy_fit, toy_store};
use fipt_core::brdf::{factorised_render, reflectances};
use fipt_core::model::step::SigmaPull;
use fipt_core::rng::Rng;
use fipt_core::scene::SceneBox;
use fipt_core::shading::ShadingLayout;

/// The toy model fitted on `st` (part loss, 25 steps), and its schedule.
fn toy_fitted(st: &PixelStore) -> (Trainer, TrainSection) {
    let (cfg, schedule) = toy_fit();
    let (tr, _) =
        crate::pipeline::fit::fit_more(toy_trainer(cfg), st, SegMode::Part, &schedule, 5, false);
    (tr, schedule)
}

/// A hop plan over the toy fit's schedule, without a carried model.
fn toy_plan<'a>(
    cfg: &'a HopConfig,
    schedule: &'a TrainSection,
    lambda_d: f32,
    footprint: f32,
) -> HopPlan<'a> {
    HopPlan {
        cfg,
        mode: SegMode::Part,
        schedule,
        lambda_d,
        seed: 5,
        show_progress: false,
        carried: None,
        refined: false,
        footprint,
    }
}

fn toy_trainer(cfg: fipt_core::model::TrainConfig) -> Trainer {
    let scene_box = SceneBox { min: 0.0, max: 1.0 };
    Trainer::new(cfg, scene_box, &burn::tensor::Device::flex(), 5)
}

/// The host objective is the fit's own: on one segment, the mean of Eq. 15 + 17 that
/// `evaluate` computes at the model equals the colour loss plus the prior of the trainer's
/// forward pass on the same pixels.
#[test]
fn objective_is_the_fit_loss() {
    let mut st = toy_store(300);
    st.pixels.seg.iter_mut().for_each(|s| *s = 0);
    for (i, x) in st.pixels.x_world.iter_mut().enumerate() {
        *x = [i as f32 / 300.0, 0.3, 0.7];
    }
    let (cfg, _) = toy_fit();
    let mut tr = toy_trainer(cfg.with_logit_bound(None).with_lambda_d(3e-2));
    let samples = sample(&st, usize::MAX);
    assert_eq!(samples.len(), 1);
    assert_eq!(samples[0].idx.len(), 300);
    let e = evaluate(
        &tr.model,
        &st,
        &samples,
        DiffusePrior {
            lambda_d: 3e-2,
            sigma: tr.cfg.prior_sigma,
        },
        Hypotheses {
            sweep: true,
            ..Default::default()
        },
    );
    let all: Vec<u32> = (0..300).collect();
    let parts = tr.gradients(&st.batch(&all), SegMode::None).parts;
    let want = (parts.color + parts.diffuse) as f64;
    assert!(
        (e[0].own - want).abs() < 1e-5 * want.abs().max(1e-3),
        "{} vs {want}",
        e[0].own
    );
    assert_eq!(e[0].sweep.len(), SWEEP);
    assert!(e[0].sigma > 0.02 && e[0].sigma < 1.0);
    // `prior` 0 holds no λ_d: the data term alone, Eq. 15.
    let data = evaluate(
        &tr.model,
        &st,
        &samples,
        DiffusePrior::NONE,
        Hypotheses::default(),
    );
    let want = parts.color as f64;
    assert!(
        (data[0].own - want).abs() < 1e-5 * want.abs().max(1e-3),
        "{} vs {want}",
        data[0].own
    );
    assert!(data[0].own < e[0].own);
}

fn eval(sigma: f64, own: f64, best_at: usize, best: f64) -> SegmentEval {
    let mut sweep = vec![own + 1.0; SWEEP];
    sweep[best_at] = best;
    SegmentEval {
        sigma,
        metallic: 0.0,
        own,
        sweep,
        metal: Vec::new(),
        uniform: f64::NAN,
        carried: None,
    }
}

/// Only a deep minimum far from the fit sends a segment hopping, to the swept σ there.
#[test]
fn only_deep_far_minima_hop() {
    let st = store(&[0, 1, 2, 2]);
    let samples = sample(&st, 8);
    assert_eq!(
        samples.iter().map(|s| s.size).collect::<Vec<_>>(),
        [1, 1, 2]
    );
    let sig = sweep();
    let near = sig.iter().position(|&s| s >= 0.9).unwrap();
    let far = sig.iter().position(|&s| s >= 0.3).unwrap();
    let evals = [
        // 20 % lower at σ ≈ 0.3, fitted at 0.95: hops.
        eval(0.95, 1.0, far, 0.8),
        // 2 % lower: the gain is too small.
        eval(0.95, 1.0, far, 0.98),
        // 50 % lower but 0.05 away: no hop (descent reaches it).
        eval(0.95, 1.0, near, 0.5),
    ];
    let cfg = HopConfig::default();
    let c = candidates(&cfg, &checks(&samples, &evals));
    assert_eq!(c.len(), 1);
    assert_eq!(c[0].segment, 0);
    assert_eq!(c[0].target, sig[far] as f64);
    assert_eq!(c[0].objective_target, 0.8);
    // The whole objective weighs each segment by its size.
    let w = whole(&samples, &evals);
    assert!((w - 1.0).abs() < 1e-12);
    // A segment already at zero (all behind the emission mask) has nothing to gain.
    let zero = [eval(0.95, 0.0, far, 0.0)];
    assert!(candidates(&cfg, &checks(&samples[..1], &zero)).is_empty());
}

/// A segment rendered as a metal (m = 1) of known colour and roughness: `uniform_colour`
/// recovers the colour at the true σ (and a dielectric's, rendered so, at m = 0), and the metal profile's least objective lies at the
/// true σ with (nearly) zero data term, far below the dielectric profile's at the fit.
#[test]
fn the_metal_hypothesis_finds_a_metal() {
    let n = 400;
    let mut st = toy_store(n);
    st.pixels.seg.iter_mut().for_each(|s| *s = 0);
    let (a, sigma) = (glam::Vec3::new(0.9, 0.6, 0.3), sweep()[12]);
    let d = ShadingLayout::DIM;
    for i in 0..n {
        // Specular shadings that vary over σ and pixels, so σ is identifiable.
        for j in 0..fipt_core::brdf::ROUGHNESS_LEVELS {
            for c in 0..3 {
                let v = 0.2 + ((i * 7 + j * 13 + c * 5) % 11) as f32 / 11.0;
                st.pixels.shadings[i * d + ShadingLayout::ls0(j).start + c] = v;
                st.pixels.shadings[i * d + ShadingLayout::ls1(j).start + c] = 0.05 * v;
            }
        }
        let sh = ShadingLayout::pixel(&st.pixels.shadings, i).to_vec();
        let c = factorised_render([0.0; 3], a.to_array(), sigma, &sh);
        st.pixels.gt[3 * i..3 * i + 3].copy_from_slice(&c);
    }
    let all: Vec<u32> = (0..n as u32).collect();
    let b = st.batch(&all);
    let alpha = vec![0.0; n];
    let fitted = uniform_colour(&b, &alpha, sigma, 1.0);
    assert!((fitted - a).abs().max_element() < 1e-4, "{fitted} vs {a}");
    let mut dielectric = st.batch(&all);
    for i in 0..n {
        let sh = ShadingLayout::pixel(&dielectric.shadings, i).to_vec();
        let (kd, ks) = reflectances(a, 0.0);
        let c = factorised_render(kd.to_array(), ks.to_array(), sigma, &sh);
        dielectric.gt[3 * i..3 * i + 3].copy_from_slice(&c);
    }
    let fitted = uniform_colour(&dielectric, &alpha, sigma, 0.0);
    assert!((fitted - a).abs().max_element() < 1e-4, "{fitted} vs {a}");
    let (cfg, _) = toy_fit();
    let tr = toy_trainer(cfg);
    let samples = sample(&st, usize::MAX);
    let with = Hypotheses {
        sweep: true,
        metal: true,
        uniform: &[],
        carried: None,
    };
    let e = evaluate(&tr.model, &st, &samples, DiffusePrior::NONE, with).remove(0);
    let (best_sigma, best) = profile_min(&e.metal);
    assert_eq!(best_sigma, sigma as f64);
    let (_, dielectric) = profile_min(&e.sweep);
    assert!(
        best < 1e-9 && best < 1e-3 * dielectric.min(e.own),
        "{best} vs {dielectric}, {}",
        e.own
    );
    // One colour at the fit's σ and m explains it far worse than the metal does.
    assert!(best < 1e-3 * e.uniform, "{best} vs {}", e.uniform);
    // The check proposes the metal for a segment fitted non-metallic, pulling m to 1 with σ.
    let mut rows = checks(&samples, &[e]);
    rows[0].metallic = 0.1;
    let c = candidates(&HopConfig::default(), &rows);
    assert_eq!(c.len(), 1);
    assert_eq!(c[0].source, Hypothesis::Metal);
    assert_eq!(
        (c[0].target, c[0].target_metallic),
        (sigma as f64, Some(1.0))
    );
}

/// A pull that names an m target moves that segment's m towards it, beyond what the same
/// steps without it do.
#[test]
fn the_pull_moves_m_where_it_names_a_target() {
    // Black photos and shadings: the data term does not see m, the pull and priors do.
    let mut st = toy_store(400);
    st.pixels.shadings.iter_mut().for_each(|v| *v = 0.0);
    st.pixels.gt.iter_mut().for_each(|v| *v = 0.0);
    let (tr, _) = toy_fitted(&st);
    let samples = sample(&st, 64);
    let m_of = |t: &Trainer| -> Vec<f64> {
        evaluate(
            &t.model,
            &st,
            &samples,
            DiffusePrior::NONE,
            Hypotheses::default(),
        )
        .iter()
        .map(|e| e.metallic)
        .collect()
    };
    let run = |pull: Option<SigmaPull>| {
        let mut t = tr.clone();
        t.pull = pull;
        let mut rng = Rng::new(9, 1);
        for _ in 0..100 {
            let idx: Vec<u32> = (0..64).map(|_| rng.below(400) as u32).collect();
            drop(step_entries(&mut t, None, &st, &idx, SegMode::Part));
        }
        t.sync_host_table();
        m_of(&t)
    };
    let free = run(None);
    let pulled = run(Some(SigmaPull {
        weight: 10.0,
        target: Default::default(),
        metallic: [(2, 1.0)].into_iter().collect(),
    }));
    let k = samples.iter().position(|s| s.id == 2).unwrap();
    // Adam's step size bounds the move in 100 steps (about 0.04 here, whatever the weight).
    assert!(
        pulled[k] > free[k] + 0.02,
        "m {} with the pull, {} without",
        pulled[k],
        free[k]
    );
}

/// A metal hypothesis is plain where its one colour per segment scores within `gain` of
/// the fit's objective (`plain_metal`), and only then: a metal that wins against one colour
/// at the fitted σ and m but needs more than the fit's free colour to match it is not, nor
/// is any other hypothesis; a plain metal is its segment's fallback where another
/// hypothesis won; the plain metals' hop holds while their one colour after it stays within
/// `gain` of the fit's objective before it.
#[test]
fn a_plain_metal_matches_the_fit_with_one_colour() {
    let sig = sweep();
    let samples = [SegmentSample {
        id: 6,
        size: 300,
        idx: Vec::new(),
    }];
    // The fit: σ 0.9, m 0, objective 1; the sweep finds nothing lower.
    let fit = checks(&samples, &[eval(0.9, 1.0, 0, 2.0)]).remove(0);
    let row = |metal: (f64, f64, f64)| SegmentObjective {
        metal: Some(metal),
        ..fit.clone()
    };
    let cfg = HopConfig::default();
    let gain = cfg.gain as f64;
    // One metal colour at σ 0.46 as good as the fit (colour free), and far better than one
    // colour at the fitted σ and m: plain.
    let c = candidates(&cfg, &[row((0.46, 1.0, 3.0))]);
    assert_eq!(c[0].source, Hypothesis::Metal);
    assert!(c[0].plain);
    // Just within `gain` of the fit, and just beyond it.
    assert!(candidates(&cfg, &[row((0.46, 1.0 + 0.9 * gain, 3.0))])[0].plain);
    let beyond = candidates(&cfg, &[row((0.46, 1.0 + 1.1 * gain, 3.0))]);
    assert_eq!(beyond[0].source, Hypothesis::Metal);
    assert!(!beyond[0].plain);
    // A metal three times the fit's objective that still halves its own baseline: a
    // candidate, not plain (a dielectric counter whose colour one metal colour cannot
    // carry).
    let counter = candidates(&cfg, &[row((0.46, 3.0, 6.0))]);
    assert_eq!(counter[0].source, Hypothesis::Metal);
    assert!(!counter[0].plain);
    // The key off: no metal is plain.
    let off = HopConfig {
        plain_metal: false,
        ..HopConfig::default()
    };
    assert!(!candidates(&off, &[row((0.46, 1.0, 3.0))])[0].plain);
    // The sweep's candidate is never plain, however low its objective.
    let far = sig.iter().position(|&s| s >= 0.3).unwrap();
    let sweep_row = checks(&samples, &[eval(0.95, 1.0, far, 0.5)]);
    let c = candidates(&cfg, &sweep_row);
    assert_eq!(c[0].source, Hypothesis::Sweep);
    assert!(!c[0].plain);
    // The plain hop holds at one colour within `gain` of the fit's objective, size-weighted.
    let hopped = |after: f64, pixels: usize| HopCandidate {
        objective: 1.0,
        objective_after: after,
        pixels,
        ..c[0].clone()
    };
    assert!(plain_held(&[hopped(1.0 + 0.9 * gain, 300)], cfg.gain));
    assert!(!plain_held(&[hopped(1.0 + 1.1 * gain, 300)], cfg.gain));
    assert!(plain_held(
        &[hopped(1.0 + 2.0 * gain, 100), hopped(1.0, 300)],
        cfg.gain
    ));
    assert!(!plain_held(
        &[hopped(1.0 + 2.0 * gain, 300), hopped(1.0, 100)],
        cfg.gain
    ));
    // A carried material that counts wins the first hop with `carried_first`; the plain
    // metal is still the segment's fallback if that hop is undone, and a metal that is not
    // plain is none.
    let carried = SegmentObjective {
        carried: Some((0.5, 0.98, 0.8)),
        ..row((0.46, 1.0, 3.0))
    };
    let c = candidates(&cfg, std::slice::from_ref(&carried));
    assert_eq!(c[0].source, Hypothesis::Carried);
    let again = plain_fallbacks(&cfg, std::slice::from_ref(&carried));
    assert_eq!(again.len(), 1);
    assert_eq!(
        (again[0].source, again[0].target, again[0].target_metallic),
        (Hypothesis::Metal, 0.46, Some(1.0))
    );
    assert!(again[0].plain && again[0].alone);
    let rough = SegmentObjective {
        metal: Some((0.46, 3.0, 6.0)),
        ..carried.clone()
    };
    assert!(plain_fallbacks(&cfg, &[rough]).is_empty());
    assert!(plain_fallbacks(&off, &[carried]).is_empty());
    // Its hop stays pulled through the release, on a stream of its own.
    assert!(Stage::Plain.held() && !Stage::First.held());
    let streams = [Stage::First, Stage::Plain, Stage::Patch].map(Stage::stream);
    assert!(streams[0] != streams[1] && streams[1] != streams[2] && streams[0] != streams[2]);
}

/// The last round's material is scored under this round's shadings: with the same model it
/// scores the model's own objective; a carried candidate wins over the sweep only with the
/// lower objective, and pulls m only when it lies across 0.5 from the fit; where it counts,
/// it wins over the metal hypothesis (`carried_first`).
#[test]
fn carried_material_is_scored_and_chosen_by_its_objective() {
    let st = toy_store(300);
    let (cfg, _) = toy_fit();
    let tr = toy_trainer(cfg);
    let samples = sample(&st, 64);
    let with = Hypotheses {
        carried: Some(&tr.model),
        ..Hypotheses::default()
    };
    for e in evaluate(&tr.model, &st, &samples, DiffusePrior::NONE, with) {
        let (sigma, m, obj) = e.carried.unwrap();
        assert_eq!((sigma, m, obj), (e.sigma, e.metallic, e.own));
    }
    let sig = sweep();
    let far = sig.iter().position(|&s| s >= 0.3).unwrap();
    let row = |carried: (f64, f64, f64)| SegmentObjective {
        carried: Some(carried),
        ..checks(&samples[..1], &[eval(0.95, 1.0, far, 0.8)]).remove(0)
    };
    let cfg = HopConfig::default();
    // Lower than the sweep's best, and a metal where the fit is not: pulls σ and m.
    let c = candidates(&cfg, &[row((0.1, 0.9, 0.5))]);
    assert_eq!(c[0].source, Hypothesis::Carried);
    assert_eq!((c[0].target, c[0].target_metallic), (0.1, Some(0.9)));
    // Higher than the sweep's best: the sweep wins.
    let c = candidates(&cfg, &[row((0.1, 0.9, 0.9))]);
    assert_eq!(c[0].source, Hypothesis::Sweep);
    // Non-metallic like the fit: σ alone is pulled.
    let c = candidates(&cfg, &[row((0.1, 0.2, 0.5))]);
    assert_eq!(
        (c[0].source, c[0].target_metallic),
        (Hypothesis::Carried, None)
    );
    // Near the fit in σ and m, but lower: it still wins (no distance asked of it).
    let c = candidates(&cfg, &[row((0.9, 0.1, 0.1))]);
    assert_eq!((c[0].source, c[0].target), (Hypothesis::Carried, 0.9));
    // Not lower by `gain`: the sweep's target.
    let c = candidates(&cfg, &[row((0.2, 0.9, 0.97))]);
    assert_eq!(c[0].source, Hypothesis::Sweep);
    // A metal hypothesis whose gain against its own baseline (one colour per segment, 0.8)
    // is larger than the carried material's against the fit (0.5) gives way to it with
    // `carried_first`, and wins without it.
    let both = SegmentObjective {
        metal: Some((0.3, 0.2, 1.0)),
        ..row((0.06, 0.98, 0.5))
    };
    let c = candidates(&cfg, std::slice::from_ref(&both));
    assert_eq!((c[0].source, c[0].target), (Hypothesis::Carried, 0.06));
    let off = HopConfig {
        carried_first: false,
        ..HopConfig::default()
    };
    let c = candidates(&off, std::slice::from_ref(&both));
    assert_eq!((c[0].source, c[0].target), (Hypothesis::Metal, 0.3));
    // A carried material that does not count leaves the metal its win.
    let weak = SegmentObjective {
        carried: Some((0.06, 0.98, 0.97)),
        ..both
    };
    assert_eq!(candidates(&cfg, &[weak])[0].source, Hypothesis::Metal);
}

/// The check holds `prior` × the fit's λ_d: with 0 each segment's objective is its data
/// term, with 1 the data term plus λ_d·mean(|σ − σ₀| + m).
#[test]
fn the_check_holds_its_share_of_the_prior() {
    let st = toy_store(400);
    let (tr, schedule) = toy_fitted(&st);
    let lambda_d = 0.05;
    let report = |prior: f32| {
        // gain 1: no segment can gain it all, so nothing hops.
        let hc = HopConfig {
            gain: 1.0,
            patch_gain: 1.0,
            pixels: 64,
            prior,
            ..HopConfig::default()
        };
        let plan = toy_plan(&hc, &schedule, lambda_d, 0.01);
        hop(tr.clone(), &st, &plan).unwrap().1
    };
    let (data, full) = (report(0.0), report(1.0));
    assert!(data.candidates.is_empty() && full.candidates.is_empty());
    assert_eq!((data.lambda_d, full.lambda_d), (0.0, lambda_d as f64));
    let samples = sample(&st, 64);
    let want = evaluate(
        &tr.model,
        &st,
        &samples,
        DiffusePrior::NONE,
        Hypotheses::default(),
    );
    let mat = |s: &SegmentSample| {
        let b = st.batch(&s.idx);
        tr.model.material(&b.x_unit, &b.part)
    };
    for ((d, f), (s, w)) in data
        .segments
        .iter()
        .zip(&full.segments)
        .zip(samples.iter().zip(&want))
    {
        assert_eq!(d.before, w.own);
        let m = mat(s);
        let prior = (0..s.idx.len())
            .map(|i| ((m.sigma[i] - tr.cfg.prior_sigma).abs() + m.metallic[i]) as f64)
            .sum::<f64>()
            / s.idx.len() as f64;
        assert!(
            (f.before - d.before - lambda_d as f64 * prior).abs() < 1e-6,
            "segment {}: {} − {} vs λ_d·{prior}",
            d.segment,
            f.before,
            d.before
        );
    }
}

/// A hop pulls every candidate's σ towards its target, and the model it returns is the
/// hopped one only when the objective fell (else the very model it was given).
#[test]
fn hop_pulls_and_keeps_only_a_lower_objective() {
    let st = toy_store(400);
    let (cfg, schedule) = toy_fit();
    let run = crate::pipeline::fit::FitRun {
        mode: SegMode::Part,
        schedule: &schedule,
        seed: 5,
        show_progress: false,
    };
    let (tr, _) =
        crate::pipeline::fit::fit_more(toy_trainer(cfg), &st, run.mode, &schedule, 5, false);
    let before = (tr.model.net_params(), tr.model.grid.table.clone());
    // Every segment whose sweep finds anything lower hops; long phases, a strong pull.
    let hc = HopConfig {
        gain: 0.0,
        min_move: 0.0,
        steps: 2.0,
        pull: 10.0,
        pixels: 64,
        prior: 1.0,
        // The sweep's hop alone.
        patch: 0.0,
        ..HopConfig::default()
    };
    let plan = toy_plan(&hc, &schedule, 5e-4, 0.01);
    let (out, rep) = hop(tr, &st, &plan).unwrap();
    assert!(!rep.candidates.is_empty());
    assert_eq!(rep.steps, 2 * 50);
    for c in &rep.candidates {
        assert!(
            (c.sigma_after - c.target).abs() < (c.sigma - c.target).abs(),
            "segment {}: σ {} → {} for target {}",
            c.segment,
            c.sigma,
            c.sigma_after,
            c.target
        );
        if let Some(t) = c.target_metallic {
            assert!(
                (c.metallic_after - t).abs() < (c.metallic - t).abs(),
                "segment {}: m {} → {} for target {t}",
                c.segment,
                c.metallic,
                c.metallic_after
            );
        }
    }
    assert!(rep.objective_after.is_some());
    assert_eq!(rep.segments.len(), 5);
    assert_eq!(rep.accepted, hop_helped(&rep.candidates, hc.gain));
    let now = (out.model.net_params(), out.model.grid.table.clone());
    assert_eq!(now == before, !rep.accepted);
}

/// A config with a patch gain of 2 % and the check of one segment fitted at σ 0.8 whose sweep
/// is flat.
fn one_flat_segment() -> (HopConfig, Vec<SegmentObjective>) {
    let samples = sample(&store(&[0]), 8);
    let cfg = HopConfig {
        patch_gain: 0.02,
        patch_min_move: 0.15,
        ..HopConfig::default()
    };
    (cfg, checks(&samples, &[eval(0.8, 1.0, 0, 1.0)]))
}

/// A patch candidate counts by its own gain and distance, and is kept by its own measure and
/// gain; the other hypotheses keep theirs.
#[test]
fn patch_candidates_have_their_own_thresholds() {
    let (cfg, mut rows) = one_flat_segment();
    // The sweep is flat (no hop of its own); the patch sweep lies 0.2 away.
    let mut with = |patch: (f64, f64, f64)| {
        rows[0].patch = Some(patch);
        candidates(&cfg, &rows)
    };
    let c = with((0.6, 0.97, 1.0));
    assert_eq!(
        (c.len(), c[0].source, c[0].target, c[0].target_metallic),
        (1, Hypothesis::Patch, 0.6, Some(0.0))
    );
    // Measured against the patch objective at the fitted σ, not the fit's own.
    assert_eq!((c[0].objective, c[0].objective_target), (1.0, 0.97));
    // 1 % lower: too little; 0.1 away: too near.
    assert!(with((0.6, 0.99, 1.0)).is_empty());
    assert!(with((0.7, 0.9, 1.0)).is_empty());
    let cand = |source, objective, after| HopCandidate {
        source,
        objective,
        objective_after: after,
        ..c[0].clone()
    };
    let (p, s) = (Hypothesis::Patch, Hypothesis::Sweep);
    let kept = |c: HopCandidate| hop_helped(std::slice::from_ref(&c), thresholds(&cfg, c.source).0);
    assert!(kept(cand(p, 1.0, 0.97)));
    assert!(!kept(cand(p, 1.0, 0.99)));
    // A sweep candidate needs its 5 %, where a patch candidate's 2 % would do.
    assert!(!kept(cand(s, 1.0, 0.97)));
    assert!(kept(cand(s, 1.0, 0.9)));
    // With `patch_dielectric` (the default) it hops as the dielectric it was solved as, m
    // pulled to 0; without it, σ alone.
    let sigma_alone = HopConfig {
        patch_dielectric: false,
        ..cfg.clone()
    };
    let d = candidates(
        &sigma_alone,
        &[SegmentObjective {
            patch: Some((0.6, 0.97, 1.0)),
            ..rows[0].clone()
        }],
    );
    assert_eq!((d.len(), d[0].target, d[0].target_metallic), (1, 0.6, None));
}

/// A segment fitted metallic has no patch candidate unless `patch_metals`; with it, its
/// patch hypothesis counts by the same gain and distance and hops as the metal it was solved
/// as, m pulled to 1.
#[test]
fn a_metal_hops_on_its_patch_only_with_patch_metals() {
    let (cfg, mut rows) = one_flat_segment();
    rows[0].metallic = 0.9;
    rows[0].patch = Some((0.6, 0.9, 1.0));
    assert!(candidates(&cfg, &rows).is_empty());
    let metals = HopConfig {
        patch_metals: true,
        ..cfg.clone()
    };
    let c = candidates(&metals, &rows);
    assert_eq!(
        (c.len(), c[0].source, c[0].target, c[0].target_metallic),
        (1, Hypothesis::Patch, 0.6, Some(1.0))
    );
    assert!(holds_metal(&metals, &c[0]));
    // A dielectric still hops as one.
    rows[0].metallic = 0.1;
    assert_eq!(candidates(&metals, &rows)[0].target_metallic, Some(0.0));
    // Too near is too near for a metal too.
    rows[0].metallic = 0.9;
    rows[0].patch = Some((0.7, 0.9, 1.0));
    assert!(candidates(&metals, &rows).is_empty());
}

/// With `patch_majority` z, a patch hypothesis that lowers the sum but that well under half
/// of many cubes prefer (more than z standard errors below) does not count; over few cubes
/// the same share cannot tell, and counts; z 0 asks for a half whatever the cubes; null lets
/// every share count. A patch candidate that falls back after an undone first hop is held to
/// the same test.
#[test]
fn a_patch_hypothesis_needs_most_of_the_surface() {
    let (cfg, mut rows) = one_flat_segment();
    let cfg = HopConfig {
        patch_majority: Some(2.0),
        ..cfg
    };
    rows[0].patch = Some((0.6, 0.97, 1.0));
    let mut with = |cfg: &HopConfig, share: Option<(f64, f64)>| {
        rows[0].patch_share = share;
        candidates(cfg, &rows).len()
    };
    // 4000 cubes: a fair coin's share lies within 2 × 0.5 / √4000 ≈ 0.016 of a half.
    assert_eq!(with(&cfg, Some((0.46, 4000.0))), 0);
    assert_eq!(with(&cfg, Some((0.49, 4000.0))), 1);
    assert_eq!(with(&cfg, Some((0.6, 4000.0))), 1);
    // 16 cubes: the bound is 0.25.
    assert_eq!(with(&cfg, Some((0.3, 16.0))), 1);
    assert_eq!(with(&cfg, Some((0.2, 16.0))), 0);
    assert_eq!(with(&cfg, None), 1);
    let half = HopConfig {
        patch_majority: Some(0.0),
        ..cfg.clone()
    };
    assert_eq!(with(&half, Some((0.49, 4000.0))), 0);
    assert_eq!(with(&half, Some((0.3, 16.0))), 0);
    assert_eq!(with(&half, Some((0.5, 16.0))), 1);
    assert_eq!(with(&half, Some((0.6, 4000.0))), 1);
    let off = HopConfig {
        patch_majority: None,
        ..cfg.clone()
    };
    assert_eq!(with(&off, Some((0.1, 4000.0))), 1);
    // The metal wins the first hop; its patch fallback passes the same test.
    rows[0].metal = Some((0.3, 0.5, 1.0));
    rows[0].metallic = 0.1;
    let fallbacks = |share: (f64, f64)| {
        let r = SegmentObjective {
            patch_share: Some(share),
            ..rows[0].clone()
        };
        patch_fallbacks(&cfg, &[r]).len()
    };
    assert_eq!(fallbacks((0.6, 4000.0)), 1);
    assert_eq!(fallbacks((0.4, 4000.0)), 0);
}

/// The data term (λ_d 0) of every sampled segment at `tr`'s model.
fn data_at(tr: &Trainer, st: &PixelStore, samples: &[SegmentSample]) -> Vec<SegmentEval> {
    let prior = DiffusePrior {
        lambda_d: 0.0,
        sigma: tr.cfg.prior_sigma,
    };
    evaluate(&tr.model, st, samples, prior, Hypotheses::default())
}

/// A candidate of `source` for the first sampled segment, as `before` has it, hopping to
/// σ `target` (and m `target_metallic`).
fn first_candidate(
    samples: &[SegmentSample],
    before: &[SegmentEval],
    target: f64,
    source: Hypothesis,
    target_metallic: Option<f64>,
) -> HopCandidate {
    HopCandidate {
        segment: samples[0].id,
        pixels: samples[0].size,
        sigma: before[0].sigma,
        target,
        sigma_after: before[0].sigma,
        source,
        metallic: before[0].metallic,
        target_metallic,
        metallic_after: before[0].metallic,
        objective: 1.0,
        objective_target: 0.5,
        objective_after: 1.0,
        plain: false,
        alone: false,
    }
}

/// With `anchor`, the segments that do not hop stay near their σ and m while one segment is
/// pulled far away; without it, the shared networks carry them along.
#[test]
fn the_anchor_holds_the_segments_not_hopping() {
    // Five segments, each a stretch of the toy's curve (apart in space).
    let mut st = toy_store(400);
    for (i, s) in st.pixels.seg.iter_mut().enumerate() {
        *s = (i / 80) as i32;
    }
    let (tr, schedule) = toy_fitted(&st);
    let samples = sample(&st, 80);
    let at = |tr: &Trainer| data_at(tr, &st, &samples);
    let before = at(&tr);
    let held_at: Vec<(i32, f64, f64)> = samples
        .iter()
        .zip(&before)
        .map(|(s, e)| (s.id, e.sigma, e.metallic))
        .collect();
    let target = if before[0].sigma > 0.5 { 0.05 } else { 0.95 };
    let chosen = [first_candidate(
        &samples,
        &before,
        target,
        Hypothesis::Sweep,
        None,
    )];
    let moved = |anchor: f32, guards: &[(i32, f64, f64)]| {
        let hc = HopConfig {
            steps: 2.0,
            pull: 10.0,
            anchor,
            ..HopConfig::default()
        };
        let plan = toy_plan(&hc, &schedule, 5e-4, 0.01);
        let (out, _) = hop_phases(
            tr.clone(),
            &st,
            &plan,
            &chosen,
            guards,
            &held_at,
            Stage::Patch,
        )
        .unwrap();
        let after = at(&out);
        let others = 1..samples.len();
        let drift = others
            .clone()
            .map(|k| {
                (after[k].sigma - before[k].sigma)
                    .abs()
                    .max((after[k].metallic - before[k].metallic).abs())
            })
            .fold(0.0f64, f64::max);
        // How far the hopping segment's σ got from the others', towards its target.
        let mean = others.map(|k| after[k].sigma).sum::<f64>() / (samples.len() - 1) as f64;
        (
            drift,
            (after[0].sigma - mean) * (target - before[0].sigma).signum(),
        )
    };
    // The toy's small networks share most of what σ depends on: free, every segment goes
    // where the pulled one goes.
    let (free, free_apart) = moved(0.0, &[]);
    let (held, held_apart) = moved(10.0, &[]);
    // Guarded (`guard`), the others are pulled where they were as the candidate is to its
    // target, without the anchor.
    let (guarded, guarded_apart) = moved(0.0, &held_at[1..]);
    assert!(
        free > 0.05,
        "without the anchor the others moved only {free}"
    );
    assert!(
        held < 0.5 * free,
        "the others moved {held} with the anchor, {free} without"
    );
    assert!(
        held_apart > free_apart + 0.03,
        "the hopping segment {held_apart} apart from the others held, {free_apart} free"
    );
    assert!(
        guarded < 0.5 * free && guarded_apart > free_apart + 0.03,
        "guarded, the others moved {guarded} (free {free}), the hopping one {guarded_apart} \
         apart (free {free_apart})"
    );
}

/// `guard` names the segments a kept hop harmed: not hopping, their objective up by more
/// than the hop's gain and their σ moved by at least its `min_move` from where they were
/// held; with the σ and m to hold them at.
#[test]
fn the_guard_names_the_segments_a_hop_harmed() {
    let cfg = HopConfig {
        patch_gain: 0.01,
        patch_min_move: 0.15,
        gain: 0.05,
        min_move: 0.25,
        ..HopConfig::default()
    };
    let held_at = [
        (0, 0.9, 0.0),
        (1, 0.3, 0.6),
        (2, 0.9, 0.0),
        (3, 0.9, 0.0),
        (4, 0.5, 0.0),
    ];
    let entering = [1e-3; 5];
    // 2 % worse: past the patch hop's gain (1 %), short of the sweep's (5 %).
    let worse = 1.02e-3;
    let after = [
        // Hopping: it moves and scores worse, and is the hop's to judge.
        eval(0.2, worse, 0, 0.0),
        // Carried off its minimum: moved by 0.26, and worse.
        eval(0.04, worse, 0, 0.0),
        // Moved by 0.3 on flat data: 0.5 % worse.
        eval(0.6, 1.005e-3, 0, 0.0),
        // Worse but 0.1 from where it was held.
        eval(0.8, worse, 0, 0.0),
        // Moved up by 0.3, and worse.
        eval(0.8, worse, 0, 0.0),
    ];
    let got = harmed(&cfg, Hypothesis::Patch, &[0], &entering, &after, &held_at);
    assert_eq!(got, vec![(1, 0.3, 0.6), (4, 0.5, 0.0)]);
    assert!(harmed(&cfg, Hypothesis::Sweep, &[0], &entering, &after, &held_at).is_empty());
    // Without the hopping segment named, it is a bystander like any other.
    let all = harmed(&cfg, Hypothesis::Patch, &[], &entering, &after, &held_at);
    assert_eq!(all[0], (0, 0.9, 0.0));
}

/// With `hold_metals`, a candidate hopping as a metal stays pulled through the release
/// phase: on photos of a dielectric, a metal hop (m 1) ends nearer its target held than
/// released, where the data takes it back. A dielectric candidate is released either way.
#[test]
fn hold_metals_keeps_a_metal_hop_at_its_target() {
    let st = rendered_store(400, 0.3);
    let (tr, mut schedule) = toy_fitted(&st);
    // The hop runs at the schedule's last rate: keep it at the first so the steps move σ.
    schedule.lr_end = 1.0;
    let samples = sample(&st, 400);
    let at = |tr: &Trainer| data_at(tr, &st, &samples);
    let before = at(&tr);
    let target = 0.7;
    let metal = first_candidate(&samples, &before, target, Hypothesis::Metal, Some(1.0));
    let dielectric = HopCandidate {
        source: Hypothesis::Sweep,
        target_metallic: None,
        metallic: 0.0,
        ..metal.clone()
    };
    let base = HopConfig {
        steps: 1.0,
        pull: 1.0,
        anchor: 0.0,
        hold_metals: 0.0,
        ..HopConfig::default()
    };
    let hold = HopConfig {
        hold_metals: 1.0,
        ..base.clone()
    };
    assert!(holds_metal(&hold, &metal) && !holds_metal(&base, &metal));
    assert!(!holds_metal(&hold, &dielectric));
    // A candidate that names no m holds where the fit already has a metal.
    let fitted_metal = HopCandidate {
        metallic: 0.8,
        ..dielectric.clone()
    };
    assert!(holds_metal(&hold, &fitted_metal));
    let hopped = |cfg: &HopConfig, c: &HopCandidate| {
        let plan = toy_plan(cfg, &schedule, 5e-4, 0.01);
        let (out, _) = hop_phases(
            tr.clone(),
            &st,
            &plan,
            std::slice::from_ref(c),
            &[],
            &[],
            Stage::First,
        )
        .unwrap();
        let a = at(&out);
        (a[0].sigma, a[0].metallic)
    };
    let (released, m_released) = hopped(&base, &metal);
    let (held, m_held) = hopped(&hold, &metal);
    // The data (a dielectric) takes a released metal back; held, m stays at its target.
    assert!(
        (1.0 - m_held) + 0.2 < 1.0 - m_released,
        "m {m_held} held, {m_released} released (σ {held} and {released}, for {target})"
    );
    // Held at a weight too small to matter, it ends where released: the weight is the hold's.
    let faint = HopConfig {
        hold_metals: 1e-6,
        ..base.clone()
    };
    let (_, m_faint) = hopped(&faint, &metal);
    assert!(
        (m_faint - m_released).abs() < 0.05,
        "m {m_faint} held at 1e-6, {m_released} released"
    );
    // A dielectric's hop is the same with the key as without.
    assert_eq!(hopped(&base, &dielectric), hopped(&hold, &dielectric));
}

/// `settle` holds a dielectric of a refined round at its patch minimum (and m 0) where that
/// scores lower and lies within `min_move`; anywhere else the anchor keeps the fitted σ.
#[test]
fn settle_holds_at_the_nearby_patch_minimum() {
    let (mut cfg, mut rows) = one_flat_segment();
    (cfg.settle, cfg.anchor, cfg.min_move) = (true, 1e-2, 0.25);
    rows[0].metallic = 0.05;
    rows[0].patch = Some((0.62, 0.99, 1.0));
    assert_eq!(settled(&cfg, true, &rows[0]), Some(0.62));
    // Held as the patch hypothesis is: a dielectric, m 0; unsettled, at its fitted m.
    assert_eq!(anchor_target(Some(0.62), 0.9, 0.05), (0.62, 0.0));
    assert_eq!(anchor_target(None, 0.9, 0.05), (0.9, 0.05));
    // Not on round 0's baked shadings, nor without the anchor or the key.
    assert_eq!(settled(&cfg, false, &rows[0]), None);
    let off = |f: fn(&mut HopConfig)| {
        let mut c = cfg.clone();
        f(&mut c);
        settled(&c, true, &rows[0])
    };
    assert_eq!(off(|c| c.anchor = 0.0), None);
    assert_eq!(off(|c| c.settle = false), None);
    // A near minimum that scores no lower than the fitted σ: the minimum is the fit's σ,
    // held there as a dielectric, m 0.
    rows[0].patch = Some((0.78, 1.0, 1.0));
    assert_eq!(settled(&cfg, true, &rows[0]), Some(0.8));
    // One a hop's distance away, and a metal: held as fitted.
    rows[0].patch = Some((0.5, 0.9, 1.0));
    assert_eq!(settled(&cfg, true, &rows[0]), None);
    // That far hypothesis, where most of the surface prefers the fit (`patch_majority`):
    // held at its fitted σ as a dielectric, m 0; without the test, as fitted.
    let lost = SegmentObjective {
        patch_share: Some((0.4, 4000.0)),
        ..rows[0].clone()
    };
    assert_eq!(settled(&cfg, true, &lost), Some(0.8));
    let untested = HopConfig {
        patch_majority: None,
        ..cfg.clone()
    };
    assert_eq!(settled(&untested, true, &lost), None);
    rows[0].patch = Some((0.62, 0.9, 1.0));
    rows[0].metallic = 0.7;
    assert_eq!(settled(&cfg, true, &rows[0]), None);
}

/// A segment whose metal hypothesis wins keeps its patch hypothesis as a fallback for the
/// second hop; one whose patch hypothesis wins, or whose patch does not count, has none.
#[test]
fn an_undone_hop_falls_back_to_the_patch() {
    let (cfg, mut rows) = one_flat_segment();
    // The metal (σ 0.3, m 1) halves its baseline; the patch (σ 0.1) gains 13 %.
    rows[0].metallic = 0.1;
    rows[0].metal = Some((0.3, 0.5, 1.0));
    rows[0].patch = Some((0.1, 0.87, 1.0));
    let c = candidates(&cfg, &rows);
    assert_eq!((c.len(), c[0].source), (1, Hypothesis::Metal));
    let f = patch_fallbacks(&cfg, &rows);
    assert_eq!(
        (f.len(), f[0].source, f[0].target, f[0].objective),
        (1, Hypothesis::Patch, 0.1, 1.0)
    );
    // The patch gains more than the metal: it is the candidate, and no fallback.
    rows[0].patch = Some((0.1, 0.4, 1.0));
    assert_eq!(candidates(&cfg, &rows)[0].source, Hypothesis::Patch);
    assert!(patch_fallbacks(&cfg, &rows).is_empty());
    // A patch that does not count (1 % lower) is no fallback either.
    rows[0].patch = Some((0.1, 0.99, 1.0));
    assert_eq!(candidates(&cfg, &rows)[0].source, Hypothesis::Metal);
    assert!(patch_fallbacks(&cfg, &rows).is_empty());
}

/// One segment of `n` pixels in four cubes, one base colour per cube, dielectric, whose
/// photos are the factorised render at σ `truth`.
fn rendered_store(n: usize, truth: f32) -> PixelStore {
    rendered_store_m(n, truth, 0.0)
}

/// `rendered_store` at metallic `m`.
fn rendered_store_m(n: usize, truth: f32, m: f32) -> PixelStore {
    let mut st = toy_store(n);
    st.pixels.seg.iter_mut().for_each(|s| *s = 0);
    let d = ShadingLayout::DIM;
    for i in 0..n {
        let cube = i % 4;
        st.pixels.x_world[i] = [0.1 + cube as f32, 0.5, 0.5];
        for j in 0..fipt_core::brdf::ROUGHNESS_LEVELS {
            for c in 0..3 {
                let v = 0.2 + ((i * 7 + j * 13 + c * 5) % 11) as f32 / 11.0;
                st.pixels.shadings[i * d + ShadingLayout::ls0(j).start + c] = 3.0 * v;
                st.pixels.shadings[i * d + ShadingLayout::ls1(j).start + c] = 0.1 * v;
            }
        }
        let sh = ShadingLayout::pixel(&st.pixels.shadings, i).to_vec();
        let a = glam::Vec3::new(0.2 + 0.2 * cube as f32, 0.4, 0.3);
        let (kd, ks) = reflectances(a, m);
        let c = factorised_render(kd.to_array(), ks.to_array(), truth, &sh);
        st.pixels.gt[3 * i..3 * i + 3].copy_from_slice(&c);
    }
    st
}

/// On photos rendered at σ 0.3 with one colour per cube, the patch sweep proposes σ near
/// 0.3 for a fit that is not there, and the hop takes the segment most of the way there.
#[test]
fn the_patch_hypothesis_finds_the_rendered_roughness() {
    let truth = 0.3;
    let st = rendered_store(400, truth);
    let (tr, mut schedule) = toy_fitted(&st);
    // The hop runs at the schedule's last rate: keep it at the first so 50 steps can move σ.
    schedule.lr_end = 1.0;
    let hc = HopConfig {
        gain: 1.0,
        metal: false,
        patch: 1.0,
        patch_gain: 0.0,
        patch_min_move: 0.0,
        steps: 1.0,
        pull: 10.0,
        ..HopConfig::default()
    };
    let plan = toy_plan(&hc, &schedule, 5e-4, 1.0);
    let (_, rep) = hop(tr, &st, &plan).unwrap();
    let (best, obj, at_fit) = rep.segments[0].patch.expect("patch profile");
    assert!((best - truth as f64).abs() < 0.05, "best σ {best}");
    assert!(obj < 0.5 * at_fit, "{obj} vs {at_fit}");
    let c = &rep.candidates[0];
    assert_eq!(c.source, Hypothesis::Patch);
    assert!(
        (c.sigma_after - c.target).abs() < 0.5 * (c.sigma - c.target).abs(),
        "{} → {} for {}",
        c.sigma,
        c.sigma_after,
        c.target
    );
    // Its own hop, with its own decision; no other hop ran.
    assert_eq!(
        rep.patch_accepted,
        Some(hop_helped(&rep.candidates, hc.patch_gain))
    );
    assert!(!rep.accepted);
    assert_eq!(rep.steps, 2 * 25);
}

/// On a metal's photos (m 1, σ 0.3, one colour per cube), the patch sweep solved as a metal
/// (`patch_metals`) puts its best σ near 0.3 and scores there below half its objective at
/// the fitted σ; solved as a dielectric, as without the key, it scores worse at its best.
#[test]
fn the_patch_hypothesis_as_a_metal_finds_a_metals_roughness() {
    let truth = 0.3;
    let st = rendered_store_m(400, truth, 1.0);
    let (tr, _) = toy_fitted(&st);
    // Cubes of side 1: the store's four.
    let p = PatchSegments::new(&st, 1.0);
    let profile = |metal: bool| p.profile(&tr.model, 0, metal).expect("patch profile").0;
    let (best, obj, at_fit) = profile(true);
    assert!((best - truth as f64).abs() < 0.05, "best σ {best}");
    assert!(obj < 0.5 * at_fit, "{obj} vs {at_fit}");
    let (_, as_dielectric, _) = profile(false);
    assert!(obj < 0.5 * as_dielectric, "{obj} vs {as_dielectric}");
}
