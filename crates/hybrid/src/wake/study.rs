//! A whole wake study from its command line: the scene's [`Wake`], its
//! [`Options`] and its [`Plan`] (the corrector's code and main size, the
//! budget in corrector evaluations, the pilots, validation and schedule)
//! make a [`Study`]; [`Study::run`] generates each data seed's references,
//! runs [`Setup::untrained`] and [`Setup::protocol`], the speed study and the
//! pressure solves, and records the held-out readings in the output
//! folder's ledger; [`Study::json`] gives the run's JSON keys.

use std::path::PathBuf;

use diffphys_flow::{PressureSolver, Scene};
use diffphys_learn::cache::Cache;
use diffphys_learn::{Hybrid, LearnError, LrSchedule, ModelCard, Splits};
use diffphys_report::print_memory;
use serde_json::{json, Map, Value};

use super::args::{self, Options, TrainArgs};
use super::{name_in, Body, Wake, ADVECTIONS, ARITHMETICS, SPLITTINGS};
use crate::reference::Reference;
use crate::study::{Probe, Record, Setup};
use crate::{FlowSimulator, NetSize, ParamCode, Result};

/// What a scene fixes about its trainings.
#[derive(Debug, Clone, Copy)]
pub struct Plan {
    /// The corrector's code of each sample's viscosity.
    pub code: ParamCode,
    /// The main variants' corrector size.
    pub main_size: NetSize,
    /// Corrector evaluations per training, full and `--small`.
    pub evaluations: [usize; 2],
    /// Corrector evaluations per Adam step, at least.
    pub step_evaluations: usize,
    /// A learning-rate pilot trains on the budget divided by this.
    pub pilot_divisor: usize,
    /// Validate (for early stopping) every this many corrector
    /// evaluations, full and `--small`.
    pub validation_evaluations: [usize; 2],
    /// The learning-rate schedule.
    pub schedule: LrSchedule,
    /// Checkpoint the long SOL unrolls every this many steps.
    pub checkpoint: Option<usize>,
}

/// What [`Study::run`] measured.
pub struct Outcome {
    /// The study's log, held-out figures and capacity sweep.
    pub record: Record,
    /// The speed-against-accuracy study ([`Wake::speed`]; `null` without it).
    pub speed: Value,
    /// The pressure solves ([`Wake::pressure_solves`]; `null` without the
    /// speed study).
    pub pressure: Value,
    /// Each corrector size's parameter count.
    pub params: Map<String, Value>,
}

/// A wake study: the scene, its options, the seeds, the solvers and the
/// reference cache.
pub struct Study {
    /// The scene.
    pub wake: Wake,
    /// Its options.
    pub options: Options,
    /// What the scene fixes about its trainings.
    pub plan: Plan,
    /// Data seeds (each a draw of the three splits and its own reference).
    pub data_seeds: Vec<u64>,
    /// Training seeds.
    pub train_seeds: Vec<u64>,
    /// The output folder (charts, the reference cache, saved models, the
    /// held-out ledger).
    pub out: PathBuf,
    /// `--small`.
    pub small: bool,
    /// `--validation-only`: the held-out split is not read.
    pub validation_only: bool,
    /// The coarse solver.
    pub coarse: FlowSimulator,
    /// The reference solver.
    pub fine: Scene,
    /// The reference cache.
    pub cache: Cache,
    /// The budget of each training: corrector evaluations.
    pub evaluations: usize,
}

impl Study {
    /// The study of `args` on the scene `wake` (whose sizes follow
    /// `options`), its output folder created.
    ///
    /// # Errors
    /// As [`args::seeds`]; whatever the scenes and the cache return.
    pub fn new(wake: Wake, options: Options, plan: Plan, args: &TrainArgs) -> Result<Self> {
        let small = args.scene.small;
        let (data_seeds, train_seeds) = args::seeds(args)?;
        let out = args.scene.out();
        std::fs::create_dir_all(&out).map_err(|e| LearnError::Invalid {
            what: "output folder",
            message: format!("{}: {e}", out.display()),
        })?;
        let fine = wake.reference_scene()?;
        let coarse = FlowSimulator::new(wake.uncorrected(1, PressureSolver::Cholesky)?);
        let cache = wake.cache(&out)?;
        let step = plan.step_evaluations;
        // `--iterations N`: N Adam steps of the plan's evaluations each.
        let evaluations =
            (args.iterations).map_or(plan.evaluations[usize::from(small)], |n| n * step);
        let s = &wake.sizes;
        println!(
            "wake flow: coarse {} x {} (dt {}), reference {} x {} (dt {}); train Re {:?}, validation Re {:?}, held-out Re {:?}; {} corrector evaluations per training, at least {} per Adam step",
            s.ny, s.nx, s.dt, fine.grid().ny, fine.grid().nx, fine.dt(),
            options.train_re, options.validation_re, options.held_out_re, evaluations, step
        );
        Ok(Study {
            wake,
            options,
            plan,
            data_seeds,
            train_seeds,
            out,
            small,
            validation_only: args.validation_only,
            coarse,
            fine,
            cache,
            evaluations,
        })
    }

    /// The study's [`Setup`]; `card` gives the settings a saved corrector of
    /// a size must match.
    pub fn setup<'a>(&'a self, card: &'a (dyn Fn(NetSize) -> ModelCard + Sync)) -> Setup<'a> {
        let (o, p, sizes) = (&self.options, &self.plan, &self.wake.sizes);
        Setup {
            coarse: &self.coarse,
            code: p.code,
            arithmetic: o.arithmetic,
            variants: &o.variants,
            main_size: p.main_size,
            capacity: &o.capacity,
            learning_rates: &o.learning_rates,
            train_seeds: &self.train_seeds,
            evaluations: self.evaluations,
            step_evaluations: p.step_evaluations,
            pilot_divisor: p.pilot_divisor,
            validation_evaluations: p.validation_evaluations[usize::from(self.small)],
            schedule: p.schedule,
            checkpoint: p.checkpoint,
            evaluation: self.wake.evaluation(),
            held_out_conditions: o.held_out_re.len(),
            threads: o.threads,
            validation_only: self.validation_only,
            models: self.out.join("models"),
            card,
            // The staircase and inscribed bodies make the pinned faces'
            // error zero by construction.
            pinned_must_vanish: (sizes.body != Body::Cylinder).then(|| sizes.body.label()),
        }
    }

    /// The three splits of data seed `ds`, generated or read from the cache.
    ///
    /// # Errors
    /// As [`Wake::splits`].
    pub fn references(&self, ds: u64) -> Result<Splits<Vec<Reference>>> {
        let o = &self.options;
        let t0 = std::time::Instant::now();
        let scenes = (self.coarse.scene(), &self.fine);
        let re = [&o.train_re[..], &o.validation_re, &o.held_out_re];
        let splits = self.wake.splits(&self.cache, scenes, ds, re, o.threads)?;
        print_memory("reference");
        println!(
            "data seed {ds}: reference ready in {:.1} s (cached under {})",
            t0.elapsed().as_secs_f64(),
            self.cache.dir().display()
        );
        Ok(splits)
    }

    /// The whole study: per data seed the references, the untrained
    /// baselines and the protocol; then the speed study on the first data
    /// seed's held-out split (a baseline reading; the validation split with
    /// `--validation-only`) and the pressure solves; last, this run's
    /// held-out readings appended to the output folder's ledger.
    ///
    /// # Errors
    /// Whatever the phases return.
    pub fn run(&self) -> Result<Outcome> {
        let mut record = Record::default();
        let arithmetic = self.options.arithmetic;
        let card = |size| self.wake.card(size, arithmetic);
        let setup = self.setup(&card);
        let mut params = Map::new();
        let sizes =
            std::iter::once(self.plan.main_size).chain(self.options.capacity.iter().copied());
        for size in sizes {
            let (_, p) = setup.net(size, 0)?;
            params.insert(size.label(), json!(p.count()));
        }
        let mut speed_inputs = None;
        for &ds in &self.data_seeds {
            let splits = self.references(ds)?;
            let (train, validation, sigma) = setup.untrained(ds, &splits, &mut record)?;
            print_memory("src");
            let probe = setup.protocol(ds, &splits, (&train, &validation), sigma, &mut record)?;
            print_memory("held-out");
            if speed_inputs.is_none() {
                speed_inputs = Some((splits, probe));
            }
        }
        let (speed, pressure) = match (self.options.speed, speed_inputs) {
            (true, Some(inputs)) => self.speed_study(&setup, &inputs, &mut record)?,
            _ => (Value::Null, Value::Null),
        };
        self.count_readings(&mut record)?;
        Ok(Outcome {
            record,
            speed,
            pressure,
            params,
        })
    }

    /// The speed study with the selected SOL corrector of the first data
    /// seed (`probe`), its convolutions on the study's threads (one rollout
    /// at a time here, so the network has the cores the trainings shared;
    /// `network_threads` in the JSON), and the pressure solves inside a
    /// rollout.
    fn speed_study(
        &self,
        setup: &Setup<'_>,
        (splits, probe): &(Splits<Vec<Reference>>, Option<Probe>),
        record: &mut Record,
    ) -> Result<(Value, Value)> {
        let size = probe.as_ref().map_or(self.plan.main_size, |p| p.1);
        let threads = self.options.threads;
        let net = setup.net(size, 0)?.0.with_threads(threads)?;
        let hybrid = Hybrid::new(self.coarse.clone(), net);
        let params = probe.as_ref().map(|p| &p.0);
        let speed_on = |refs: &[Reference]| -> Result<Value> {
            let mut speed = self.wake.speed(&hybrid, params, refs, &self.out)?;
            speed["network_threads"] = json!(threads);
            Ok(speed)
        };
        let speed = if self.validation_only {
            speed_on(&splits.validation)?
        } else {
            let result = splits.held_out().evaluate_baseline(|refs| {
                speed_on(refs).map_err(|e| LearnError::Invalid {
                    what: "speed",
                    message: e.to_string(),
                })
            })?;
            (record.log.held_out_readings).insert(splits.seed.0, splits.held_out().readings());
            result
        };
        print_memory("speed");
        let pressure = self.wake.pressure_solves(self.options.validation_re[0])?;
        Ok((speed, pressure))
    }

    /// Appends this run's held-out readings to the output folder's ledger:
    /// per data seed, the split (what draws its conditions: the coarse grid
    /// and step, the windows, the held-out Re and the data seed, but not the
    /// reference's resolution or scheme, so that a reading stays counted
    /// when the reference is refined) and the configuration that shaped the
    /// models read on it (every option but the held-out Re, the thread count
    /// and the speed study, the reference's factor and scheme included; the
    /// sizes; the budget; the training seeds).
    fn count_readings(&self, record: &mut Record) -> Result<()> {
        let shaping = Options {
            held_out_re: Vec::new(),
            threads: 0,
            speed: false,
            ..self.options.clone()
        };
        let configuration = format!(
            "{shaping:?} | {:?} | corrector evaluations {} | training seeds {:?}",
            self.wake.sizes, self.evaluations, self.train_seeds
        );
        let held_out = &self.options.held_out_re;
        let s = &self.wake.sizes;
        let conditions = format!(
            "coarse {}x{} dt {} warm_base {} warm {} record {} base_re {} starts {:?}",
            s.nx, s.ny, s.dt, s.warm_base, s.warm, s.record, s.base_re, s.starts
        );
        let split = |ds| format!("{conditions} | held-out Re {held_out:?} | data seed {ds}");
        Ok((record.log).count_readings(&self.out, split, &configuration)?)
    }

    /// The run's JSON keys beside the record's: the grids, steps, splits,
    /// seeds, budget, setup, parameter counts, speed study and pressure
    /// solves.
    pub fn json(&self, outcome: &Outcome) -> Map<String, Value> {
        let (o, s, c) = (&self.options, &self.wake.sizes, &self.wake.channel);
        let training_iterations: Map<String, Value> = (o.variants.iter())
            .filter(|v| !matches!(v, diffphys_learn::study::Variant::Src))
            .map(|&v| {
                let steps = v.adam_steps(self.evaluations, self.plan.step_evaluations);
                (v.name(), json!(steps))
            })
            .collect();
        let (inside, outside): (Vec<f64>, Vec<f64>) =
            o.held_out_re.iter().partition(|&&r| o.inside(r));
        let setup = json!({
            "body": s.body.label(),
            "reference_scheme": s.reference.label(),
            "coarse_advection": name_in(&ADVECTIONS, s.advection),
            "coarse_splitting": name_in(&SPLITTINGS, s.splitting),
            "network_arithmetic": name_in(&ARITHMETICS, o.arithmetic),
            "pinned_face_error": outcome.record.pinned_face_error,
        });
        let g = self.fine.grid();
        let line = json!({
            "small": self.small,
            "grid_coarse": [s.ny, s.nx],
            "grid_reference": [g.ny, g.nx],
            "dt_coarse": s.dt,
            "dt_reference": self.fine.dt(),
            "skipped_transient_steps": {"base": s.warm_base, "per_re": s.warm, "base_re": s.base_re},
            "recorded_steps": s.record,
            "rollout_steps": s.rollout,
            "rollout_starts": s.starts,
            "long_rollout_steps": s.long,
            "re_definition": format!("U D / nu, U = {} inflow speed, D = {} cylinder diameter", c.inflow, c.diameter),
            "re_range": c.re_range,
            "data_seeds": self.data_seeds,
            "train_seeds": self.train_seeds,
            "train_re": o.train_re,
            "validation_re": o.validation_re,
            "held_out_re": {"inside": inside, "outside": outside},
            "training_iterations": training_iterations,
            "corrector_evaluations_per_training": self.evaluations,
            "setup": setup,
            "params": outcome.params,
            "main_size": self.plan.main_size.label(),
            "speed": outcome.speed,
            "pressure": outcome.pressure,
            "validation_only": self.validation_only,
            "saved_models": self.out.join("models").display().to_string(),
        });
        let mut map = match line {
            Value::Object(map) => map,
            _ => Map::new(),
        };
        map.extend(outcome.record.to_json());
        map
    }
}
