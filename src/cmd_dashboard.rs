//! `fsrl dashboard`: a live page of one run, or of every run it sees, in the browser
//! (`dashboard::run`: metrics, status and liveliness over zenoh, served over HTTP with
//! Server-Sent Events; the page's files are compiled in).

use std::net::TcpListener;
use std::sync::atomic::AtomicBool;

use anyhow::Context;
use transport::Transport;

#[derive(Debug, clap::Args)]
pub struct DashboardArgs {
    #[command(flatten)]
    pub monitor: crate::config::MonitorArgs,
    /// Run id to show [default: every run whose metrics reach this process, each under its
    /// id]
    #[arg(long)]
    pub run: Option<String>,
    /// Port of the page (0: any free port, printed)
    #[arg(long, default_value_t = 8080)]
    pub port: u16,
    /// Address to serve the page on (loopback by default: the page is for this machine)
    #[arg(long, default_value = "127.0.0.1")]
    pub bind: std::net::IpAddr,
}

pub fn run(args: DashboardArgs) -> anyhow::Result<()> {
    // Every run: the subscriptions are `fsrl/*/…`; the session's own run names nothing.
    let (run, scope) = match &args.run {
        Some(run) => (run.as_str(), dashboard::Scope::Run),
        None => ("dashboard", dashboard::Scope::EveryRun),
    };
    let cfg = args.monitor.transport_config(run)?;
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
    match &args.run {
        Some(run) => println!("dashboard of run `{run}`: http://{addr}/"),
        None => println!("dashboard of every run it sees: http://{addr}/"),
    }
    dashboard::run(&t, scope, listener, &AtomicBool::new(false))?;
    Ok(())
}
