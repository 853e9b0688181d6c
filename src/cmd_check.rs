//! `fsrl check-config FILE...`: parses and validates run configurations, printing each resolved
//! (with every default filled in) or every problem found.

use std::path::PathBuf;

use crate::config::FileConfig;

#[derive(Debug, clap::Args)]
pub struct CheckArgs {
    /// Config files to check
    #[arg(required = true)]
    pub files: Vec<PathBuf>,
    /// Print each resolved config
    #[arg(long)]
    pub print: bool,
}

pub fn run(args: CheckArgs) -> anyhow::Result<()> {
    let mut failed = 0;
    for f in &args.files {
        let checked = FileConfig::load(Some(f)).and_then(|c| {
            let r = c.resolve(Vec::new())?;
            r.file
                .transport
                .for_sender(
                    &r.file.run.id,
                    proto::SenderId::new(proto::Role::Monitor, 0),
                )?
                .validate()?;
            Ok(r)
        });
        match checked {
            Ok(r) => {
                println!(
                    "ok: {} (run {}, {} on {})",
                    f.display(),
                    r.file.run.id,
                    r.method,
                    r.setting
                );
                if let Some(problem) = crate::select::distributed_problem(&r.file.train) {
                    println!("  note: not for multi-process `fsrl train` nor the learner/actor/evaluator commands: {problem}");
                }
                if args.print {
                    println!("{}", toml::to_string(&r.file)?);
                }
            }
            Err(e) => {
                failed += 1;
                eprintln!("error: {}: {e:#}", f.display());
            }
        }
    }
    if failed > 0 {
        anyhow::bail!("{failed} of {} config file(s) invalid", args.files.len());
    }
    Ok(())
}
