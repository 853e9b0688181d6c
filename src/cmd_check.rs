//! `fsrl check-config FILE...`: parses and validates run configurations, printing each resolved
//! (with every default filled in) or every problem found. Without a file it checks the built-in
//! defaults (`fsrl check-config --print` shows them).

use std::path::PathBuf;

use crate::config::FileConfig;

#[derive(Debug, clap::Args)]
pub struct CheckArgs {
    /// Config files to check [default: the built-in defaults]
    pub files: Vec<PathBuf>,
    /// Print each resolved config
    #[arg(long)]
    pub print: bool,
}

pub fn run(args: CheckArgs) -> anyhow::Result<()> {
    let mut failed = 0;
    let files: Vec<Option<&PathBuf>> = if args.files.is_empty() {
        vec![None]
    } else {
        args.files.iter().map(Some).collect()
    };
    let total = files.len();
    for f in files {
        let name = f.map_or("the built-in defaults".to_string(), |f| {
            f.display().to_string()
        });
        let checked = FileConfig::load(f.map(|f| f.as_path())).and_then(|c| {
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
                    "ok: {name} (run {}, {} on {})",
                    r.file.run.id, r.method, r.setting
                );
                if args.print {
                    println!("{}", toml::to_string(&r.file)?);
                }
            }
            Err(e) => {
                failed += 1;
                eprintln!("error: {name}: {e:#}");
            }
        }
    }
    if failed > 0 {
        anyhow::bail!("{failed} of {total} config file(s) invalid");
    }
    Ok(())
}
