//! A hybrid flow study, one data seed at a time: the untrained baselines,
//! the learning-rate pilots, the plan (every variant at the main corrector
//! size, `non` and the first SOL at the capacity sweep's sizes, every
//! training seed), the trainings, selection on validation, each trained model
//! read once on the held-out split, and every model saved with the settings
//! that shaped it.
//!
//! A scene states its geometry and its options as a [`Setup`] and generates
//! its references ([`crate::reference::Recorder`]); [`Setup::untrained`] and
//! [`Setup::protocol`] do the rest for each data seed, into one [`Record`]
//! (the study's [`Log`](diffphys_learn::study::Log), the held-out
//! [`Results`], the capacity sweep).

mod record;

pub use record::{
    dir_name, HeldOutRun, Record, Results, DEVIATION, LONG, METRICS, STATE, SWEEP_FIGURES,
    VORTICITY,
};

use std::path::PathBuf;

use diffphys_learn::study::{
    run_jobs, Entry, Outcome, Plan, Protocol, Run, SweepRun, TrainJob, TrainedRun, Trainings,
    Variant,
};
use diffphys_learn::{
    rollout, rollout_each, HeldOut, Hybrid, LrSchedule, ModelCard, SavedModel, Splits, TrainSeed,
    Trajectory,
};
use diffphys_nn::{Arithmetic, Params};
use diffphys_report::{progress_bar, Progress};
use serde_json::json;

use crate::reference::{evaluate, Evaluation, Reference, Rollouts};
use crate::{FlowSimulator, HybridError, LatticeNet, NetSize, ParamCode, Result};

/// A trained corrector of the study.
pub type Model = TrainedRun<NetSize>;

/// The selected SOL corrector of a data seed: its parameters and size.
pub type Probe = (Params<f64>, NetSize);

/// What a hybrid flow study is: the coarse solver and its corrector, what is
/// trained with which budget, how the held-out split is rolled out, where
/// the models go.
pub struct Setup<'a> {
    /// The coarse solver the corrector is trained through.
    pub coarse: &'a FlowSimulator,
    /// The corrector's code of each sample's viscosity.
    pub code: ParamCode,
    /// The corrector's convolution arithmetic.
    pub arithmetic: Arithmetic,
    /// The variants (`src` always runs untrained).
    pub variants: &'a [Variant],
    /// The main variants' corrector size.
    pub main_size: NetSize,
    /// The capacity sweep's other sizes (`non` and the first SOL at each).
    pub capacity: &'a [NetSize],
    /// The learning rates the pilots choose from.
    pub learning_rates: &'a [f64],
    /// Every entry of the plan trains from each of these.
    pub train_seeds: &'a [u64],
    /// The budget of each training: corrector evaluations.
    pub evaluations: usize,
    /// Corrector evaluations per Adam step, at least.
    pub step_evaluations: usize,
    /// A pilot trains on the budget over this.
    pub pilot_divisor: usize,
    /// Validate every this many corrector evaluations.
    pub validation_evaluations: usize,
    /// How the learning rate changes over a training.
    pub schedule: LrSchedule,
    /// SOL unrolls longer than this are checkpointed every this many steps.
    pub checkpoint: Option<usize>,
    /// The rollouts of the validation (`rollout` steps from step 0) and
    /// held-out splits.
    pub evaluation: Evaluation<'a>,
    /// How many held-out conditions each data seed has (the length of
    /// the held-out progress bar).
    pub held_out_conditions: usize,
    /// Trainings and rollouts run at once.
    pub threads: usize,
    /// Develop on validation only: the held-out split is not read.
    pub validation_only: bool,
    /// Where the trained models are saved.
    pub models: PathBuf,
    /// The settings a saved corrector of a size must match.
    pub card: &'a (dyn Fn(NetSize) -> ModelCard + Sync),
    /// `Some(body)`: the body was built so that the reference carries no
    /// flow on faces the coarse step pins; a pinned-face error above 1e-12
    /// is refused naming it.
    pub pinned_must_vanish: Option<&'static str>,
}

impl Setup<'_> {
    /// A corrector of `size` drawn from training seed `seed`.
    ///
    /// # Errors
    /// [`HybridError::Nn`] for a size the network refuses.
    pub fn net(&self, size: NetSize, seed: u64) -> Result<(LatticeNet, Params<f64>)> {
        LatticeNet::new(
            self.coarse.scene(),
            size,
            self.code,
            self.arithmetic,
            &mut TrainSeed(seed).init_rng(),
        )
    }

    /// The first SOL variant listed (the capacity sweep's and the pilots').
    pub fn first_sol(&self) -> Option<Variant> {
        self.variants.iter().copied().find(Variant::is_sol)
    }

    /// The training and validation trajectories of data seed `ds`, the
    /// noise scale (the coarse solver's one-step RMS error), the error on
    /// the faces the coarse step pins, and `src`'s validation, into `rec`.
    ///
    /// # Errors
    /// [`HybridError::PinnedFaces`] (see [`Setup::pinned_must_vanish`]);
    /// whatever the windows and rollouts return.
    pub fn untrained(
        &self,
        ds: u64,
        splits: &Splits<Vec<Reference>>,
        rec: &mut Record,
    ) -> Result<(Vec<Trajectory>, Vec<Trajectory>, f64)> {
        let coarse = self.coarse;
        let rollout_steps = self.evaluation.rollout;
        let train: Vec<Trajectory> = (splits.train.iter())
            .map(|r| r.window(coarse.scene(), 0, r.states.len()))
            .collect::<Result<_>>()?;
        let validation: Vec<Trajectory> = (splits.validation.iter())
            .map(|r| r.window(coarse.scene(), 0, rollout_steps + 1))
            .collect::<Result<_>>()?;
        let sigma = coarse.one_step_rms(&train, 10)?;
        // What no corrector can remove: the pinned faces' error.
        let mut pinned = Vec::new();
        for (r, t) in
            (splits.train.iter().zip(&train)).chain(splits.validation.iter().zip(&validation))
        {
            pinned.push((r.re, coarse.pinned_face_error(t)?));
        }
        println!(
            "  error on the faces the coarse step pins (no corrector removes it), per train and validation Re: {}",
            pinned
                .iter()
                .map(|(re, e)| format!("{re}: {e:.4}"))
                .collect::<Vec<_>>()
                .join(", ")
        );
        if let Some(body) = self.pinned_must_vanish {
            if let Some(&(re, error)) = pinned.iter().find(|(_, e)| *e > 1e-12) {
                return Err(HybridError::PinnedFaces { body, re, error });
            }
        }
        rec.pinned_face_error.insert(
            format!("data_{ds}"),
            (pinned.iter())
                .map(|(re, e)| (re.to_string(), json!(e)))
                .collect(),
        );
        rec.sigma = sigma;
        let (net0, _) = self.net(self.main_size, 0)?;
        let hybrid = Hybrid::new(coarse.clone(), net0);
        let src_val = rollout(&hybrid, None, &validation, rollout_steps)?.mean();
        let src_per_re = rollout_each(&hybrid, None, &validation, rollout_steps)?;
        let per_re: Vec<(String, f64)> = (splits.validation.iter())
            .map(|r| r.re.to_string())
            .zip(src_per_re.iter().copied())
            .collect();
        rec.log.baseline("src", ds, src_val, &per_re);
        println!("  noise sigma (one-step RMS error of the coarse solver) {sigma:.2e}; src validation {src_val:.4} (per Re {src_per_re:.4?})");
        Ok((train, validation, sigma))
    }

    /// The trainings of data seed `ds`: the learning rates on validation,
    /// then the library's protocol over the plan (every entry at every
    /// training seed, selection on validation, each trained model once on
    /// the held-out split, saved); the selected SOL corrector for the speed
    /// study.
    ///
    /// # Errors
    /// Whatever the trainings, rollouts and saves return.
    pub fn protocol(
        &self,
        ds: u64,
        splits: &Splits<Vec<Reference>>,
        (train, validation): (&[Trajectory], &[Trajectory]),
        sigma: f64,
        rec: &mut Record,
    ) -> Result<Option<Probe>> {
        let corrector = |size: NetSize, seed: TrainSeed| self.net(size, seed.0);
        let trainings = Trainings {
            simulator: self.coarse,
            corrector: &corrector,
            schedule: self.schedule,
            step_evaluations: self.step_evaluations,
            checkpoint: self.checkpoint,
            validation_steps: self.evaluation.rollout,
            validation_evaluations: self.validation_evaluations,
            sigma,
            train,
            validation,
            label: format!("data {ds}"),
        };
        let first_seed =
            *self
                .train_seeds
                .first()
                .ok_or_else(|| diffphys_learn::LearnError::Invalid {
                    what: "study",
                    message: "no training seed".into(),
                })?;
        // The learning rate of `non` (and `noise`) and of SOL, on
        // validation: pilots on a fraction of the budget, first seed.
        let pilot = (
            self.main_size,
            TrainSeed(first_seed),
            self.evaluations.div_ceil(self.pilot_divisor.max(1)),
        );
        let lrs =
            trainings.learning_rates(self.variants, self.learning_rates, pilot, self.threads)?;
        lrs.record(ds, &mut rec.log.learning_rates);
        let plan = self.plan();
        let held_out_jobs = if self.validation_only {
            0
        } else {
            self.held_out_conditions * (1 + plan.jobs().len())
        };
        let bar = progress_bar(held_out_jobs, &format!("data {ds}: held-out"));
        if !self.validation_only {
            let (src, reference_last) = self.baselines(splits.held_out(), &bar)?;
            rec.results.record("src", ds, None, &src)?;
            rec.results
                .last
                .entry("reference".into())
                .or_insert(reference_last);
        }
        let train_job = |j: &diffphys_learn::study::Job<Variant, NetSize>| {
            trainings.train(&TrainJob {
                variant: j.variant,
                size: j.size,
                seed: j.seed,
                lr: lrs.of(j.variant),
                evaluations: self.evaluations,
            })
        };
        // Selection on validation only: every SOL variant trained, at every
        // size, competes (the unroll and the corrector's size are both
        // chosen here); the others stand alone. Then the held-out split,
        // each trained model once.
        let protocol = Protocol {
            plan: &plan,
            threads: self.threads,
        };
        let score = |m: &Model| m.trained.model.validation;
        let competes = |e: &Entry<Variant, NetSize>| e.variant.is_sol();
        let outcomes: Vec<Outcome<Variant, NetSize, Model, Option<HeldOutRun>>> =
            if self.validation_only {
                let selected = protocol.select(train_job, score, competes)?;
                (selected.into_iter())
                    .map(|o| o.map_held_out(|()| None))
                    .collect()
            } else {
                let evaluated = protocol.run(
                    splits.held_out(),
                    train_job,
                    score,
                    competes,
                    |_, models, refs| {
                        let models: Vec<_> = (models.iter())
                            .map(|m| (Some(&m.trained.model.params), m.job.size, m.job.seed.0))
                            .collect();
                        self.held_out_runs(&models, refs, &bar)
                    },
                )?;
                (evaluated.into_iter())
                    .map(|o| o.map_held_out(Some))
                    .collect()
            };
        bar.finish_and_clear();
        let conditions: Vec<String> = (splits.validation.iter())
            .map(|r| r.re.to_string())
            .collect();
        for &(variant, size) in &plan.entries {
            let entry = Entry { variant, size };
            for o in outcomes.iter().filter(|o| o.entry == entry) {
                for r in &o.runs {
                    rec.log.training(ds, &r.model, self.main_size, &conditions);
                }
            }
        }
        let res = |list: &[Reference]| list.iter().map(|r| r.re).collect::<Vec<f64>>();
        let trained_on = (res(&splits.train), res(&splits.validation));
        let mut probe = None;
        for o in &outcomes {
            if o.selected() && o.entry.variant.is_sol() {
                rec.log.selected(ds, o.entry.variant, o.entry.size);
            }
            for r in &o.runs {
                self.save_and_record(ds, o, r, &trained_on, rec)?;
                if o.selected() && probe.is_none() {
                    probe = Some((r.model.trained.model.params.clone(), o.entry.size));
                }
            }
        }
        if !self.validation_only {
            rec.log
                .held_out_readings
                .insert(ds, splits.held_out().readings());
        }
        Ok(probe)
    }

    /// Every variant at the main size and, for the capacity sweep, `non` and
    /// the first SOL at the other sizes; every training seed. The larger
    /// sweep sizes first and the smaller last, so that the workers finish
    /// together.
    pub fn plan(&self) -> Plan<Variant, NetSize> {
        let sol = self.first_sol();
        let mut plan: Vec<(Variant, NetSize)> = Vec::new();
        let mut sweep = self.capacity.to_vec();
        sweep.sort_by_key(|s| std::cmp::Reverse(s.cost()));
        let (larger, smaller): (Vec<NetSize>, Vec<NetSize>) =
            sweep.iter().partition(|s| s.cost() > self.main_size.cost());
        let both = |plan: &mut Vec<(Variant, NetSize)>, size| {
            for variant in [Some(Variant::Non), sol].into_iter().flatten() {
                plan.push((variant, size));
            }
        };
        for size in larger {
            both(&mut plan, size);
        }
        for &variant in self.variants.iter().filter(|v| **v != Variant::Src) {
            plan.push((variant, self.main_size));
        }
        for size in smaller {
            both(&mut plan, size);
        }
        Plan::new(
            plan,
            self.train_seeds.iter().map(|&s| TrainSeed(s)).collect(),
        )
    }

    /// The rollouts of the hybrid with `params` (`None`: the coarse solver
    /// alone) on one held-out reference ([`evaluate`]).
    ///
    /// # Errors
    /// Whatever the rollouts return.
    pub fn held_out_re(
        &self,
        hybrid: &Hybrid<FlowSimulator, LatticeNet>,
        params: Option<&Params<f64>>,
        r: &Reference,
    ) -> Result<Rollouts> {
        evaluate(hybrid, params, r, &self.evaluation)
    }

    /// The held-out runs of `models` (parameters, size, seed) at every
    /// held-out Re: each model at each Re is one job, and the workers share
    /// them.
    fn held_out_runs(
        &self,
        models: &[(Option<&Params<f64>>, NetSize, u64)],
        refs: &[Reference],
        bar: &(dyn Progress + Sync),
    ) -> Result<Vec<HeldOutRun>> {
        let jobs: Vec<(usize, usize)> = (0..models.len())
            .flat_map(|m| (0..refs.len()).map(move |r| (m, r)))
            .collect();
        let runs = run_jobs(&jobs, self.threads, |&(m, r)| {
            let (params, size, seed) = models[m];
            let (net, _) = self.net(size, seed)?;
            let h = Hybrid::new(self.coarse.clone(), net);
            let run = self.held_out_re(&h, params, &refs[r])?;
            bar.inc(1);
            Ok::<_, HybridError>(run)
        })?;
        let mut runs = runs.into_iter();
        Ok((0..models.len())
            .map(|_| HeldOutRun {
                per_re: runs.by_ref().take(refs.len()).collect(),
            })
            .collect())
    }

    /// The baselines' held-out readings: `src` (the uncorrected coarse
    /// solver) and the reference's state after the long rollout (for the
    /// charts).
    fn baselines(
        &self,
        held_out: &HeldOut<Vec<Reference>>,
        bar: &(dyn Progress + Sync),
    ) -> Result<(HeldOutRun, diffphys_flow::FlowState<f64>)> {
        let invalid = |e: HybridError| diffphys_learn::LearnError::Invalid {
            what: "held-out",
            message: e.to_string(),
        };
        let src = held_out
            .evaluate_baseline(|refs| {
                self.held_out_runs(&[(None, self.main_size, 0)], refs, bar)
                    .map_err(invalid)
            })?
            .remove(0);
        let long = self.evaluation.long;
        let last = held_out.evaluate_baseline(|refs| Ok(refs[0].states[long].clone()))?;
        Ok((src, last))
    }

    /// What a trained model leaves: its saved model (with the settings and
    /// figures that describe it) and, when the held-out split was read, the
    /// capacity sweep's entry and the report's.
    fn save_and_record(
        &self,
        ds: u64,
        o: &Outcome<Variant, NetSize, Model, Option<HeldOutRun>>,
        r: &Run<Model, Option<HeldOutRun>>,
        (train_re, validation_re): &(Vec<f64>, Vec<f64>),
        rec: &mut Record,
    ) -> Result<()> {
        let m = &r.model;
        let (job, t) = (&m.job, &m.trained.model);
        let mut card = (self.card)(job.size)
            .provenance("variant", job.variant.name())
            .provenance("chosen_on_validation", o.chosen)
            .provenance("data_seed", ds)
            .provenance("train_seed", job.seed.0)
            .provenance("learning_rate", job.lr)
            .provenance("corrector_evaluations", job.evaluations)
            .provenance("kept_iteration", t.best_iteration)
            .provenance("validation", t.validation)
            .provenance("train_re", train_re)
            .provenance("validation_re", validation_re);
        if let Some(run) = &r.held_out {
            card = card.provenance("held_out_per_re", run.per_re_json());
        }
        let name = dir_name(&job.variant.name(), job.size, ds, job.seed.0);
        SavedModel::save(self.models.join(name), &t.params, &card)?;
        let Some(run) = &r.held_out else {
            return Ok(());
        };
        let family = match job.variant {
            Variant::Non => Some("non"),
            v if Some(v) == self.first_sol() => Some("sol"),
            _ => None,
        };
        if let Some(variant) = family {
            rec.capacity.add(SweepRun {
                size: job.size.label(),
                params: t.params.count(),
                variant: variant.into(),
                seed: job.seed.0,
                figures: vec![run.mean(), run.long_mean(), run.deviation_mean()],
            });
        }
        if job.size == self.main_size {
            (rec.results).record(&job.variant.name(), ds, Some(job.seed.0), run)?;
        }
        if o.selected() {
            (rec.results).record("sol_selected", ds, Some(job.seed.0), run)?;
        }
        Ok(())
    }
}
