//! `fsrl dashboard`: a live page of a run in the browser (`dashboard::run`: metrics, status
//! and liveliness over zenoh, served over HTTP with Server-Sent Events; the page's files are
//! compiled in).

use std::net::TcpListener;
use std::sync::atomic::AtomicBool;

use anyhow::Context;
use proto::{Role, RunId, SenderId};
use transport::{Transport, TransportConfig, ZenohConfig};

#[derive(Debug, clap::Args)]
pub struct DashboardArgs {
    /// zenoh endpoint of a process of the run (the learner) or a router (repeatable)
    #[arg(long, required_unless_present = "config")]
    pub connect: Vec<String>,
    /// Take the zenoh session (mode, endpoints, TLS, credentials) from this run config's
    /// [transport.zenoh], e.g. deploy/cluster-monitor.toml; --connect still overrides
    #[arg(long)]
    pub config: Option<std::path::PathBuf>,
    /// Run id
    #[arg(long, default_value = "local")]
    pub run: String,
    /// Port of the page (0: any free port, printed)
    #[arg(long, default_value_t = 8080)]
    pub port: u16,
    /// Address to serve the page on (loopback by default: the page is for this machine)
    #[arg(long, default_value = "127.0.0.1")]
    pub bind: std::net::IpAddr,
}

pub fn run(args: DashboardArgs) -> anyhow::Result<()> {
    let run =
        RunId::new(args.run.clone()).map_err(|e| anyhow::anyhow!("--run `{}`: {e}", args.run))?;
    let mut cfg = TransportConfig::new(run, SenderId::new(Role::Monitor, std::process::id()));
    cfg.zenoh = match &args.config {
        Some(path) => {
            let mut z = crate::config::FileConfig::load(Some(path))?.transport.zenoh;
            if !args.connect.is_empty() {
                z.connect = args.connect.clone();
            }
            z
        }
        None => ZenohConfig::peer(vec!["tcp/127.0.0.1:0".into()], args.connect.clone()),
    };
    let listener = TcpListener::bind((args.bind, args.port))
        .with_context(|| format!("cannot serve the page on {}:{}", args.bind, args.port))?;
    let addr = listener.local_addr()?;
    // The run's processes or router may not be up yet: try again, as the roles do.
    let mut wait = std::time::Duration::from_millis(500);
    let t = loop {
        match Transport::open(cfg.clone()) {
            Ok(t) => break t,
            Err(e @ transport::TransportError::Config(_)) => {
                return Err(e).context("cannot open the transport")
            }
            Err(e) => {
                eprintln!(
                    "cannot open the transport (connect {:?}): {e}; retrying in {:.1} s",
                    cfg.zenoh.connect,
                    wait.as_secs_f64()
                );
                std::thread::sleep(wait);
                wait = (wait * 2).min(std::time::Duration::from_secs(10));
            }
        }
    };
    println!("dashboard of run `{}`: http://{addr}/", args.run);
    dashboard::run(&t, listener, &AtomicBool::new(false))?;
    Ok(())
}
