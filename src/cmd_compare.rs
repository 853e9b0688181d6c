//! `fsrl compare RUN...`: one table across runs, methods × settings, mean ± std over the runs
//! (seeds) of each method, the paper's numbers beside ours where it has them (`lab::compare`).

use std::path::PathBuf;

#[derive(Debug, clap::Args)]
pub struct CompareArgs {
    /// Run directories of `fsrl train` (evaluated with `fsrl eval RUN` for all six settings) or
    /// eval.json files.
    #[arg(required = true)]
    pub runs: Vec<PathBuf>,
    /// Also write compare.md, compare.csv and compare.json into this directory.
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// A second arm (same kinds of sources) to test the first against: per setting and metric,
    /// each run's value, mean ± std with a 95 % t interval over runs, and Welch's t-test of the
    /// difference of the means. Each arm must hold a single method.
    #[arg(long, num_args = 1..)]
    pub vs: Vec<PathBuf>,
}

pub fn run(args: CompareArgs) -> anyhow::Result<()> {
    let c = lab::compare::compare(&args.runs, &args.vs)?;
    println!("{}", c.markdown);
    if let Some(dir) = &args.out {
        c.write_to(dir)?;
        println!(
            "written: {}/compare.md, compare.csv, compare.json",
            dir.display()
        );
    }
    Ok(())
}
