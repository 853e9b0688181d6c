//! `fsrl watch`: live metrics of a run from another terminal (any tool can do the same: the
//! messages are MessagePack with field names under `fsrl/<run>/metrics/**`); with
//! `--tensorboard DIR`, TensorBoard files of them instead (`tboard::LiveBoard`).

use std::time::{Duration, Instant};

use proto::keys;
use transport::Transport;

#[derive(Debug, clap::Args)]
pub struct WatchArgs {
    #[command(flatten)]
    pub monitor: crate::config::MonitorArgs,
    /// Run id
    #[arg(long, default_value = "local")]
    pub run: String,
    /// Stop after this many messages (0: until Ctrl-C)
    #[arg(long, default_value_t = 0)]
    pub count: u64,
    /// Stop after this many seconds (0: never)
    #[arg(long, default_value_t = 0.0)]
    pub timeout_s: f64,
    /// Write TensorBoard event files of the metrics into this directory instead of printing
    /// them (the tags of a run directory's tb/; `tensorboard --logdir DIR`)
    #[arg(long, value_name = "DIR")]
    pub tensorboard: Option<std::path::PathBuf>,
}

pub fn run(args: WatchArgs) -> anyhow::Result<()> {
    let cfg = args.monitor.transport_config(&args.run)?;
    let t = Transport::open(cfg)?;
    let sub = t.subscriber(&keys::all_metrics(t.run()))?;
    let mut board = match &args.tensorboard {
        Some(dir) => {
            let b = tboard::LiveBoard::open(dir)
                .map_err(|e| anyhow::anyhow!("--tensorboard {}: {e}", dir.display()))?;
            eprintln!("writing TensorBoard files to {}", b.path().display());
            Some(b)
        }
        None => None,
    };
    let start = Instant::now();
    let mut seen = 0u64;
    let mut quiet_warned = false;
    loop {
        if args.timeout_s > 0.0 && start.elapsed().as_secs_f64() > args.timeout_s {
            return Ok(());
        }
        match sub.recv_timeout(Duration::from_millis(500))? {
            Some(m) if board.is_some() => {
                if let Some(b) = &mut board {
                    b.message(m.header.sender, &m.body)
                        .map_err(|e| anyhow::anyhow!("writing TensorBoard files: {e}"))?;
                }
                seen += 1;
                if args.count > 0 && seen >= args.count {
                    return Ok(());
                }
            }
            Some(m) => {
                let vals: Vec<String> = m
                    .body
                    .values
                    .iter()
                    .map(|(k, v)| format!("{k}={v:.4}"))
                    .collect();
                println!(
                    "{} episodes={} env_steps={} {}",
                    m.header.sender,
                    m.body.episodes,
                    m.body.env_steps,
                    vals.join(" ")
                );
                seen += 1;
                if args.count > 0 && seen >= args.count {
                    return Ok(());
                }
            }
            None if !quiet_warned && start.elapsed() > Duration::from_secs(5) && seen == 0 => {
                eprintln!(
                    "no metrics yet from run `{}` via {:?}; still listening",
                    args.run,
                    t.config().zenoh.connect
                );
                quiet_warned = true;
            }
            None => {}
        }
    }
}
