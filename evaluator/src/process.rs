//! The evaluator process: scores weight snapshots as they are broadcast (every N RL episodes and
//! the final one) on all six settings, publishes each report and writes it to disk.

use std::path::PathBuf;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Duration;

use policy::method::RunSpec;
use policy::wire::net_from_weights;
use proto::{keys, EvalReport, RunPhase};
use sim::Setting;
use transport::{Transport, TransportError};

use crate::{evaluate, EvalError, SettingResult, Subject};

/// Evaluator settings.
#[derive(Debug, Clone)]
pub struct EvaluatorOptions {
    /// Evaluate a snapshot every this many RL episodes (0: only the final one).
    pub every_episodes: u64,
    pub episodes_per_setting: u32,
    pub seed_start: u64,
    pub settings: Vec<Setting>,
    pub threads: usize,
    /// Reports are written here: `eval-<version>.{json,md}` and, at the end, `report.{json,md}`.
    pub out_dir: PathBuf,
}

#[derive(Debug, thiserror::Error)]
pub enum ProcessError {
    #[error(transparent)]
    Transport(#[from] TransportError),
    #[error(transparent)]
    Eval(#[from] EvalError),
    #[error("{0}")]
    Other(String),
}

/// The wire report of `results`.
pub fn report(
    results: &[SettingResult],
    trained_episodes: u64,
    final_snapshot: bool,
) -> EvalReport {
    EvalReport {
        trained_episodes,
        final_snapshot,
        settings: results
            .iter()
            .map(|r| {
                let a = &r.aggregate;
                proto::SettingReport {
                    setting: r.setting.name().to_string(),
                    episodes: a.episodes,
                    success_rate: a.success_rate(),
                    collision_rate: a.collision_rate(),
                    timeout_rate: a.timeout_rate(),
                    nav_time_s: a.nav_time_s(),
                    discomfort: a.discomfort(),
                    mean_return: a.mean_return(),
                    path_length_m: a.path_length_m().unwrap_or(0.0),
                    smoothness_rad: a.mean_abs_rotation_rad(),
                }
            })
            .collect(),
    }
}

/// The paper's table layout: Succ., Coll., Timeout, Nav. Time, Disc. per setting and averaged.
pub fn markdown(r: &EvalReport, method: &str, version: u64) -> String {
    let mut s = format!(
        "Method `{method}`, weights version {version}, {} RL episodes trained{}.\n\n| setting | episodes | Succ. | Coll. | Timeout | Nav. Time (s) | Disc. |\n|---|---|---|---|---|---|---|\n",
        r.trained_episodes,
        if r.final_snapshot { " (final)" } else { "" }
    );
    let row = |name: &str, n: u32, sr: f64, cr: f64, tr: f64, nav: Option<f64>, d: f64| {
        format!(
            "| {name} | {n} | {sr:.3} | {cr:.3} | {tr:.3} | {} | {d:.3} |\n",
            nav.map_or("–".to_string(), |x| format!("{x:.2}"))
        )
    };
    for x in &r.settings {
        s += &row(
            &x.setting,
            x.episodes,
            x.success_rate,
            x.collision_rate,
            x.timeout_rate,
            x.nav_time_s,
            x.discomfort,
        );
    }
    for vis in ["invisible", "visible"] {
        let rows: Vec<_> = r
            .settings
            .iter()
            .filter(|x| x.setting.ends_with(&format!("-{vis}")))
            .collect();
        if rows.len() > 1 {
            let n = rows.len() as f64;
            let navs: Vec<f64> = rows.iter().filter_map(|x| x.nav_time_s).collect();
            let nav = (!navs.is_empty()).then(|| navs.iter().sum::<f64>() / navs.len() as f64);
            s += &row(
                &format!("average {vis}"),
                rows.iter().map(|x| x.episodes).sum(),
                rows.iter().map(|x| x.success_rate).sum::<f64>() / n,
                rows.iter().map(|x| x.collision_rate).sum::<f64>() / n,
                rows.iter().map(|x| x.timeout_rate).sum::<f64>() / n,
                nav,
                rows.iter().map(|x| x.discomfort).sum::<f64>() / n,
            );
        }
    }
    s
}

fn write(
    opts: &EvaluatorOptions,
    stem: &str,
    r: &EvalReport,
    method: &str,
    version: u64,
) -> Result<(), ProcessError> {
    let err = |e: std::io::Error| {
        ProcessError::Other(format!(
            "writing reports to {}: {e}",
            opts.out_dir.display()
        ))
    };
    std::fs::create_dir_all(&opts.out_dir).map_err(err)?;
    let json = serde_json::to_string_pretty(r).map_err(|e| ProcessError::Other(e.to_string()))?;
    std::fs::write(opts.out_dir.join(format!("{stem}.json")), json).map_err(err)?;
    std::fs::write(
        opts.out_dir.join(format!("{stem}.md")),
        markdown(r, method, version),
    )
    .map_err(err)?;
    Ok(())
}

/// How the evaluator ended.
#[derive(Debug, Clone, PartialEq)]
pub enum EvaluatorExit {
    /// The final snapshot was evaluated.
    Finished(EvalReport),
    Stopped,
}

/// Runs until the learner finishes the run (after evaluating the final weights) or `stop`.
pub fn run(
    transport: &Transport,
    spec: &RunSpec,
    opts: &EvaluatorOptions,
    stop: &AtomicBool,
) -> Result<EvaluatorExit, ProcessError> {
    let net_cfg = spec.method.net().ok_or_else(|| {
        ProcessError::Other(format!("method {} has no weights to evaluate", spec.method))
    })?;
    let run = transport.run().clone();
    let weights = transport.latest_subscriber(&keys::weights(&run))?;
    let control = transport.latest_subscriber(&keys::control(&run))?;
    let reports = transport.publisher(&keys::eval_report(&run, transport.sender().index))?;
    let _token = transport.declare_alive()?;
    let il_epochs = spec.train.imitation.epochs as u64;
    let mut next_due = opts.every_episodes;
    let mut evaluated: Option<u64> = None;
    loop {
        if stop.load(Ordering::SeqCst) {
            return Ok(EvaluatorExit::Stopped);
        }
        let finished = control
            .latest()?
            .is_some_and(|c| c.body.phase == RunPhase::Finished);
        let latest = weights.latest()?;
        let Some(w) = latest else {
            let _ = weights.next(Duration::from_millis(200))?;
            continue;
        };
        let version = w.body.version;
        // Versions advance once per imitation epoch and once per RL episode.
        let trained = version.saturating_sub(il_epochs);
        let due = opts.every_episodes > 0 && trained >= next_due && evaluated != Some(version);
        if !(finished || due) {
            let _ = weights.next(Duration::from_millis(200))?;
            continue;
        }
        let net = net_from_weights(&w.body, &net_cfg).map_err(ProcessError::Other)?;
        tracing::info!(
            version,
            trained,
            final_snapshot = finished,
            "evaluating a snapshot"
        );
        let subject = Subject {
            method: spec.method,
            net: Some(&net),
            gamma: spec.train.gamma,
            human_model: spec.train.human_model.into(),
            orca_safety_space_m: 0.0,
        };
        let results = evaluate(
            subject,
            &spec.sim,
            &opts.settings,
            opts.seed_start,
            opts.episodes_per_setting,
            opts.threads,
        )?;
        let r = report(&results, trained, finished);
        reports.publish(version, &r)?;
        write(
            opts,
            &format!("eval-{version:06}"),
            &r,
            spec.method.name(),
            version,
        )?;
        evaluated = Some(version);
        while next_due <= trained && opts.every_episodes > 0 {
            next_due += opts.every_episodes;
        }
        if finished {
            write(opts, "report", &r, spec.method.name(), version)?;
            return Ok(EvaluatorExit::Finished(r));
        }
    }
}
