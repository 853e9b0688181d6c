//! Scoring policies on test seeds with the numbers a report needs: per-setting results with
//! their intervals, episode by episode ([`evaluate_subject`], what `fsrl eval` runs), and the final
//! evaluation of a finished run on its own setting ([`final_evaluation`], the same in both
//! training modes).

use std::path::Path;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::Mutex;

use anyhow::Context;
use evaluator::{evaluate, Subject};
use policy::method::RunSpec;
use sim::{Aggregate, CrowdModel, Setting, SimConfig};

use crate::policy_file::{bytes_sha256, subject_label, Input};
use crate::report::{Report, Samples, SettingReport, SubjectReport};

/// What an evaluation runs: `episodes` test episodes (seeds from `seed_start`) of each of
/// `settings`, `threads` at once; `orca_safety_space_m` for the ORCA robot and the ORCA humans'
/// model of it.
#[derive(Debug, Clone)]
pub struct EvalPlan {
    pub settings: Vec<Setting>,
    pub seed_start: u64,
    pub episodes: u32,
    pub threads: usize,
    pub orca_safety_space_m: f64,
    /// Overrides every model's `train.planning_top_k` (`fsrl eval --planning-top-k`).
    pub planning_top_k: Option<usize>,
    /// Overrides every model's `train.planning_breadth` (`fsrl eval --planning-breadth`).
    pub planning_breadth: Option<usize>,
    /// A crowd other than the one each policy was trained with (`fsrl eval --people / --crowd`).
    pub crowd: Crowd,
    /// Overrides every model's `train.shield_s` (`fsrl eval --shield-s`).
    pub shield_s: Option<f64>,
    /// Overrides every model's `train.progress_tolerance` (`fsrl eval --progress-tolerance`).
    pub progress_tolerance: Option<f64>,
}

/// The most moving people `fsrl eval --people` accepts.
pub const MAX_PEOPLE: usize = 40;

/// The most people the paper's 4 m circle holds at its density (Env 1's ten): above it, the
/// circle grows so that its people per square metre stay the paper's ([`Crowd::apply`]).
pub const CIRCLE_PEOPLE: usize = 10;

/// A crowd other than the trained one (issue 54's robustness table): `people` moving people per
/// episode in the paper's settings, and people who all follow `model`. Env 2's and Env 3's five
/// standing people stay. Up to [`CIRCLE_PEOPLE`] moving people cross the paper's 4 m circle;
/// more cross a circle grown by √(people / 10) (5.66 m for 20), so that the crowd is larger at
/// the paper's density (twenty people do not fit on the 4 m circle with their goals clear), while
/// the robot's start, goal and time limit stay the paper's. `Crowd::default()` changes nothing.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct Crowd {
    pub people: Option<usize>,
    pub model: Option<CrowdModel>,
}

#[derive(Debug, thiserror::Error, PartialEq)]
pub enum CrowdError {
    #[error("--people must be in 1..={MAX_PEOPLE}, got {0}")]
    People(usize),
    #[error(
        "--people sets the moving people of the paper's six settings; {0} places its own (its \
         [sim.walls.*] section says how many)"
    )]
    Walled(Setting),
}

impl Crowd {
    /// Checks the crowd against the settings it will be used in.
    pub fn check(&self, settings: &[Setting]) -> Result<(), CrowdError> {
        if let Some(n) = self.people {
            if n == 0 || n > MAX_PEOPLE {
                return Err(CrowdError::People(n));
            }
            if let Some(s) = settings.iter().find(|s| !s.is_paper()) {
                return Err(CrowdError::Walled(*s));
            }
        }
        Ok(())
    }

    /// `sim` with this crowd in `setting`: `humans.count` is the moving people plus the
    /// setting's standing ones (Env 1 has none).
    pub fn apply(&self, sim: &SimConfig, setting: Setting) -> SimConfig {
        let mut sim = sim.clone();
        if let Some(n) = self.people {
            let standing = match setting.env {
                sim::EnvKind::Env1 => 0,
                _ => sim.humans.standing,
            };
            // A model trained on crowds of any size keeps the person rows it was trained with.
            sim.humans.slots = sim.people_slots(setting.env);
            sim.humans.count_max = None;
            sim.humans.count = n + standing;
            sim.humans.circle_grows_past.get_or_insert(CIRCLE_PEOPLE);
        }
        if let Some(m) = self.model {
            sim.humans.model = m;
        }
        sim
    }

    /// "20 moving people, social-force" (`None` for the trained crowd).
    pub fn label(&self) -> Option<String> {
        let parts: Vec<String> = self
            .people
            .map(|n| format!("{n} moving people"))
            .into_iter()
            .chain(self.model.map(|m| format!("{m} people")))
            .collect();
        (!parts.is_empty()).then(|| parts.join(", "))
    }
}

/// The settings a policy is evaluated on when none are named: the paper's six for a policy
/// trained on one of them (every shipped model), its own setting for one trained among walls.
pub fn default_settings(trained: Setting) -> Vec<Setting> {
    if trained.is_paper() {
        Setting::ALL.to_vec()
    } else {
        vec![trained]
    }
}

/// The ORCA robot on `sim` as a report's subject.
pub fn evaluate_orca(
    sim: &SimConfig,
    plan: &EvalPlan,
    done: &(dyn Fn() + Sync),
) -> anyhow::Result<SubjectReport> {
    let subject = Subject {
        method: policy::method::Method::Orca,
        net: None,
        gamma: 0.9,
        human_model: policy::lookahead::HumanModel::Orca,
        terminal_previews: false,
        planning_top_k: 0,
        planning_breadth: 0,
        shield_s: 0.0,
        progress_tolerance: 0.0,
        orca_safety_space_m: plan.orca_safety_space_m,
    };
    let settings = evaluate_in_crowd(subject, sim, plan, done)?;
    Ok(SubjectReport {
        label: "orca".into(),
        method: "orca".into(),
        checkpoint: None,
        checkpoint_sha256: None,
        policy_version: 0,
        run_seed: None,
        trained_setting: None,
        planning_top_k: 0,
        planning_breadth: 0,
        shield_s: 0.0,
        progress_tolerance: 0.0,
        settings,
    })
}

/// A policy file read once: the weights evaluated are the bytes whose SHA-256 the report
/// records, even when the file is replaced meanwhile (a training exporting its model).
pub struct LoadedPolicy {
    pub model: learner::model::Model,
    pub label: String,
    pub path: std::path::PathBuf,
    pub sha256: String,
}

impl LoadedPolicy {
    pub fn read(input: &Input) -> anyhow::Result<Self> {
        let path = &input.checkpoint;
        let bytes =
            std::fs::read(path).with_context(|| format!("cannot read {}", path.display()))?;
        let (model, kind) = learner::model::policy_from_bytes(path, &bytes)
            .with_context(|| format!("cannot load {}", path.display()))?;
        Ok(Self {
            label: subject_label(input, &model, kind),
            model,
            path: path.clone(),
            sha256: bytes_sha256(&bytes),
        })
    }

    /// The policy on `plan`'s settings, in its own simulator configuration.
    pub fn evaluate(
        &self,
        plan: &EvalPlan,
        done: &(dyn Fn() + Sync),
    ) -> anyhow::Result<SubjectReport> {
        let model = &self.model;
        let learned = Subject::learned(model.method, &model.net, &model.train);
        let subject = Subject {
            orca_safety_space_m: plan.orca_safety_space_m,
            planning_top_k: plan.planning_top_k.unwrap_or(learned.planning_top_k),
            planning_breadth: plan.planning_breadth.unwrap_or(learned.planning_breadth),
            shield_s: plan.shield_s.unwrap_or(learned.shield_s),
            progress_tolerance: plan
                .progress_tolerance
                .unwrap_or(learned.progress_tolerance),
            ..learned
        };
        let settings = evaluate_in_crowd(subject, &model.sim, plan, done)
            .with_context(|| format!("evaluating {}", self.path.display()))?;
        Ok(SubjectReport {
            label: self.label.clone(),
            method: model.method.name().to_string(),
            checkpoint: Some(self.path.display().to_string()),
            checkpoint_sha256: Some(self.sha256.clone()),
            policy_version: model.counters.policy_version,
            run_seed: Some(model.run_seed),
            trained_setting: Some(model.setting.name().to_string()),
            planning_top_k: subject.planning_top_k,
            planning_breadth: subject.planning_breadth,
            shield_s: subject.shield_s,
            progress_tolerance: subject.progress_tolerance,
            settings,
        })
    }
}

/// [`evaluate_subject`] on `plan`, in `plan.crowd` (the crowd of `sim` when it is the default).
fn evaluate_in_crowd(
    subject: Subject<'_>,
    sim: &SimConfig,
    plan: &EvalPlan,
    done: &(dyn Fn() + Sync),
) -> anyhow::Result<Vec<SettingReport>> {
    let run = |sim: &SimConfig, settings: &[Setting]| {
        evaluate_subject(
            subject,
            sim,
            settings,
            plan.seed_start,
            plan.episodes,
            plan.threads,
            done,
        )
    };
    if plan.crowd == Crowd::default() {
        return run(sim, &plan.settings);
    }
    plan.crowd.check(&plan.settings)?;
    let mut out = Vec::with_capacity(plan.settings.len());
    for &setting in &plan.settings {
        let sim = plan.crowd.apply(sim, setting);
        sim.validate()?;
        out.extend(run(&sim, &[setting])?);
    }
    Ok(out)
}

/// Runs `episodes` test episodes per setting of one subject, one episode per evaluator call,
/// and reports every setting with its intervals (per-episode values: Nav. Time, path length and
/// return samples). `threads` episodes run at once; `done` is called after each episode
/// (progress). The sums are in seed order, so they do not depend on the thread count.
pub fn evaluate_subject(
    subject: Subject<'_>,
    base: &SimConfig,
    settings: &[Setting],
    seed_start: u64,
    episodes: u32,
    threads: usize,
    done: &(dyn Fn() + Sync),
) -> anyhow::Result<Vec<SettingReport>> {
    let jobs: Vec<(usize, u64)> = (0..settings.len())
        .flat_map(|s| (0..episodes as u64).map(move |k| (s, k)))
        .collect();
    let results: Mutex<Vec<Option<Aggregate>>> = Mutex::new(vec![None; jobs.len()]);
    let next = AtomicUsize::new(0);
    let failure: Mutex<Option<anyhow::Error>> = Mutex::new(None);
    std::thread::scope(|scope| {
        for _ in 0..threads.clamp(1, jobs.len().max(1)) {
            scope.spawn(|| loop {
                let i = next.fetch_add(1, Ordering::Relaxed);
                let Some(&(s, k)) = jobs.get(i) else { break };
                if failure.lock().map(|f| f.is_some()).unwrap_or(true) {
                    break;
                }
                match evaluate(subject, base, &settings[s..=s], seed_start + k, 1, 1) {
                    Ok(r) => {
                        if let Ok(mut res) = results.lock() {
                            res[i] = r.first().map(|r| r.aggregate);
                        }
                        done();
                    }
                    Err(e) => {
                        if let Ok(mut f) = failure.lock() {
                            f.get_or_insert(anyhow::Error::new(e).context(format!(
                                "{} seed {}",
                                settings[s],
                                seed_start + k
                            )));
                        }
                    }
                }
            });
        }
    });
    if let Some(e) = failure.into_inner().ok().flatten() {
        return Err(e);
    }
    let results = results
        .into_inner()
        .map_err(|_| anyhow::anyhow!("an evaluation thread panicked"))?;
    let mut out = Vec::with_capacity(settings.len());
    for (s, setting) in settings.iter().enumerate() {
        let mut total = Aggregate::default();
        let mut samples = Samples::default();
        // Seed order, so the sums do not depend on the thread count.
        for (i, _) in jobs.iter().enumerate().filter(|(_, j)| j.0 == s) {
            let a = results[i].ok_or_else(|| anyhow::anyhow!("an episode went missing"))?;
            total.merge(&a);
            if a.successes == 1 {
                samples.nav_times_s.push(a.success_time_s);
                samples.path_lengths_m.push(a.success_path_m);
            }
            samples.returns.push(a.return_sum);
        }
        out.push(SettingReport::with_samples(
            setting.name(),
            &total,
            &samples,
        ));
    }
    Ok(out)
}

/// The final evaluation of a finished run, the same in both modes: the run's policy `policy`
/// (`crate::policy_choice::run_policy`: the last checkpoint, or the chosen validation snapshot) on
/// `train.eval_episodes` test episodes of its own setting; writes `report.json` and `report.md`
/// into the run directory and prints the table.
pub fn final_evaluation(out: &Path, spec: &RunSpec, policy: &Path) -> anyhow::Result<Report> {
    let train = &spec.train;
    eprintln!(
        "evaluating on {} test episodes of {} ...",
        train.eval_episodes, spec.setting
    );
    let (model, _) = learner::model::load_policy(policy)
        .with_context(|| format!("cannot load {}", policy.display()))?;
    let subject = Subject::of_run(spec, &model.net);
    let threads = std::thread::available_parallelism().map_or(1, |n| n.get());
    let results = evaluate(
        subject,
        &spec.sim,
        &[spec.setting],
        train.test_seed_start,
        train.eval_episodes,
        threads,
    )?;
    let report = Report {
        method: spec.method.name().to_string(),
        policy_version: model.counters.policy_version,
        test_seed_start: train.test_seed_start,
        settings: results
            .iter()
            .map(|r| SettingReport::new(r.setting.name(), &r.aggregate))
            .collect(),
    };
    std::fs::write(
        out.join("report.json"),
        serde_json::to_string_pretty(&report)?,
    )?;
    let md = report.markdown();
    std::fs::write(out.join("report.md"), &md)?;
    println!("{md}");
    Ok(report)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_crowd_sets_moving_people_beside_the_standing_ones_and_grows_the_circle_past_ten() {
        let sim = SimConfig::default();
        let env1: Setting = "env1-invisible".parse().unwrap();
        let env2: Setting = "env2-visible".parse().unwrap();
        assert_eq!(Crowd::default().apply(&sim, env1), sim);
        let c = |n| Crowd {
            people: Some(n),
            model: Some(CrowdModel::SocialForce),
        };
        let five = c(5).apply(&sim, env1);
        assert_eq!(five.humans.count, 5);
        assert_eq!(five.humans.model, CrowdModel::SocialForce);
        assert_eq!(c(5).apply(&sim, env2).humans.count, 5 + sim.humans.standing);
        assert_eq!(
            five.humans.slots, None,
            "a model of one crowd size has no slots"
        );
        let mut any = sim.clone();
        any.humans.count = 5;
        any.humans.count_max = Some(20);
        let tested = c(10).apply(&any, env1);
        assert_eq!(
            (
                tested.humans.count,
                tested.humans.count_max,
                tested.humans.slots
            ),
            (10, None, Some(20)),
            "a model of any crowd keeps its 20 rows in a crowd of 10"
        );
        assert_eq!(tested.entities(env1), 20);
        assert_eq!(c(30).apply(&any, env1).entities(env1), 30);
        let twenty = c(20).apply(&sim, env1);
        assert_eq!(twenty.humans.count, 20);
        assert_eq!(twenty.humans.circle_grows_past, Some(CIRCLE_PEOPLE));
        assert_eq!(c(0).check(&[env1]), Err(CrowdError::People(0)));
        assert_eq!(c(41).check(&[env1]), Err(CrowdError::People(41)));
        let corridor: Setting = "corridor".parse().unwrap();
        let e = c(10).check(&[env1, corridor]).unwrap_err();
        assert!(e.to_string().contains("corridor places its own"), "{e}");
        // Twenty people fit in the grown circle: every episode is placed and runs.
        let plan = EvalPlan {
            settings: vec![env1, env2],
            seed_start: 1000,
            episodes: 3,
            threads: 2,
            orca_safety_space_m: 0.0,
            planning_top_k: None,
            planning_breadth: None,
            crowd: c(20),
            shield_s: None,
            progress_tolerance: None,
        };
        let r = evaluate_orca(&sim, &plan, &|| {}).unwrap();
        assert!(r.settings.iter().all(|s| s.episodes == 3));
    }

    #[test]
    fn an_evaluation_does_not_depend_on_its_thread_count_and_counts_every_episode() {
        let sim = SimConfig::default();
        let settings: Vec<Setting> = ["env1-invisible", "env2-visible"]
            .iter()
            .map(|s| s.parse().unwrap())
            .collect();
        let plan = |threads| EvalPlan {
            settings: settings.clone(),
            seed_start: 1000,
            episodes: 6,
            threads,
            orca_safety_space_m: 0.0,
            planning_top_k: None,
            planning_breadth: None,
            crowd: Crowd::default(),
            shield_s: None,
            progress_tolerance: None,
        };
        let done = AtomicUsize::new(0);
        let one = evaluate_orca(&sim, &plan(1), &|| {
            done.fetch_add(1, Ordering::Relaxed);
        })
        .unwrap();
        assert_eq!(done.load(Ordering::Relaxed), 12);
        let two = evaluate_orca(&sim, &plan(2), &|| {}).unwrap();
        assert_eq!(
            serde_json::to_string(&one).unwrap(),
            serde_json::to_string(&two).unwrap()
        );
        assert_eq!(one.settings.len(), 2);
        for r in &one.settings {
            assert_eq!(r.episodes, 6);
            r.check().unwrap();
        }
    }
}
