//! Transport configuration (serde, `deny_unknown_fields`; roles embed it in their TOML).

use std::path::{Path, PathBuf};
use std::time::Duration;

use proto::{RunId, SenderId};
use serde::{Deserialize, Serialize};

use crate::error::TransportError;

/// Where the data plane (transitions, weights, control, acks) travels.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(rename_all = "lowercase")]
pub enum DataPlane {
    /// zenoh for everything (any number of machines).
    #[default]
    Zenoh,
    /// iceoryx2 shared memory for the data plane (one machine); telemetry and liveliness stay
    /// on zenoh (loopback).
    Iceoryx2,
}

/// zenoh session mode.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(rename_all = "lowercase")]
pub enum ZenohMode {
    /// Peer: talks directly to the peers it listens for / connects to.
    #[default]
    Peer,
    /// Client of a router (`zenohd`) given in `connect`.
    Client,
}

/// zenoh session settings.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct ZenohConfig {
    /// Peer (default) or client.
    pub mode: ZenohMode,
    /// Endpoints to listen on, e.g. `tcp/127.0.0.1:7447`. Default: loopback, ephemeral port
    /// (`tcp/127.0.0.1:0`) in peer mode, nothing in client mode.
    pub listen: Vec<String>,
    /// Endpoints to connect to (the learner's listen endpoint, or the router).
    pub connect: Vec<String>,
    /// Multicast scouting (UDP 224.0.0.224:7446). Off by default: explicit endpoints only.
    pub multicast_scouting: bool,
    /// How long a blocked reliable publication waits for a full receiver before zenoh closes
    /// the link (zenoh `congestion_control/block/wait_before_close`), in ms.
    pub block_timeout_ms: u64,
    /// TLS for `tls/...` endpoints (`[transport.zenoh.tls]`).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub tls: Option<ZenohTls>,
    /// User/password authentication towards the router (`[transport.zenoh.auth]`).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub auth: Option<ZenohAuth>,
    /// Extra raw zenoh settings `(key path, JSON5 value)`, applied last, e.g.
    /// `("transport/link/tx/lease", "20000")`.
    pub overrides: Vec<(String, String)>,
}

/// TLS settings (zenoh `transport/link/tls/*`). Relative paths are resolved against the
/// directory of the config file that holds them, a relative `key` first against systemd's
/// credentials directory ([`ZenohConfig::resolve_paths`]).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ZenohTls {
    /// PEM certificate of the certificate authority that signed the router's (and, with
    /// mutual TLS, the other processes') certificates.
    pub root_ca: PathBuf,
    /// This process's own PEM certificate, for mutual TLS (with `key`); its common name is the
    /// subject the router's access control sees as `cert_common_names`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub cert: Option<PathBuf>,
    /// The PEM private key of `cert`: a secret, refused when group or others may read it.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub key: Option<PathBuf>,
    /// Check that the router's certificate names the host or address connected to (default
    /// true; turn off only for tests with certificates that do not name the host).
    #[serde(default = "yes")]
    pub verify_name: bool,
}

fn yes() -> bool {
    true
}

/// User/password authentication (zenoh `transport/auth/usrpwd`). The password lives in its
/// own file (first line; never in the TOML), readable only by the service's user: a file that
/// group or others may read is refused ([`ZenohConfig::problems`]).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ZenohAuth {
    /// User name; the router's access control grants rights by it (`learner`, `actor-<id>`,
    /// `evaluator`, `monitor` in `deploy/router.json5`).
    pub user: String,
    /// File whose first line is the password. A relative name is looked up first in systemd's
    /// credentials directory (`$CREDENTIALS_DIRECTORY`, from the unit's `LoadCredential=`),
    /// then beside the config file.
    pub password_file: PathBuf,
}

impl ZenohAuth {
    /// The password: the first line of `password_file`, without its line end.
    pub fn read_password(&self) -> Result<String, String> {
        let text = std::fs::read_to_string(&self.password_file).map_err(|e| {
            format!(
                "cannot read the password file {}: {e}",
                self.password_file.display()
            )
        })?;
        let line = text.lines().next().unwrap_or("").trim_end_matches('\r');
        if line.is_empty() {
            return Err(format!(
                "the password file {} is empty",
                self.password_file.display()
            ));
        }
        Ok(line.to_string())
    }
}

impl Default for ZenohConfig {
    fn default() -> Self {
        Self {
            mode: ZenohMode::Peer,
            listen: vec!["tcp/127.0.0.1:0".into()],
            connect: Vec::new(),
            multicast_scouting: false,
            block_timeout_ms: 10_000,
            tls: None,
            auth: None,
            overrides: Vec::new(),
        }
    }
}

impl ZenohConfig {
    /// A client of the router at `endpoint` (e.g. `tcp/10.0.0.5:7447`).
    pub fn client(endpoint: impl Into<String>) -> Self {
        Self {
            mode: ZenohMode::Client,
            listen: Vec::new(),
            connect: vec![endpoint.into()],
            ..Self::default()
        }
    }

    /// A peer listening on `listen` and connecting to `connect`.
    pub fn peer(listen: Vec<String>, connect: Vec<String>) -> Self {
        Self {
            listen,
            connect,
            ..Self::default()
        }
    }

    /// Makes the TLS and password file paths absolute, relative to `base` (the directory of
    /// the config file they were read from). The secrets (password file, TLS private key), when
    /// named relatively, are first looked up by file name in systemd's credentials directory
    /// (`$CREDENTIALS_DIRECTORY`, set for a unit with `LoadCredential=`): under systemd the
    /// service then reads the copy only it can read, by hand the file beside the config.
    pub fn resolve_paths(&mut self, base: &Path) {
        let credentials = std::env::var_os(CREDENTIALS_DIRECTORY).map(PathBuf::from);
        self.resolve_paths_with(base, credentials.as_deref());
    }

    /// [`Self::resolve_paths`] with the credentials directory given.
    fn resolve_paths_with(&mut self, base: &Path, credentials: Option<&Path>) {
        let fix = |p: &mut PathBuf| {
            if p.is_relative() {
                *p = base.join(&*p);
            }
        };
        let secret = |p: &mut PathBuf| {
            if p.is_relative() {
                let provided = credentials
                    .filter(|c| c.is_absolute())
                    .zip(p.file_name())
                    .map(|(c, name)| c.join(name))
                    .filter(|c| c.is_file());
                *p = provided.unwrap_or_else(|| base.join(&*p));
            }
        };
        if let Some(t) = &mut self.tls {
            fix(&mut t.root_ca);
            if let Some(c) = &mut t.cert {
                fix(c);
            }
            if let Some(k) = &mut t.key {
                secret(k);
            }
        }
        if let Some(a) = &mut self.auth {
            secret(&mut a.password_file);
        }
    }

    /// Every problem of the zenoh settings (files that cannot be read, TLS endpoints without
    /// a certificate authority, ...).
    pub fn problems(&self) -> Vec<String> {
        let mut problems = Vec::new();
        if self.mode == ZenohMode::Client && self.connect.is_empty() {
            problems.push("zenoh client mode needs a `connect` endpoint (the router)".into());
        }
        let uses_tls = self
            .listen
            .iter()
            .chain(&self.connect)
            .any(|e| e.starts_with("tls/"));
        let readable = |what: &str, p: &Path, problems: &mut Vec<String>| {
            if let Err(e) = std::fs::File::open(p) {
                problems.push(format!("{what}: cannot read {}: {e}", p.display()));
            }
        };
        match &self.tls {
            None if uses_tls => problems.push(
                "a tls/ endpoint needs [transport.zenoh.tls] root_ca (the CA that signed the router's certificate)".into(),
            ),
            None => {}
            Some(t) => {
                readable("zenoh.tls.root_ca", &t.root_ca, &mut problems);
                match (&t.cert, &t.key) {
                    (Some(c), Some(k)) => {
                        readable("zenoh.tls.cert", c, &mut problems);
                        readable("zenoh.tls.key", k, &mut problems);
                        problems.extend(exposed_secret("zenoh.tls.key", k));
                    }
                    (None, None) => {}
                    _ => problems.push(
                        "zenoh.tls.cert and zenoh.tls.key go together (mutual TLS)".into(),
                    ),
                }
                let listens_tls = self.listen.iter().any(|e| e.starts_with("tls/"));
                if listens_tls && t.cert.is_none() {
                    problems.push(
                        "listening on a tls/ endpoint needs zenoh.tls.cert and zenoh.tls.key".into(),
                    );
                }
            }
        }
        if let Some(a) = &self.auth {
            if a.user.is_empty() || a.user.contains(':') || a.user.chars().any(char::is_whitespace)
            {
                problems.push(format!(
                    "zenoh.auth.user {:?} must be non-empty, without ':' or spaces",
                    a.user
                ));
            }
            if let Err(e) = a.read_password() {
                problems.push(format!("zenoh.auth.password_file: {e}"));
            }
            problems.extend(exposed_secret("zenoh.auth.password_file", &a.password_file));
        }
        for (k, _) in &self.overrides {
            if k.starts_with("transport/auth") {
                problems.push(format!(
                    "zenoh.overrides must not set {k}: use [transport.zenoh.auth] (password in a file)"
                ));
            }
        }
        problems
    }

    /// The native zenoh config of these settings (`fsrl serve` opens its own session with it).
    pub fn to_zenoh(&self, max_message_bytes: usize) -> Result<zenoh::Config, TransportError> {
        fn set(c: &mut zenoh::Config, key: &str, value: String) -> Result<(), TransportError> {
            c.insert_json5(key, &value)
                .map_err(|e| TransportError::Config(format!("zenoh {key} = {value}: {e}")))
        }
        fn json<T: Serialize + ?Sized>(v: &T) -> Result<String, TransportError> {
            serde_json::to_string(v).map_err(|e| TransportError::Config(e.to_string()))
        }
        let mut c = zenoh::Config::default();
        let mode = match self.mode {
            ZenohMode::Peer => "\"peer\"",
            ZenohMode::Client => "\"client\"",
        };
        set(&mut c, "mode", mode.into())?;
        set(&mut c, "listen/endpoints", json(&self.listen)?)?;
        set(&mut c, "connect/endpoints", json(&self.connect)?)?;
        set(
            &mut c,
            "scouting/multicast/enabled",
            self.multicast_scouting.to_string(),
        )?;
        set(
            &mut c,
            "transport/link/tx/queue/congestion_control/block/wait_before_close",
            (self.block_timeout_ms.saturating_mul(1000)).to_string(),
        )?;
        // Reject oversized messages at defragmentation already (default would be 1 GiB).
        set(
            &mut c,
            "transport/link/rx/max_message_size",
            (max_message_bytes + 64 * 1024).to_string(),
        )?;
        if let Some(t) = &self.tls {
            let path = |p: &Path| json(&p.to_string_lossy());
            set(
                &mut c,
                "transport/link/tls/root_ca_certificate",
                path(&t.root_ca)?,
            )?;
            set(
                &mut c,
                "transport/link/tls/verify_name_on_connect",
                t.verify_name.to_string(),
            )?;
            if let (Some(cert), Some(key)) = (&t.cert, &t.key) {
                set(&mut c, "transport/link/tls/enable_mtls", "true".into())?;
                for (k, p) in [
                    ("connect_certificate", cert),
                    ("connect_private_key", key),
                    ("listen_certificate", cert),
                    ("listen_private_key", key),
                ] {
                    set(&mut c, &format!("transport/link/tls/{k}"), path(p)?)?;
                }
            }
        }
        if let Some(a) = &self.auth {
            let password = a.read_password().map_err(TransportError::Config)?;
            set(&mut c, "transport/auth/usrpwd/user", json(&a.user)?)?;
            // Not through `set`: its error message would show the value.
            c.insert_json5("transport/auth/usrpwd/password", &json(&password)?)
                .map_err(|_| TransportError::Config("zenoh rejected the password".into()))?;
        }
        for (k, v) in &self.overrides {
            set(&mut c, k, v.clone())?;
        }
        Ok(c)
    }
}

/// The environment variable systemd sets to a unit's credentials directory (`LoadCredential=`).
const CREDENTIALS_DIRECTORY: &str = "CREDENTIALS_DIRECTORY";

/// A problem if the secret file `path` may be read (or changed) by anyone but its owner
/// (`mode & 0o077 != 0`), naming the file, its mode and the fix. Nothing if it cannot be
/// examined: that is reported as unreadable already. The clients' password files and TLS keys
/// are checked with it ([`ZenohConfig::problems`]), and so are the router's (`fsrl router`).
pub fn exposed_secret(what: &str, path: &Path) -> Option<String> {
    #[cfg(unix)]
    {
        use std::os::unix::fs::PermissionsExt as _;
        let mode = std::fs::metadata(path).ok()?.permissions().mode() & 0o7777;
        if mode & 0o077 != 0 {
            return Some(format!(
                "{what}: {} is a secret but group or others may read it (mode {mode:04o}); \
                 make it readable by the service's user only: chmod 600 {}",
                path.display(),
                path.display()
            ));
        }
    }
    #[cfg(not(unix))]
    let _ = (what, path);
    None
}

/// iceoryx2 settings (used when `data_plane = "iceoryx2"`).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct IceoryxConfig {
    /// Most processes of a run on this machine (actors + learner + evaluator + tools): sizes
    /// the publisher, subscriber and node limits of every service.
    pub max_processes: usize,
    /// Most subscribers of a many-to-one topic (the learner plus tools).
    pub max_collectors: usize,
    /// Samples a subscriber of a reliable topic can queue before publishers block.
    pub subscriber_buffer: usize,
    /// Initial sample size of reliable topics, in bytes (grows by powers of two).
    pub initial_sample_bytes: usize,
    /// Fixed sample size of latest-value topics (weights, control), in bytes: must hold the
    /// largest encoded weights (SARL: ~0.39 MB).
    pub latest_sample_bytes: usize,
    /// File-name prefix of every iceoryx2 resource (shared memory, files). Default:
    /// `fsrl_<run>_`, so runs never see each other.
    pub prefix: Option<String>,
    /// Directory of iceoryx2's files. Default: iceoryx2's (`/tmp/iceoryx2/`).
    pub root_path: Option<String>,
}

impl Default for IceoryxConfig {
    fn default() -> Self {
        Self {
            max_processes: 32,
            max_collectors: 4,
            subscriber_buffer: 64,
            initial_sample_bytes: 32 * 1024,
            latest_sample_bytes: 1024 * 1024,
            prefix: None,
            root_path: None,
        }
    }
}

/// Everything [`crate::Transport::open`] needs.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TransportConfig {
    /// The run (first key chunk after `fsrl/`).
    pub run: RunId,
    /// Who this process is.
    pub sender: SenderId,
    /// Data plane.
    #[serde(default)]
    pub data_plane: DataPlane,
    /// zenoh session (always opened: telemetry and liveliness).
    #[serde(default)]
    pub zenoh: ZenohConfig,
    /// iceoryx2 settings.
    #[serde(default)]
    pub iceoryx2: IceoryxConfig,
    /// Largest message sent or accepted, in bytes.
    #[serde(default = "default_max_message_bytes")]
    pub max_message_bytes: usize,
    /// How long a reliable publication may block on a full receiver before failing, in ms.
    #[serde(default = "default_publish_timeout_ms")]
    pub publish_timeout_ms: u64,
    /// Capacity of a zenoh subscriber's receive queue (messages); when full, zenoh pushes back
    /// on reliable publishers.
    #[serde(default = "default_subscriber_queue")]
    pub subscriber_queue: usize,
}

fn default_max_message_bytes() -> usize {
    proto::DEFAULT_MAX_MESSAGE_BYTES
}
fn default_publish_timeout_ms() -> u64 {
    10_000
}
fn default_subscriber_queue() -> usize {
    1024
}

impl TransportConfig {
    /// Defaults: zenoh data plane, peer on loopback with an ephemeral port, no multicast.
    pub fn new(run: RunId, sender: SenderId) -> Self {
        Self {
            run,
            sender,
            data_plane: DataPlane::Zenoh,
            zenoh: ZenohConfig::default(),
            iceoryx2: IceoryxConfig::default(),
            max_message_bytes: default_max_message_bytes(),
            publish_timeout_ms: default_publish_timeout_ms(),
            subscriber_queue: default_subscriber_queue(),
        }
    }

    /// `publish_timeout_ms` as a duration.
    pub fn publish_timeout(&self) -> Duration {
        Duration::from_millis(self.publish_timeout_ms)
    }

    /// Checks the configuration, reporting every problem at once.
    pub fn validate(&self) -> Result<(), TransportError> {
        let mut problems = Vec::new();
        if self.max_message_bytes < 1024 {
            problems.push("max_message_bytes must be at least 1024".to_string());
        }
        if self.subscriber_queue == 0 {
            problems.push("subscriber_queue must be positive".into());
        }
        problems.extend(self.zenoh.problems());
        let i = &self.iceoryx2;
        if i.max_processes < 2 {
            problems.push("iceoryx2.max_processes must be at least 2".into());
        }
        if i.max_collectors == 0 || i.subscriber_buffer == 0 {
            problems.push("iceoryx2.max_collectors and subscriber_buffer must be positive".into());
        }
        if i.initial_sample_bytes < 64 || i.latest_sample_bytes < 64 {
            problems.push("iceoryx2 sample sizes must be at least 64 bytes".into());
        }
        if i.latest_sample_bytes > self.max_message_bytes {
            problems.push("iceoryx2.latest_sample_bytes exceeds max_message_bytes".into());
        }
        if let Some(p) = &i.prefix {
            if p.is_empty()
                || !p
                    .chars()
                    .all(|c| c.is_ascii_alphanumeric() || matches!(c, '_' | '-' | '.'))
            {
                problems.push(format!("iceoryx2.prefix {p:?} must be [A-Za-z0-9_.-]+"));
            }
        }
        if problems.is_empty() {
            Ok(())
        } else {
            Err(TransportError::Config(problems.join("; ")))
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A scratch directory removed on drop.
    struct Scratch(PathBuf);
    impl Scratch {
        fn new(tag: &str) -> Self {
            let p = std::env::temp_dir().join(format!("fsrl-zcfg-{tag}-{}", std::process::id()));
            std::fs::create_dir_all(&p).unwrap();
            Self(p)
        }
    }
    impl Drop for Scratch {
        fn drop(&mut self) {
            let _ = std::fs::remove_dir_all(&self.0);
        }
    }

    /// Writes `text` to `path` with permission bits `mode`.
    fn write_mode(path: &Path, text: &str, mode: u32) {
        std::fs::write(path, text).unwrap();
        #[cfg(unix)]
        {
            use std::os::unix::fs::PermissionsExt as _;
            std::fs::set_permissions(path, std::fs::Permissions::from_mode(mode)).unwrap();
        }
        #[cfg(not(unix))]
        let _ = mode;
    }

    fn secured(dir: &Path) -> ZenohConfig {
        let mut z = ZenohConfig::client("tls/10.0.0.1:7447");
        z.tls = Some(ZenohTls {
            root_ca: "certs/ca.crt".into(),
            cert: None,
            key: None,
            verify_name: true,
        });
        z.auth = Some(ZenohAuth {
            user: "actor".into(),
            password_file: "actor.password".into(),
        });
        z.resolve_paths(dir);
        z
    }

    #[test]
    fn relative_paths_resolve_against_the_config_directory() {
        let z = secured(Path::new("/etc/fsrl"));
        let t = z.tls.as_ref().unwrap();
        assert_eq!(t.root_ca, Path::new("/etc/fsrl/certs/ca.crt"));
        let a = z.auth.as_ref().unwrap();
        assert_eq!(a.password_file, Path::new("/etc/fsrl/actor.password"));
        let mut abs = z.clone();
        abs.resolve_paths(Path::new("/elsewhere"));
        assert_eq!(abs, z, "absolute paths stay as they are");
    }

    #[test]
    fn tls_and_credentials_become_zenoh_settings() {
        let s = Scratch::new("ok");
        std::fs::create_dir_all(s.0.join("certs")).unwrap();
        std::fs::write(s.0.join("certs/ca.crt"), "pem").unwrap();
        write_mode(&s.0.join("actor.password"), "s3cret\n", 0o600);
        let z = secured(&s.0);
        assert!(z.problems().is_empty(), "{:?}", z.problems());
        let c = z.to_zenoh(1 << 20).unwrap();
        let get = |k: &str| c.get_json(k).unwrap();
        assert_eq!(get("mode"), "\"client\"");
        assert_eq!(
            get("transport/link/tls/root_ca_certificate"),
            format!("\"{}\"", s.0.join("certs/ca.crt").display())
        );
        assert_eq!(get("transport/auth/usrpwd/user"), "\"actor\"");
        assert_eq!(get("transport/auth/usrpwd/password"), "\"s3cret\"");
        assert_ne!(
            get("transport/link/tls/enable_mtls"),
            "true",
            "no client certificate"
        );
        // Mutual TLS: the client certificate and key for both sides of a link.
        let mut m = z.clone();
        write_mode(&s.0.join("certs/me.key"), "pem", 0o600);
        let t = m.tls.as_mut().unwrap();
        t.cert = Some(s.0.join("certs/ca.crt"));
        t.key = Some(s.0.join("certs/me.key"));
        assert!(m.problems().is_empty(), "{:?}", m.problems());
        let c = m.to_zenoh(1 << 20).unwrap();
        assert_eq!(
            c.get_json("transport/link/tls/enable_mtls").unwrap(),
            "true"
        );
        assert!(c
            .get_json("transport/link/tls/connect_certificate")
            .unwrap()
            .contains("ca.crt"));
        // The serialised config names the file, never the password.
        let text = serde_json::to_string(&z).unwrap();
        assert!(text.contains("actor.password") && !text.contains("s3cret"));
    }

    #[test]
    fn unreadable_files_and_half_settings_are_problems_naming_the_paths() {
        let s = Scratch::new("bad");
        let mut z = secured(&s.0);
        z.tls.as_mut().unwrap().cert = Some(s.0.join("me.crt"));
        let p = z.problems().join("\n");
        assert!(
            p.contains(&*s.0.join("certs/ca.crt").to_string_lossy()),
            "{p}"
        );
        assert!(
            p.contains(&*s.0.join("actor.password").to_string_lossy()),
            "{p}"
        );
        assert!(p.contains("go together"), "{p}");
        assert!(matches!(
            z.to_zenoh(1 << 20),
            Err(TransportError::Config(_))
        ));

        let mut plain = ZenohConfig::client("tls/10.0.0.1:7447");
        assert!(
            plain.problems()[0].contains("root_ca"),
            "{:?}",
            plain.problems()
        );
        plain
            .overrides
            .push(("transport/auth/usrpwd/password".into(), "\"x\"".into()));
        assert!(plain
            .problems()
            .iter()
            .any(|p| p.contains("password in a file")));
    }

    #[cfg(unix)]
    #[test]
    fn secrets_readable_by_group_or_others_are_refused_naming_file_mode_and_fix() {
        let s = Scratch::new("mode");
        std::fs::create_dir_all(s.0.join("certs")).unwrap();
        std::fs::write(s.0.join("certs/ca.crt"), "pem").unwrap();
        let password = s.0.join("actor.password");
        let key = s.0.join("certs/me.key");
        write_mode(&password, "s3cret\n", 0o644);
        write_mode(&key, "pem", 0o640);
        let mut z = secured(&s.0);
        let t = z.tls.as_mut().unwrap();
        t.cert = Some(s.0.join("certs/ca.crt"));
        t.key = Some(key.clone());
        let p = z.problems();
        assert_eq!(p.len(), 2, "{p:?}");
        for (problem, file, mode) in [(&p[1], &password, "0644"), (&p[0], &key, "0640")] {
            let file = file.display().to_string();
            assert!(
                problem.contains(&file)
                    && problem.contains(&format!("mode {mode}"))
                    && problem.contains(&format!("chmod 600 {file}")),
                "{problem}"
            );
        }
        // Reported with the other problems of the config when the transport opens.
        let mut cfg = TransportConfig::new(
            RunId::new("r").unwrap(),
            SenderId::new(proto::Role::Actor, 0),
        );
        cfg.zenoh = z.clone();
        cfg.subscriber_queue = 0;
        let Err(TransportError::Config(all)) = cfg.validate() else {
            panic!("a readable secret must be refused");
        };
        assert!(
            all.contains("subscriber_queue") && all.contains("mode 0644"),
            "{all}"
        );
        // Owner-only files (0600, or 0400 as systemd's credentials) are accepted.
        write_mode(&password, "s3cret\n", 0o600);
        write_mode(&key, "pem", 0o400);
        assert!(z.problems().is_empty(), "{:?}", z.problems());
    }

    #[test]
    fn secrets_named_relatively_come_from_the_credentials_directory_first() {
        let s = Scratch::new("creds");
        let creds = s.0.join("credentials");
        std::fs::create_dir_all(&creds).unwrap();
        write_mode(&creds.join("actor.password"), "from-systemd\n", 0o400);
        let mut z = ZenohConfig::client("tls/10.0.0.1:7447");
        z.tls = Some(ZenohTls {
            root_ca: "certs/ca.crt".into(),
            cert: Some("certs/actor.crt".into()),
            key: Some("certs/actor.key".into()),
            verify_name: true,
        });
        z.auth = Some(ZenohAuth {
            user: "actor-0".into(),
            password_file: "actor.password".into(),
        });
        let mut under_systemd = z.clone();
        under_systemd.resolve_paths_with(Path::new("/etc/fsrl"), Some(&creds));
        let a = under_systemd.auth.as_ref().unwrap();
        assert_eq!(a.password_file, creds.join("actor.password"));
        assert_eq!(a.read_password().unwrap(), "from-systemd");
        // Not provided as a credential, or not a secret: beside the config file.
        let t = under_systemd.tls.as_ref().unwrap();
        assert_eq!(
            t.key.as_deref(),
            Some(Path::new("/etc/fsrl/certs/actor.key"))
        );
        assert_eq!(t.root_ca, Path::new("/etc/fsrl/certs/ca.crt"));
        let mut by_hand = z.clone();
        by_hand.resolve_paths_with(Path::new("/etc/fsrl"), None);
        let a = by_hand.auth.as_ref().unwrap();
        assert_eq!(a.password_file, Path::new("/etc/fsrl/actor.password"));
    }
}
