//! `fsrl train`: trains one method on one setting, as a learner, actors and an evaluator
//! (`launch::local`) or, with `--single-process`, in this process (`launch::single`:
//! `trainer::run`, the same parts in lockstep), with progress, Ctrl-C handling, `--resume`, and
//! the same final evaluation on the setting's test seeds in both modes. This module parses the
//! arguments and installs the Ctrl-C handler; the rules (which snapshot is the policy, the
//! replay ratio) are `launch::config`'s.

use std::path::PathBuf;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;

use anyhow::Context;
use transport::DataPlane;

use crate::config::{ReplayRatioArg, Resolved, RunOverrides};

#[derive(Debug, clap::Args)]
pub struct TrainArgs {
    #[command(flatten)]
    pub run: RunOverrides,
    /// Test episodes of the final evaluation [default: 500]
    #[arg(long)]
    pub eval_episodes: Option<u32>,
    /// Checkpoint every N RL episodes [default: 500]
    #[arg(long)]
    pub checkpoint_every: Option<u64>,
    /// Run directory [default: runs/<method>-<setting>-s<seed>]
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// Continue the run in --out from its last checkpoint.
    #[arg(long)]
    pub resume: bool,
    /// Train in this one process instead of learner + actors + evaluator processes. The run's
    /// policy (`[train] select`, unless the config or a resumed run says): distributed,
    /// `revalidated-return` (the 4 best validation returns after the ε decay and the last
    /// weights, scored again on 300 fresh validation episodes, recorded in revalidation.jsonl);
    /// one process, `low-disc`, as the shipped models of the paper's methods (`fsrl-plan`:
    /// `revalidated-return` in both modes)
    #[arg(long)]
    pub single_process: bool,
    /// Actor processes (multi-process mode)
    #[arg(long, default_value_t = 2)]
    pub actors: u32,
    /// Data plane of the local run: iceoryx2 (shared memory) or zenoh
    #[arg(long, default_value = "iceoryx2")]
    pub transport: String,
    /// Skip the evaluator process (multi-process mode)
    #[arg(long)]
    pub no_evaluator: bool,
    /// Updates per RL episode of a distributed run: `MIN,MAX` (the adaptive replay ratio: the
    /// learner trains flat out, taking episodes while it has done between MIN and MAX updates
    /// per episode) or `fixed` (train.rl.batches_per_episode each) [default: the config's
    /// train.rl.replay_ratio, else 4,20; a resumed run keeps its own; --single-process: fixed]
    #[arg(long, value_name = "MIN,MAX|fixed", allow_hyphen_values = true, value_parser = ReplayRatioArg::parse)]
    pub replay_ratio: Option<ReplayRatioArg>,
    /// Serve a live page of the run on http://127.0.0.1:PORT/ (`fsrl dashboard`; the
    /// distributed mode, whose processes publish live metrics)
    #[arg(long, value_name = "PORT", conflicts_with = "single_process")]
    pub dashboard: Option<u16>,
    /// Write no TensorBoard files (runs/<run>/tb/); to measure what they cost (`cargo bench
    /// --bench watch_cost`) or where nobody reads them
    #[arg(long)]
    pub no_tensorboard: bool,
}

fn resolve(args: &TrainArgs) -> anyhow::Result<Resolved> {
    let mut file = args.run.load()?;
    let mut problems = Vec::new();
    if let Some(n) = args.eval_episodes {
        file.train.eval_episodes = n;
    }
    if let Some(n) = args.checkpoint_every {
        file.train.checkpoint_every_episodes = n;
    }
    if file.run.method == "orca" {
        problems.push("method orca is not trainable; evaluate it with `fsrl sim`".to_string());
    }
    Ok(file.resolve(problems)?)
}

/// The default mode: learner, actors and an evaluator as child processes (`launch::local`).
fn distributed(args: TrainArgs) -> anyhow::Result<()> {
    let stop = Arc::new(AtomicBool::new(false));
    {
        let stop = stop.clone();
        ctrlc::set_handler(move || {
            if stop.swap(true, Ordering::SeqCst) {
                std::process::exit(130);
            }
            eprintln!("\ninterrupted: stopping the learner (it checkpoints), actors and evaluator; Ctrl-C again to quit at once");
        })
        .context("cannot install the Ctrl-C handler")?;
    }
    let mut problems = Vec::new();
    let data_plane = match args.transport.as_str() {
        "iceoryx2" => DataPlane::Iceoryx2,
        "zenoh" => DataPlane::Zenoh,
        other => {
            problems.push(format!(
                "--transport must be iceoryx2 or zenoh, got `{other}`"
            ));
            DataPlane::Zenoh
        }
    };
    if args.actors == 0 {
        problems.push("--actors must be at least 1".to_string());
    }
    let mut resolved = match resolve(&args) {
        Ok(r) => r,
        Err(e) => {
            if problems.is_empty() {
                return Err(e);
            }
            anyhow::bail!("{e:#}\n  - {}", problems.join("\n  - "));
        }
    };
    if !problems.is_empty() {
        return Err(sim::ConfigError { problems }.into());
    }
    let out = args
        .out
        .clone()
        .unwrap_or_else(|| resolved.default_run_dir());
    let flag = args.replay_ratio.map(|ReplayRatioArg(r)| r);
    resolved.for_processes(&out, args.resume, flag, !args.no_evaluator)?;
    let launch = launch::local::Launch {
        exe: std::env::current_exe().context("cannot find the fsrl executable")?,
        resolved,
        out,
        resume: args.resume,
        actors: args.actors,
        data_plane,
        evaluator: !args.no_evaluator,
        eval_episodes: args.eval_episodes,
        dashboard: args.dashboard,
        tensorboard: !args.no_tensorboard,
    };
    launch::local::run(launch, &stop)
}

pub fn run(args: TrainArgs) -> anyhow::Result<()> {
    if !args.single_process {
        return distributed(args);
    }
    let stop = Arc::new(AtomicBool::new(false));
    {
        let stop = stop.clone();
        ctrlc::set_handler(move || {
            if stop.swap(true, Ordering::SeqCst) {
                eprintln!("second interrupt: exiting without a final checkpoint");
                std::process::exit(130);
            }
            eprintln!("\ninterrupted: finishing the current episode and writing a checkpoint (Ctrl-C again to quit at once)");
        })
        .context("cannot install the Ctrl-C handler")?;
    }
    let resolved = resolve(&args)?;
    let out = args
        .out
        .clone()
        .unwrap_or_else(|| resolved.default_run_dir());
    let single = launch::single::SingleRun {
        resolved,
        out,
        resume: args.resume,
        rl_episodes: args.run.rl_episodes,
        replay_ratio: args.replay_ratio.map(|ReplayRatioArg(r)| r),
        tensorboard: !args.no_tensorboard,
    };
    launch::single::run(single, &stop)
}

#[cfg(test)]
mod tests {
    use super::*;
    use clap::Parser;

    #[derive(Parser)]
    struct Cli {
        #[command(flatten)]
        train: TrainArgs,
    }

    fn try_args(extra: &[&str]) -> Result<TrainArgs, clap::Error> {
        Cli::try_parse_from(std::iter::once("fsrl-train").chain(extra.iter().copied()))
            .map(|c| c.train)
    }

    /// A bad `--replay-ratio` is refused as the arguments are parsed (issue 44): syntax and
    /// bounds. (Which ratio and which snapshot rule a run gets: `launch::config`'s tests.)
    #[test]
    fn a_bad_replay_ratio_is_refused_as_the_arguments_are_parsed() {
        let ok = |a: &[&str]| try_args(a).unwrap().replay_ratio;
        assert_eq!(ok(&[]), None);
        assert_eq!(ok(&["--replay-ratio", "fixed"]), Some(ReplayRatioArg(None)));
        assert_eq!(
            ok(&["--replay-ratio", "5,6"]),
            Some(ReplayRatioArg(Some(policy::method::ReplayRatio {
                min: 5.0,
                max: 6.0
            })))
        );
        for (bad, says) in [
            ("5", "MIN,MAX"),
            ("nan", "MIN,MAX"),
            ("inf", "MIN,MAX"),
            ("5,1", "must not exceed"),
            ("-1,4", "min >= 0"),
            ("0,0", "max > 0"),
            ("nan,4", "finite"),
            ("2,inf", "finite"),
        ] {
            let e = try_args(&["--replay-ratio", bad]).err();
            let e = e.map(|e| e.to_string()).unwrap_or_default();
            assert!(
                e.contains(says) && e.contains("--replay-ratio"),
                "{bad}: {e}"
            );
        }
    }
}
