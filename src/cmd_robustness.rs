//! `fsrl robustness MODEL...`: issue 54's robustness table. Every model is tested, without
//! retraining, in the setting it was trained in with 5, 10, 15 and 20 moving people, all ORCA
//! or all social force (`lab::robustness`), the ORCA robot beside them with `--orca`; one
//! `fsrl eval` report per crowd and setting (resumable), then `robustness.md` and `.json`.

use std::path::PathBuf;

use lab::evaluation::LoadedPolicy;
use lab::policy_choice::resolve_input;
use lab::robustness::{self, Plan, Table};

use crate::config::FileConfig;

#[derive(Debug, clap::Args)]
pub struct RobustnessArgs {
    /// Model files (.fsrlm), checkpoints or run directories, trained in the paper's settings.
    pub inputs: Vec<PathBuf>,
    /// Also the ORCA robot, in all six settings.
    #[arg(long)]
    pub orca: bool,
    /// Simulator config for the ORCA robot (TOML with a [sim] table).
    #[arg(long)]
    pub config: Option<PathBuf>,
    /// Test episodes per setting and crowd.
    #[arg(long, default_value_t = 500)]
    pub episodes: u32,
    /// First test seed.
    #[arg(long, default_value_t = 1000)]
    pub seed_start: u64,
    /// Where the reports go (kept: a second run evaluates only what is missing; other models
    /// add their rows).
    #[arg(long, default_value = "robustness")]
    pub out: PathBuf,
    /// Worker threads [default: all cores].
    #[arg(long)]
    pub threads: Option<usize>,
    /// Only rebuild the table from the reports already in --out.
    #[arg(long)]
    pub table_only: bool,
}

pub fn run(args: RobustnessArgs) -> anyhow::Result<()> {
    if !args.table_only {
        if args.inputs.is_empty() && !args.orca {
            anyhow::bail!(
                "nothing to evaluate: name model files or run directories, or pass --orca"
            );
        }
        if args.episodes == 0 {
            anyhow::bail!("--episodes must be at least 1");
        }
        let policies = args
            .inputs
            .iter()
            .map(|p| LoadedPolicy::read(&resolve_input(p, None)?))
            .collect::<anyhow::Result<Vec<_>>>()?;
        let sim = FileConfig::load(args.config.as_deref())?.sim;
        sim.validate()?;
        let threads = args
            .threads
            .unwrap_or_else(|| std::thread::available_parallelism().map_or(1, |n| n.get()));
        let plan = Plan {
            policies: &policies,
            orca_sim: args.orca.then_some(&sim),
            episodes: args.episodes,
            seed_start: args.seed_start,
            threads,
        };
        let bar = std::sync::Mutex::new(None::<indicatif::ProgressBar>);
        let progress = |name: &str, len: u64| {
            if let Ok(mut b) = bar.lock() {
                if let Some(old) = b.take() {
                    old.finish_and_clear();
                }
                eprintln!("robustness: {name}");
                *b = Some(crate::cmd_eval::progress(len, name));
            }
        };
        let done = || {
            if let Ok(b) = bar.lock() {
                if let Some(b) = b.as_ref() {
                    b.inc(1);
                }
            }
        };
        robustness::run(&plan, &args.out, &progress, &done)?;
        let last = bar.lock().ok().and_then(|mut b| b.take());
        if let Some(b) = last {
            b.finish_and_clear();
        }
    }
    let table = Table::collect(&args.out)?;
    table.write(&args.out)?;
    println!("{}", table.markdown());
    println!(
        "written: {}/robustness.md, robustness.json",
        args.out.display()
    );
    Ok(())
}
