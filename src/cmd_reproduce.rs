//! `fsrl reproduce`: the paper's grid in one command (`launch::reproduce`: methods × settings ×
//! seeds trained, exported and evaluated as child processes of this executable, then one report
//! beside the paper's numbers). This module parses the arguments.

use std::path::PathBuf;

use crate::config::ReplayRatioArg;

#[derive(Debug, clap::Args)]
pub struct ReproduceArgs {
    /// Run configuration of every run ([train] schedule, [sim] simulator) [default: the
    /// built-in defaults: the short schedule of configs/fast.toml; the paper's is
    /// configs/paper.toml]
    #[arg(long)]
    pub config: Option<PathBuf>,
    /// Train each run in one process (`fsrl train --single-process`: bit-for-bit reproducible,
    /// the path that trained the shipped models) instead of learner, actors and evaluator
    #[arg(long)]
    pub single_process: bool,
    /// Actor processes of each distributed run
    #[arg(long, default_value_t = 2)]
    pub actors: u32,
    /// Updates per RL episode of each distributed run (`fsrl train --replay-ratio`): `MIN,MAX`
    /// or `fixed` [default: the config's train.rl.replay_ratio, else 4,20]
    #[arg(long, value_name = "MIN,MAX|fixed", allow_hyphen_values = true, value_parser = ReplayRatioArg::parse)]
    pub replay_ratio: Option<ReplayRatioArg>,
    /// Train only shard I of N of the grid (0 ≤ I < N; run k of the grid, in its order, belongs
    /// to shard k mod N), for a cluster scheduler's array job. Without it: from
    /// SLURM_ARRAY_TASK_ID − SLURM_ARRAY_TASK_MIN of SLURM_ARRAY_TASK_COUNT, or Kubernetes'
    /// JOB_COMPLETION_INDEX of FSRL_SHARDS; otherwise the whole grid. A shard writes no report:
    /// `fsrl reproduce --no-train` over the shared directories writes it
    #[arg(long, value_name = "I/N")]
    pub shard: Option<String>,
    /// Methods to train, comma-separated, run in this order
    #[arg(long, value_delimiter = ',', default_values = ["lstm-rl", "sarl", "fsrl"])]
    pub methods: Vec<String>,
    /// Settings, comma-separated, in this order; each run is trained and evaluated in its own
    /// setting [default: all six]
    #[arg(long, value_delimiter = ',')]
    pub settings: Vec<String>,
    /// Run seeds, comma-separated, in this order
    #[arg(long, value_delimiter = ',', default_values_t = [0u64, 1, 2])]
    pub seeds: Vec<u64>,
    /// Run directories: RUNS/<method>-<setting>-s<seed>; evaluations in RUNS/eval/
    #[arg(long, default_value = "runs/reproduce")]
    pub runs: PathBuf,
    /// Model files: MODELS/<method>-<setting>-s<seed>.fsrlm
    #[arg(long, default_value = "models")]
    pub models: PathBuf,
    /// Test episodes of each evaluation (seeds from 1000)
    #[arg(long, default_value_t = 500)]
    pub episodes: u32,
    /// Report directory (compare.md, compare.csv, compare.json) [default: RUNS/report]
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// Print the plan (finished, to resume, to train) and the estimated time; run nothing
    #[arg(long)]
    pub dry_run: bool,
    /// Train nothing: export, evaluate and report the runs that are finished
    #[arg(long)]
    pub no_train: bool,
}

pub fn run(args: ReproduceArgs) -> anyhow::Result<()> {
    launch::reproduce::run(launch::reproduce::Request {
        config: args.config,
        single_process: args.single_process,
        actors: args.actors,
        replay_ratio: args.replay_ratio.map(|ReplayRatioArg(r)| r),
        shard: args.shard,
        methods: args.methods,
        settings: args.settings,
        seeds: args.seeds,
        runs: args.runs,
        models: args.models,
        episodes: args.episodes,
        out: args.out,
        dry_run: args.dry_run,
        no_train: args.no_train,
    })
}
