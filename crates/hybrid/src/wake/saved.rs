//! Saved correctors of a wake scene: the settings that shape one, and the
//! evaluation of a saved corrector at any Reynolds number in range against
//! a reference generated (or read from the cache) on the fly, without
//! training.

use std::path::Path;

use diffphys_flow::{PressureSolver, Splitting};
use diffphys_learn::study::run_jobs;
use diffphys_learn::{DataSeed, Hybrid, LearnError, ModelCard, SavedModel, Split, TrainSeed};
use diffphys_nn::Arithmetic;
use serde_json::{json, Map, Value};

use super::{name_in, Wake, ADVECTIONS, ARITHMETICS, SPLITTINGS};
use crate::reference::{Reference, Rollouts};
use crate::{FlowSimulator, HybridError, LatticeNet, NetSize, ParamCode, Result};

/// The kind of model a wake scene saves.
pub const KIND: &str = "wake_flow corrector";

/// What [`Wake::evaluate`] is asked.
pub struct Evaluation<'a> {
    /// The saved model's directory.
    pub model: &'a Path,
    /// The corrector's code of each sample's viscosity.
    pub code: ParamCode,
    /// The corrector's arithmetic.
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

impl Wake {
    /// The settings a saved corrector of `size` must match: the coarse grid
    /// and time step, its advection (and splitting where not plain), the
    /// body, the reference it was trained against, the corrector's
    /// architecture and arithmetic, the centre of its Re input.
    pub fn card(&self, size: NetSize, arithmetic: Arithmetic) -> ModelCard {
        let s = &self.sizes;
        let card = ModelCard::new(KIND);
        // The default adds nothing, so correctors saved before the option
        // stay readable.
        let card = match s.splitting {
            Splitting::Plain => card,
            other => card.setting("coarse_splitting", name_in(&SPLITTINGS, other)),
        };
        card.setting("grid_coarse", [s.ny, s.nx])
            .setting("dt_coarse", s.dt)
            .setting("coarse_advection", name_in(&ADVECTIONS, s.advection))
            .setting("body", s.body.label())
            .setting("reference_scheme", s.reference.label())
            .setting("corrector", size.label())
            .setting("network_arithmetic", name_in(&ARITHMETICS, arithmetic))
            .setting("re_centre", self.channel.re_centre)
    }

    /// Evaluates a saved corrector: the uncorrected and the corrected coarse
    /// solver rolled out at each Reynolds number, and, where the training
    /// run measured the same Re, whether the figures are the same to the
    /// bit (keys `compared_with_training`, `identical_to_training`).
    ///
    /// # Errors
    /// [`LearnError::SettingsMismatch`] naming the field where the model
    /// does not fit the scene, or [`LearnError::Model`] for a missing or
    /// broken model; whatever the reference and the rollouts return.
    pub fn evaluate(&self, e: &Evaluation<'_>) -> Result<Value> {
        let saved = SavedModel::open(e.model)?;
        let corrector = saved
            .card
            .settings
            .get("corrector")
            .and_then(Value::as_str)
            .ok_or_else(|| LearnError::Model {
                path: e.model.to_path_buf(),
                message: "the saved model names no corrector size".into(),
            })?;
        let size: NetSize = corrector.parse()?;
        saved.card.check(&self.card(size, e.arithmetic))?;
        let coarse = FlowSimulator::new(self.uncorrected(1, PressureSolver::Cholesky)?);
        let fine = self.reference_scene()?;
        // The corrector's layers (each worker builds its own: a hybrid is
        // not shared between threads), with the saved parameters.
        let new_net = || {
            let rng = &mut TrainSeed(0).init_rng();
            LatticeNet::new(coarse.scene(), size, e.code, e.arithmetic, rng)
        };
        let (_, mut params) = new_net()?;
        saved.load_params(&mut params)?;
        let provenance_seed = saved.card.provenance.get("data_seed");
        let data_seed = (e.data_seed)
            .or_else(|| provenance_seed.and_then(Value::as_u64))
            .unwrap_or(1);

        // The held-out stream's start state, as training drew it.
        let cache = self.cache(e.out)?;
        let bump = self.draw_bump(&mut DataSeed(data_seed).rng(Split::HeldOut));
        let base = self.base_state(&cache, &fine, bump, &|_| {})?;
        let refs: Vec<Reference> = run_jobs(e.re, e.threads, |&re| {
            self.reference(&cache, (coarse.scene(), &fine), (&base, bump), re, &|_| {})
        })?;
        let runs: Vec<(Rollouts, Rollouts)> = run_jobs(&refs, e.threads, |r| {
            let hybrid = Hybrid::new(coarse.clone(), new_net()?.0);
            Ok::<_, HybridError>((
                self.rollouts(&hybrid, None, r)?,
                self.rollouts(&hybrid, Some(&params), r)?,
            ))
        })?;
        let trained = saved.card.provenance.get("held_out_per_re");
        let (per_re, compared, identical) =
            compare_with_training(trained.and_then(Value::as_object), &runs);
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
}

/// Each Re's figures (corrected and uncorrected) beside the training run's
/// (`trained`, keyed by Re), printed and as JSON: `(per Re, compared,
/// identical to the bit)`.
fn compare_with_training(
    trained: Option<&Map<String, Value>>,
    runs: &[(Rollouts, Rollouts)],
) -> (Map<String, Value>, usize, usize) {
    let mut per_re = Map::new();
    let (mut compared, mut identical) = (0, 0);
    for (src, corrected) in runs {
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
    (per_re, compared, identical)
}
