//! `fsrl eval`: scores model files, checkpoints (or the ORCA baseline) on the test seeds of all
//! six settings with the paper's five metrics plus path length, smoothness and return, with 95% intervals, and
//! writes `eval.md` (the paper's table layout beside the paper's numbers), `eval.csv` and
//! `eval.json`.
//!
//! Every episode is one call of `evaluator::evaluate`, so the numbers are exactly those of the
//! evaluator (and of `fsrl train`'s report) while the per-episode values give the intervals.

use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::Mutex;

use anyhow::{bail, Context};
use evaluator::{evaluate, Subject};
use indicatif::{ProgressBar, ProgressDrawTarget, ProgressStyle};
use learner::model::{self, ArtifactKind, Model};
use policy::lookahead::HumanModel;
use policy::method::{Method, Select};
use sim::{Aggregate, Setting, SimConfig};

use crate::config::FileConfig;
use crate::report::{EvalReport, Samples, SettingReport, SubjectReport, EVAL_KIND};

#[derive(Debug, clap::Args)]
pub struct EvalArgs {
    /// Model files (.fsrlm, from `fsrl export-model`), checkpoints (.ckpt files) or run
    /// directories of `fsrl train` (their checkpoints/latest.ckpt, or the validation snapshot
    /// their `train.select` chooses); a file's kind is read from its first bytes.
    pub inputs: Vec<PathBuf>,
    /// Which weights of a run directory: last, best-validation or low-disc [default: the run's
    /// train.select].
    #[arg(long, value_parser = parse_select)]
    pub select: Option<Select>,
    /// Also evaluate the ORCA baseline.
    #[arg(long)]
    pub orca: bool,
    /// Test episodes per setting.
    #[arg(long, default_value_t = 500)]
    pub episodes: u32,
    /// First test seed (CrowdNav's test seeds start at 1000).
    #[arg(long, default_value_t = 1000)]
    pub seed_start: u64,
    /// Settings, comma-separated (default: all six).
    #[arg(long, value_delimiter = ',')]
    pub settings: Vec<String>,
    /// Output directory for eval.md, eval.csv and eval.json [default: RUN/eval for a single run
    /// directory, else ./eval].
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// Worker threads [default: all cores].
    #[arg(long)]
    pub threads: Option<usize>,
    /// Simulator config for the ORCA baseline (TOML with a [sim] table; models and checkpoints
    /// carry their own).
    #[arg(long)]
    pub config: Option<PathBuf>,
    /// Extra radius the ORCA robot keeps from humans (CrowdNav: 0 at test time).
    #[arg(long, default_value_t = 0.0)]
    pub safety_space_m: f64,
}

/// A policy file (model file or checkpoint) and the run directory it belongs to, if any.
pub struct Input {
    pub checkpoint: PathBuf,
    pub run_dir: Option<PathBuf>,
}

/// `--select`: a `train.select` value.
pub fn parse_select(s: &str) -> Result<Select, String> {
    [Select::Last, Select::BestValidation, Select::LowDisc]
        .into_iter()
        .find(|r| r.name() == s)
        .ok_or_else(|| format!("{s:?}: not one of last, best-validation, low-disc"))
}

/// A run directory means its `checkpoints/latest.ckpt` or the validation snapshot its
/// `train.select` (or `select`, when given) chooses; anything else is a model file or a
/// checkpoint.
pub fn resolve_input(path: &Path, select: Option<Select>) -> anyhow::Result<Input> {
    if path.is_dir() {
        if !path.join("checkpoints").join("latest.ckpt").exists() {
            bail!(
                "{}: a directory without checkpoints/latest.ckpt (not a run directory of `fsrl train`)",
                path.display()
            );
        }
        Ok(Input {
            checkpoint: crate::select::run_policy(path, select)?,
            run_dir: Some(path.to_path_buf()),
        })
    } else if path.exists() {
        Ok(Input {
            checkpoint: path.to_path_buf(),
            run_dir: None,
        })
    } else {
        bail!("{}: no such checkpoint or run directory", path.display())
    }
}

/// A short name: the run directory's name, else `<dir>/<file stem>` of the checkpoint.
pub fn label_of(input: &Input) -> String {
    let name = |p: &Path| {
        p.file_name().map_or_else(
            || p.display().to_string(),
            |n| n.to_string_lossy().into_owned(),
        )
    };
    match &input.run_dir {
        Some(d) => name(&d.canonicalize().unwrap_or_else(|_| d.clone())),
        None => {
            let stem = input
                .checkpoint
                .file_stem()
                .map_or_else(String::new, |s| s.to_string_lossy().into_owned());
            match input.checkpoint.parent().map(name) {
                Some(dir) if !dir.is_empty() => format!("{dir}/{stem}"),
                _ => stem,
            }
        }
    }
}

/// Loads the policy of a model file or a checkpoint (told apart by content) with a message
/// naming it.
pub fn load_policy(path: &Path) -> anyhow::Result<(Model, ArtifactKind)> {
    model::load_policy(path).with_context(|| format!("cannot load {}", path.display()))
}

/// SHA-256 of a file's bytes, 64 lowercase hex digits (as `sha256sum`): the content id a report
/// records for the file it evaluated ([`crate::report::SubjectReport::checkpoint_sha256`]).
///
/// Not a CRC: model files and checkpoints end with the CRC-32 of their payload, and the CRC-32 of
/// such a file is the same for every payload of one length (CRC's residue), so it told the
/// weights of two runs of one configuration apart no better than their size did.
pub fn file_sha256(path: &Path) -> anyhow::Result<String> {
    use sha2::Digest;
    let mut f =
        std::fs::File::open(path).with_context(|| format!("cannot open {}", path.display()))?;
    let mut hasher = sha2::Sha256::new();
    std::io::copy(&mut f, &mut hasher)
        .with_context(|| format!("cannot read {}", path.display()))?;
    Ok(hex(&hasher.finalize()))
}

/// [`file_sha256`] of bytes already read.
fn bytes_sha256(bytes: &[u8]) -> String {
    use sha2::Digest;
    hex(&sha2::Sha256::digest(bytes))
}

fn hex(digest: &[u8]) -> String {
    digest.iter().map(|b| format!("{b:02x}")).collect()
}

/// A model file names its method, trained setting and seed (its file name need not); a
/// checkpoint keeps its run's name.
pub fn subject_label(input: &Input, model: &Model, kind: ArtifactKind) -> String {
    match kind {
        ArtifactKind::Model => format!(
            "{} (trained {}, seed {})",
            model.method, model.setting, model.run_seed
        ),
        ArtifactKind::Checkpoint => label_of(input),
    }
}

/// Runs `episodes` test episodes per setting of one subject, one episode per evaluator call,
/// and reports every setting with its intervals.
pub fn evaluate_subject(
    subject: Subject<'_>,
    base: &SimConfig,
    settings: &[Setting],
    seed_start: u64,
    episodes: u32,
    threads: usize,
    bar: &ProgressBar,
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
                        bar.inc(1);
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

pub fn progress(len: u64, what: &str) -> ProgressBar {
    let bar = ProgressBar::with_draw_target(Some(len), ProgressDrawTarget::stderr_with_hz(4));
    bar.set_style(
        ProgressStyle::with_template(&format!(
            "{what:>12} [{{elapsed_precise}}] {{bar:30}} {{pos}}/{{len}} ({{per_sec}}, ETA {{eta}})"
        ))
        .expect("valid template"),
    );
    bar
}

/// The settings named on the command line (all six when none), every problem reported at once.
pub fn parse_settings(names: &[String]) -> anyhow::Result<Vec<Setting>> {
    if names.is_empty() {
        return Ok(Setting::ALL.to_vec());
    }
    Ok(SimConfig::default().resolve_settings(names)?)
}

pub fn run(args: EvalArgs) -> anyhow::Result<()> {
    if args.inputs.is_empty() && !args.orca {
        bail!(
            "nothing to evaluate: name model files, checkpoints or run directories, or pass --orca"
        );
    }
    if args.episodes == 0 {
        bail!("--episodes must be at least 1");
    }
    let settings = parse_settings(&args.settings)?;
    let inputs = args
        .inputs
        .iter()
        .map(|p| resolve_input(p, args.select))
        .collect::<anyhow::Result<Vec<_>>>()?;
    let threads = args
        .threads
        .unwrap_or_else(|| std::thread::available_parallelism().map_or(1, |n| n.get()));
    let out = match &args.out {
        Some(o) => o.clone(),
        None => match inputs.as_slice() {
            [Input {
                run_dir: Some(d), ..
            }] if !args.orca => d.join("eval"),
            _ => PathBuf::from("eval"),
        },
    };
    let mut subjects = Vec::new();
    let per_subject = settings.len() as u64 * args.episodes as u64;
    if args.orca {
        let sim = FileConfig::load(args.config.as_deref())?.sim;
        sim.validate()?;
        let bar = progress(per_subject, "orca");
        let subject = Subject {
            method: Method::Orca,
            net: None,
            gamma: 0.9,
            human_model: HumanModel::Orca,
            terminal_previews: false,
            orca_safety_space_m: args.safety_space_m,
        };
        let reports = evaluate_subject(
            subject,
            &sim,
            &settings,
            args.seed_start,
            args.episodes,
            threads,
            &bar,
        )?;
        bar.finish_and_clear();
        subjects.push(SubjectReport {
            label: "orca".into(),
            method: "orca".into(),
            checkpoint: None,
            checkpoint_sha256: None,
            policy_version: 0,
            run_seed: None,
            trained_setting: None,
            settings: reports,
        });
    }
    for input in &inputs {
        // Read once: the weights evaluated are the bytes whose hash the report records, even
        // when the file is replaced meanwhile (a training exporting its model).
        let (model, kind, sha256) = {
            let path = &input.checkpoint;
            let bytes =
                std::fs::read(path).with_context(|| format!("cannot read {}", path.display()))?;
            let (model, kind) = model::policy_from_bytes(path, &bytes)
                .with_context(|| format!("cannot load {}", path.display()))?;
            (model, kind, bytes_sha256(&bytes))
        };
        let method = model.method;
        let label = subject_label(input, &model, kind);
        let subject = Subject {
            orca_safety_space_m: args.safety_space_m,
            ..Subject::learned(method, &model.net, &model.train)
        };
        let bar = progress(per_subject, &label.chars().take(12).collect::<String>());
        let reports = evaluate_subject(
            subject,
            &model.sim,
            &settings,
            args.seed_start,
            args.episodes,
            threads,
            &bar,
        )
        .with_context(|| format!("evaluating {}", input.checkpoint.display()))?;
        bar.finish_and_clear();
        eprintln!(
            "evaluated {label} ({method} trained on {}, policy version {})",
            model.setting, model.counters.policy_version
        );
        subjects.push(SubjectReport {
            label,
            method: method.name().to_string(),
            checkpoint: Some(input.checkpoint.display().to_string()),
            checkpoint_sha256: Some(sha256),
            policy_version: model.counters.policy_version,
            run_seed: Some(model.run_seed),
            trained_setting: Some(model.setting.name().to_string()),
            settings: reports,
        });
    }
    let report = EvalReport {
        kind: EVAL_KIND.into(),
        test_seed_start: args.seed_start,
        episodes_per_setting: args.episodes,
        subjects,
    };
    report.write(&out)?;
    println!("{}", report.markdown());
    println!("written: {}/eval.md, eval.csv, eval.json", out.display());
    Ok(())
}
