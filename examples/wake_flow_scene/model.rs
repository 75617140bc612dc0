//! Saved correctors of the wake scene: the settings that shape one, and
//! `wake_flow evaluate`, which rolls a saved corrector out at any Reynolds
//! number in range against a reference generated (or read from the cache) on
//! the fly, without training.

use std::path::Path;

use diffphys::flow::{PressureSolver, Splitting};
use diffphys::learn::study::run_jobs;
use diffphys::learn::{DataSeed, Hybrid, ModelCard, SavedModel, Split, TrainSeed};
use diffphys::nn::Arithmetic;
use serde_json::{json, Map, Value};

use super::data::{self, base_state, reference, Bump, Reference};
use super::study::held_out_re;
use super::{
    advection_label, arithmetic_label, net, reference_scene, splitting_label, uncorrected, Coarse,
    NetSize, Result, Sizes, WakeError, RE_CENTRE,
};
use diffphys::hybrid::reference::Rollouts;

/// The kind of model the scene saves.
pub const KIND: &str = "wake_flow corrector";

/// The settings a saved corrector of `size` must match: the coarse grid and
/// time step, its advection, the body, the reference it was trained against,
/// the corrector's architecture and arithmetic, the centre of its Re input.
pub fn card(sizes: &Sizes, size: NetSize, arithmetic: Arithmetic) -> ModelCard {
    let card = ModelCard::new(KIND);
    // The default adds nothing, so correctors saved before the option stay
    // readable.
    let card = match sizes.splitting {
        Splitting::Plain => card,
        other => card.setting("coarse_splitting", splitting_label(other)),
    };
    card.setting("grid_coarse", [sizes.ny, sizes.nx])
        .setting("dt_coarse", sizes.dt)
        .setting("coarse_advection", advection_label(sizes.advection))
        .setting("body", sizes.body.label())
        .setting("reference_scheme", sizes.reference.label())
        .setting("corrector", size.label())
        .setting("network_arithmetic", arithmetic_label(arithmetic))
        .setting("re_centre", RE_CENTRE)
}

/// What `wake_flow evaluate` is asked.
pub struct Evaluation<'a> {
    /// The saved model's directory.
    pub model: &'a Path,
    /// The scene's sizes (as for training: `--small`, `--body`, ...).
    pub sizes: &'a Sizes,
    /// The corrector's arithmetic (`--network-arithmetic`).
    pub arithmetic: Arithmetic,
    /// The Reynolds numbers to evaluate at.
    pub re: &'a [f64],
    /// The data seed whose held-out stream draws the start state (default:
    /// the one the model was trained with).
    pub data_seed: Option<u64>,
    /// Where the reference cache lives.
    pub out: &'a Path,
    /// Worker threads.
    pub threads: usize,
}

/// Evaluates a saved corrector: the uncorrected and the corrected coarse
/// solver rolled out at each Reynolds number, and, where the training run
/// measured the same Re, whether the figures are the same to the bit.
///
/// # Errors
/// [`WakeError::Learn`] with [`diffphys::learn::LearnError::SettingsMismatch`]
/// naming the field where the model does not fit the scene, or
/// [`diffphys::learn::LearnError::Model`] for a missing or broken model;
/// whatever the reference and the rollouts return.
pub fn evaluate(e: &Evaluation<'_>) -> Result<Value> {
    let saved = SavedModel::open(e.model)?;
    let corrector = saved
        .card
        .settings
        .get("corrector")
        .and_then(Value::as_str)
        .ok_or_else(|| WakeError::Argument {
            option: "--model".into(),
            message: "the saved model names no corrector size".into(),
        })?;
    let size: NetSize = corrector.parse()?;
    saved.card.check(&card(e.sizes, size, e.arithmetic))?;
    let coarse = Coarse::new(uncorrected(e.sizes, 1, PressureSolver::Cholesky)?);
    let fine = reference_scene(e.sizes)?;
    // The corrector's layers (each worker builds its own: a hybrid is not
    // shared between threads), with the saved parameters.
    let new_net = || {
        net(
            coarse.scene(),
            size,
            e.arithmetic,
            &mut TrainSeed(0).init_rng(),
        )
    };
    let (_, mut params) = new_net()?;
    saved.load_params(&mut params)?;
    let data_seed = e
        .data_seed
        .or_else(|| {
            saved
                .card
                .provenance
                .get("data_seed")
                .and_then(Value::as_u64)
        })
        .unwrap_or(1);

    // The held-out stream's start state, as training drew it.
    let cache = data::cache(e.out, e.sizes)?;
    let bump = Bump::draw(&mut DataSeed(data_seed).rng(Split::HeldOut));
    let base = base_state(&cache, e.sizes, &fine, bump, &|_| {})?;
    let refs: Vec<Reference> = run_jobs(e.re, e.threads, |&re| {
        reference(
            &cache,
            e.sizes,
            coarse.scene(),
            &fine,
            (&base, bump),
            re,
            &|_| {},
        )
    })?;
    let runs: Vec<(Rollouts, Rollouts)> = run_jobs(&refs, e.threads, |r| {
        let hybrid = Hybrid::new(coarse.clone(), new_net()?.0);
        Ok::<_, WakeError>((
            held_out_re(&hybrid, None, r, e.sizes)?,
            held_out_re(&hybrid, Some(&params), r, e.sizes)?,
        ))
    })?;

    let trained: Option<&Map<String, Value>> = saved
        .card
        .provenance
        .get("held_out_per_re")
        .and_then(Value::as_object);
    let mut per_re = Map::new();
    let mut compared = 0;
    let mut identical = 0;
    for (src, corrected) in &runs {
        let before = trained.and_then(|t| t.get(&corrected.re.to_string()));
        let same = before.map(|b| {
            let bits = |k: &str| b.get(k).and_then(Value::as_f64).map(f64::to_bits);
            bits("mean") == Some(corrected.mean.to_bits())
                && bits("long") == Some(corrected.long.to_bits())
                && [
                    ("deviation", corrected.deviation),
                    ("vorticity", corrected.vorticity),
                ]
                .iter()
                .all(|&(k, v)| b.get(k).is_none() || bits(k) == Some(v.to_bits()))
        });
        compared += usize::from(same.is_some());
        identical += usize::from(same == Some(true));
        println!(
            "  Re {:>6}: corrected {:.5}, uncorrected {:.5}, ratio {:.3}{}",
            corrected.re,
            corrected.mean,
            src.mean,
            corrected.mean / src.mean,
            match same {
                Some(true) => " (the training run's figure, to the bit)",
                Some(false) => " (DIFFERS from the training run's figure)",
                None => "",
            }
        );
        per_re.insert(
            corrected.re.to_string(),
            json!({
                "mean": corrected.mean,
                "long": corrected.long,
                "deviation": corrected.deviation,
                "vorticity": corrected.vorticity,
                "src_mean": src.mean,
                "src_long": src.long,
                "src_deviation": src.deviation,
                "src_vorticity": src.vorticity,
                "ratio_to_src": corrected.mean / src.mean,
                "same_bits_as_training": same,
            }),
        );
    }
    Ok(json!({
        "model": e.model.display().to_string(),
        "commit": saved.commit,
        "settings": saved.card.settings,
        "provenance": saved.card.provenance,
        "data_seed": data_seed,
        "parameters": params.count(),
        "per_re": per_re,
        "compared_with_training": compared,
        "identical_to_training": identical,
    }))
}
