//! `fsrl`: one command for simulating, training, evaluating and watching crowd-navigation
//! policies. The binary is thin: parse arguments, install logging, run a subcommand.

mod cmd_check;
mod cmd_compare;
mod cmd_dashboard;
mod cmd_eval;
mod cmd_model;
mod cmd_plot;
mod cmd_reproduce;
mod cmd_robot;
mod cmd_robustness;
mod cmd_roles;
mod cmd_router;
mod cmd_serve;
mod cmd_sim;
mod cmd_train;
mod cmd_watch;
mod config;

use std::process::ExitCode;

use clap::{Parser, Subcommand};

#[derive(Debug, Parser)]
#[command(
    name = "fsrl",
    version,
    about = "Foresight social-aware RL for crowd navigation"
)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Debug, Subcommand)]
enum Command {
    /// Run the ORCA robot on the six settings: metrics table and an episode picture.
    Sim(cmd_sim::SimArgs),
    /// Train one method on one setting: imitation, then deep V-learning, then evaluation.
    Train(cmd_train::TrainArgs),
    /// Evaluate checkpoints, model files or ORCA on all six settings: metrics with intervals (md,
    /// csv, json).
    Eval(cmd_eval::EvalArgs),
    /// Write a run's trained policy as a small model file (.fsrlm) with a recorded check.
    ExportModel(cmd_model::ExportArgs),
    /// One table across runs: methods × settings, mean ± std over seeds, beside the paper.
    Compare(cmd_compare::CompareArgs),
    /// Every model tested, without retraining, with 5/10/15/20 ORCA or social-force people.
    Robustness(cmd_robustness::RobustnessArgs),
    /// Pictures (SVG and PNG): outcome bars, learning curves, ablation, episode with attention.
    Plot(cmd_plot::PlotArgs),
    /// The paper's grid: train methods × settings × seeds (resumable), export, evaluate, report.
    Reproduce(cmd_reproduce::ReproduceArgs),
    /// The learner process of a distributed run.
    Learner(cmd_roles::LearnerArgs),
    /// An actor process of a distributed run.
    Actor(cmd_roles::ActorArgs),
    /// The evaluator process of a distributed run, or `--checkpoint FILE` offline.
    Evaluator(cmd_roles::EvaluatorArgs),
    /// A zenoh router (TLS, user/password, access control) from a zenoh JSON5 file.
    Router(cmd_router::RouterArgs),
    /// Show a run's live metrics.
    Watch(cmd_watch::WatchArgs),
    /// A live page of a run in the browser: validation curves, throughput, lag, processes.
    Dashboard(cmd_dashboard::DashboardArgs),
    /// Parse and validate run configuration files.
    CheckConfig(cmd_check::CheckArgs),
    /// Drive a robot with a model over zenoh: ROS 2 topics (bridge or rmw_zenoh) and a queryable.
    Serve(cmd_serve::ServeArgs),
}

fn main() -> ExitCode {
    tracing_subscriber::fmt()
        .with_env_filter(
            tracing_subscriber::EnvFilter::try_from_default_env().unwrap_or_else(|_| {
                tracing_subscriber::EnvFilter::new("info,zenoh=warn,zenoh_transport=warn")
            }),
        )
        .with_writer(std::io::stderr)
        .with_ansi(std::io::IsTerminal::is_terminal(&std::io::stderr()))
        .init();
    let cli = Cli::parse();
    if matches!(
        cli.command,
        Command::Sim(_)
            | Command::Eval(_)
            | Command::ExportModel(_)
            | Command::Compare(_)
            | Command::Robustness(_)
            | Command::Plot(_)
            | Command::CheckConfig(_)
    ) {
        // Commands that open no socket end quietly when their output is closed (`| head`), as
        // Unix tools do, instead of panicking on the failed print. Networked ones keep Rust's
        // ignored SIGPIPE, so a peer closing a connection is an error, not a kill.
        // SAFETY: setting a signal's disposition to the default at startup, before any thread.
        unsafe {
            libc::signal(libc::SIGPIPE, libc::SIG_DFL);
        }
    }
    let result = match cli.command {
        Command::Sim(args) => cmd_sim::run(args),
        Command::Train(args) => cmd_train::run(args),
        Command::Eval(args) => cmd_eval::run(args),
        Command::ExportModel(args) => cmd_model::run(args),
        Command::Compare(args) => cmd_compare::run(args),
        Command::Robustness(args) => cmd_robustness::run(args),
        Command::Plot(args) => cmd_plot::run(args),
        Command::Reproduce(args) => cmd_reproduce::run(args),
        Command::Learner(args) => cmd_roles::learner(args),
        Command::Actor(args) => cmd_roles::actor(args),
        Command::Evaluator(args) => cmd_roles::evaluator(args),
        Command::Router(args) => cmd_router::run(args),
        Command::Watch(args) => cmd_watch::run(args),
        Command::Dashboard(args) => cmd_dashboard::run(args),
        Command::CheckConfig(args) => cmd_check::run(args),
        Command::Serve(args) => cmd_serve::run(args),
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {e:#}");
            ExitCode::FAILURE
        }
    }
}

#[cfg(test)]
mod tests {
    #[test]
    fn the_command_line_definition_is_consistent() {
        // clap's own checks (duplicate flags, conflicting names), which release builds skip.
        <super::Cli as clap::CommandFactory>::command().debug_assert();
    }
}
