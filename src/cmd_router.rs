//! `fsrl router --config deploy/router.json5`: a zenoh router built from the same zenoh as the
//! other processes, configured by a native zenoh JSON5 file (the very file `zenohd -c` reads),
//! running until SIGINT/SIGTERM. In a cluster it terminates TLS, checks user/password
//! credentials and enforces access control; learner, actors and evaluator are its clients.

use std::path::{Path, PathBuf};
use std::sync::atomic::Ordering;
use std::time::Duration;

use anyhow::{bail, Context};
use zenoh::Wait;

use crate::cmd_roles::stop_flag;

#[derive(Debug, clap::Args)]
pub struct RouterArgs {
    /// zenoh JSON5 configuration file (e.g. deploy/router.json5; `zenohd -c` reads the same)
    #[arg(long)]
    pub config: PathBuf,
    /// Override one setting, `KEY:VALUE` with a JSON5 value, as `zenohd --cfg` does, e.g.
    /// --cfg 'listen/endpoints:["tls/10.0.0.1:7447"]' (repeatable)
    #[arg(long = "cfg", value_name = "KEY:VALUE")]
    pub cfg: Vec<String>,
    /// Check the configuration (parse, mode, files it names) and exit without opening
    #[arg(long)]
    pub check: bool,
}

/// zenoh settings that name files the router must be able to read, and whether the file is a
/// secret (a private key, the users' passwords) that group and others must not read.
const FILE_KEYS: [(&str, bool); 6] = [
    ("transport/link/tls/root_ca_certificate", false),
    ("transport/link/tls/listen_certificate", false),
    ("transport/link/tls/listen_private_key", true),
    ("transport/link/tls/connect_certificate", false),
    ("transport/link/tls/connect_private_key", true),
    ("transport/auth/usrpwd/dictionary_file", true),
];

/// The router's zenoh configuration: the file, then the `--cfg` overrides; checked (router
/// mode, every file it names readable, its private keys and users file readable by its owner
/// only), every problem reported at once.
pub fn load(path: &Path, overrides: &[String]) -> anyhow::Result<zenoh::Config> {
    if !path.is_file() {
        bail!("cannot read the router configuration {}", path.display());
    }
    let mut c = zenoh::Config::from_file(path)
        .map_err(|e| anyhow::anyhow!("invalid zenoh configuration {}: {e}", path.display()))?;
    for o in overrides {
        let Some((key, value)) = o.split_once(':') else {
            bail!(
                "--cfg {o:?}: expected KEY:VALUE, e.g. 'listen/endpoints:[\"tls/0.0.0.0:7447\"]'"
            );
        };
        c.insert_json5(key, value)
            .map_err(|e| anyhow::anyhow!("--cfg {key}: {e}"))?;
    }
    let mut problems = Vec::new();
    match get(&c, "mode").as_deref() {
        Some("router") => {}
        None => c
            .insert_json5("mode", "\"router\"")
            .map_err(|e| anyhow::anyhow!("mode: {e}"))?,
        Some(m) => problems.push(format!("mode must be \"router\", got {m:?}")),
    }
    for (key, secret) in FILE_KEYS {
        if let Some(file) = get(&c, key) {
            if let Err(e) = std::fs::File::open(&file) {
                problems.push(format!("{key}: cannot read {file}: {e}"));
            } else if secret {
                // The same rule as the clients' password files and keys.
                problems.extend(transport::exposed_secret(key, Path::new(&file)));
            }
        }
    }
    if !problems.is_empty() {
        bail!(
            "invalid router configuration {} ({} problem{}):\n  - {}",
            path.display(),
            problems.len(),
            if problems.len() == 1 { "" } else { "s" },
            problems.join("\n  - ")
        );
    }
    Ok(c)
}

/// A string setting, or None when unset (JSON `null`) or not a string.
fn get(c: &zenoh::Config, key: &str) -> Option<String> {
    let v: serde_json::Value = serde_json::from_str(&c.get_json(key).ok()?).ok()?;
    v.as_str().map(str::to_string)
}

fn warnings(c: &zenoh::Config) -> Vec<&'static str> {
    let mut w = Vec::new();
    if c.get_json("access_control/enabled").ok().as_deref() != Some("true") {
        w.push("access control is off: any client may publish on any key");
    }
    if get(c, "transport/auth/usrpwd/dictionary_file").is_none() {
        w.push("no user/password dictionary: any client that reaches the router may connect");
    }
    let listen = c.get_json("listen/endpoints").unwrap_or_default();
    if listen.contains("tcp/") {
        w.push("a tcp/ (unencrypted) listen endpoint is configured");
    }
    w
}

pub fn run(args: RouterArgs) -> anyhow::Result<()> {
    let config = load(&args.config, &args.cfg)?;
    let listen = config.get_json("listen/endpoints").unwrap_or_default();
    for w in warnings(&config) {
        eprintln!("warning: {w}");
    }
    if args.check {
        println!("ok: {} (router, listen {listen})", args.config.display());
        return Ok(());
    }
    let stop = stop_flag()?;
    let session = zenoh::open(config)
        .wait()
        .map_err(|e| anyhow::anyhow!("cannot open the zenoh router: {e}"))
        .with_context(|| format!("router configuration {}", args.config.display()))?;
    tracing::info!(zid = %session.zid(), %listen, "router ready");
    while !stop.load(Ordering::SeqCst) {
        std::thread::sleep(Duration::from_millis(100));
    }
    tracing::info!("router stopping");
    if let Err(e) = session.close().wait() {
        tracing::warn!("closing the router session: {e}");
    }
    Ok(())
}
