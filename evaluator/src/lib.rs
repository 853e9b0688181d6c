//! `evaluator`: scores a policy (the ORCA baseline or a value network) on the test seeds of any
//! settings with the paper's metrics, spreading settings and seeds over threads.

#[cfg(feature = "process")]
pub mod process;

use policy::lookahead::{HumanModel, Lookahead};
use policy::method::Method;
use policy::rollout::{rollout, Behaviour};
use policy::{PolicyError, ValueNet};
use sim::{Aggregate, Env, Setting, SimConfig};

/// What to evaluate.
#[derive(Clone, Copy)]
pub struct Subject<'a> {
    pub method: Method,
    /// The weights, for learned methods.
    pub net: Option<&'a ValueNet>,
    pub gamma: f64,
    pub human_model: HumanModel,
    /// Terminal candidates scored by their reward alone (`TrainConfig::terminal_previews`).
    pub terminal_previews: bool,
    /// Depth-2 planning over this many best first steps (`TrainConfig::planning_top_k`; 0: off).
    pub planning_top_k: usize,
    /// Second steps tried after each planned first step (`TrainConfig::planning_breadth`; 0:
    /// every action).
    pub planning_breadth: usize,
    /// The people shield's horizon (`TrainConfig::shield_s`; 0: off).
    pub shield_s: f64,
    /// The progress tie-break's tolerance (`TrainConfig::progress_tolerance`; 0: off).
    pub progress_tolerance: f64,
    /// Extra ORCA radius for the ORCA baseline.
    pub orca_safety_space_m: f64,
}

impl<'a> Subject<'a> {
    /// The greedy policy of a run's method with `net`, under the run's γ and human model.
    pub fn of_run(spec: &policy::method::RunSpec, net: &'a ValueNet) -> Self {
        Self::learned(spec.method, net, &spec.train)
    }

    /// The greedy policy of `method` with `net`, under `train`'s lookahead settings.
    pub fn learned(method: Method, net: &'a ValueNet, train: &policy::method::TrainConfig) -> Self {
        Self {
            method,
            net: Some(net),
            gamma: train.gamma,
            human_model: train.human_model.into(),
            terminal_previews: train.terminal_previews,
            planning_top_k: train.planning_top_k,
            planning_breadth: train.planning_breadth,
            shield_s: train.shield_s,
            progress_tolerance: train.progress_tolerance,
            orca_safety_space_m: 0.0,
        }
    }
}

/// Why an evaluation failed.
#[derive(Debug, thiserror::Error)]
pub enum EvalError {
    #[error("method {0} needs weights to be evaluated")]
    NoWeights(Method),
    #[error(transparent)]
    Sim(#[from] sim::EnvError),
    #[error(transparent)]
    Policy(#[from] PolicyError),
    #[error("an evaluation thread panicked")]
    Panicked,
}

/// One setting's results.
#[derive(Debug, Clone, Copy)]
pub struct SettingResult {
    pub setting: Setting,
    pub aggregate: Aggregate,
}

/// Runs seeds `seed_start .. seed_start + episodes` on every setting, greedily, with `threads`
/// worker threads. The base simulator config gets the method's reward switches.
pub fn evaluate(
    subject: Subject<'_>,
    base: &SimConfig,
    settings: &[Setting],
    seed_start: u64,
    episodes: u32,
    threads: usize,
) -> Result<Vec<SettingResult>, EvalError> {
    if subject.method != Method::Orca && subject.net.is_none() {
        return Err(EvalError::NoWeights(subject.method));
    }
    let cfg = subject.method.sim_config(base);
    // Work items: (setting index, seed offset), split round-robin over threads.
    let jobs: Vec<(usize, u64)> = (0..settings.len())
        .flat_map(|s| (0..episodes as u64).map(move |k| (s, k)))
        .collect();
    let threads = threads.clamp(1, jobs.len().max(1));
    let partials: Vec<Vec<Aggregate>> = std::thread::scope(|scope| {
        let handles: Vec<_> = (0..threads)
            .map(|w| {
                let jobs = &jobs;
                let cfg = &cfg;
                scope.spawn(move || -> Result<Vec<Aggregate>, EvalError> {
                    let mut out = vec![Aggregate::default(); settings.len()];
                    let mut envs: Vec<Option<Env>> = (0..settings.len()).map(|_| None).collect();
                    let mut lookahead = Lookahead::new(
                        subject.gamma,
                        subject.human_model,
                        subject.method.human_order(),
                    )
                    .with_terminal_previews(subject.terminal_previews)
                    .with_planning(subject.planning_top_k)
                    .with_planning_breadth(subject.planning_breadth)
                    .with_shield(subject.shield_s)
                    .with_progress_tolerance(subject.progress_tolerance);
                    for &(s, k) in jobs.iter().skip(w).step_by(threads) {
                        let env = match &mut envs[s] {
                            Some(env) => env,
                            slot => slot.insert(Env::new(cfg.clone(), settings[s], seed_start)?),
                        };
                        let behaviour = match subject.net {
                            None => Behaviour::Orca {
                                safety_space_m: subject.orca_safety_space_m,
                            },
                            Some(net) => Behaviour::Net {
                                net,
                                lookahead: &mut lookahead,
                                epsilon: 0.0,
                                policy_version: 0,
                            },
                        };
                        let ep = rollout(env, seed_start + k, behaviour)?;
                        out[s].add(&ep.summary);
                    }
                    Ok(out)
                })
            })
            .collect();
        handles
            .into_iter()
            .map(|h| h.join().map_err(|_| EvalError::Panicked)?)
            .collect::<Result<Vec<_>, EvalError>>()
    })?;
    Ok(settings
        .iter()
        .enumerate()
        .map(|(s, &setting)| {
            let mut aggregate = Aggregate::default();
            for p in &partials {
                aggregate.merge(&p[s]);
            }
            SettingResult { setting, aggregate }
        })
        .collect())
}
