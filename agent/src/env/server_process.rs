//! Start and stop a local `env_server` process (`python -m env_server`).
//!
//! Used by the CLI's demo, the end-to-end tests and the benchmarks. The server
//! binds 127.0.0.1 (or another loopback address) on an OS-chosen port and announces it with one stdout line,
//! `LISTENING <host>:<port>`, which is read here.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::process::Stdio;
use std::time::Duration;

use tokio::io::{AsyncBufReadExt, BufReader};
use tokio::process::{Child, Command};

use crate::env::error::EnvError;

/// How to start the server.
#[derive(Debug, Clone, PartialEq)]
pub struct ServerOptions {
    /// Python interpreter that has `env_server` installed.
    pub python: PathBuf,
    /// Address to bind: 127.0.0.1, or another loopback address (Linux routes all of
    /// 127/8 to `lo`) to run several servers on one port, as several hosts would.
    pub host: String,
    /// Port to bind; 0 lets the OS choose.
    pub port: u16,
    /// Extra command-line flags, e.g. `["--max-sessions", "4"]`.
    pub extra_args: Vec<String>,
    /// Environment variables set for the server on top of this process's, e.g.
    /// `PYTHONPATH` naming a folder of plug-in packages.
    pub environment: BTreeMap<String, String>,
    /// How long to wait for the LISTENING line.
    pub startup_timeout: Duration,
}

impl Default for ServerOptions {
    fn default() -> Self {
        Self {
            python: default_python(),
            host: "127.0.0.1".into(),
            port: 0,
            extra_args: Vec::new(),
            environment: BTreeMap::new(),
            startup_timeout: Duration::from_secs(120),
        }
    }
}

/// The interpreter to run the server with: `$ENV_SERVER_PYTHON`, else the
/// workspace's `.venv` (made by `scripts/setup.sh`), else `python3` on PATH.
pub fn default_python() -> PathBuf {
    if let Some(p) = std::env::var_os("ENV_SERVER_PYTHON") {
        return PathBuf::from(p);
    }
    let venv = Path::new(env!("CARGO_MANIFEST_DIR")).join("../.venv/bin/python");
    if venv.exists() {
        venv
    } else {
        PathBuf::from("python3")
    }
}

/// A running `env_server` child process; killed when dropped.
#[derive(Debug)]
pub struct LocalServer {
    child: Child,
    address: String,
}

impl LocalServer {
    /// Start a server and wait until it listens.
    pub async fn start(options: &ServerOptions) -> Result<Self, EnvError> {
        let mut command = Command::new(&options.python);
        command
            .args([
                "-m",
                "env_server",
                "--host",
                &options.host,
                "--port",
                &options.port.to_string(),
            ])
            .args(&options.extra_args)
            .envs(&options.environment)
            // A spawned server is a helper of this process: only its warnings and errors
            // reach the terminal (pass --log-level in extra_args to see more).
            .args(if options.extra_args.iter().any(|a| a == "--log-level") {
                &[][..]
            } else {
                &["--log-level", "WARNING"][..]
            })
            .stdin(Stdio::null())
            .stdout(Stdio::piped())
            .stderr(Stdio::inherit())
            .kill_on_drop(true);
        let mut child = command.spawn().map_err(|e| {
            EnvError::Process(format!(
                "cannot run {} -m env_server: {e} (run scripts/setup.sh, or set ENV_SERVER_PYTHON)",
                options.python.display()
            ))
        })?;
        let stdout = child.stdout.take().expect("stdout is piped");
        let mut lines = BufReader::new(stdout).lines();
        let listening = tokio::time::timeout(options.startup_timeout, async {
            while let Some(line) = lines
                .next_line()
                .await
                .map_err(|e| EnvError::Process(e.to_string()))?
            {
                if let Some(address) = line.strip_prefix("LISTENING ") {
                    return Ok(address.trim().to_string());
                }
            }
            Err(EnvError::Process(
                "exited before printing its LISTENING line (see its stderr above)".into(),
            ))
        })
        .await
        .map_err(|_| {
            EnvError::Process(format!(
                "no LISTENING line within {:?}",
                options.startup_timeout
            ))
        })??;
        // Keep draining stdout so the server never blocks on a full pipe.
        tokio::spawn(async move { while let Ok(Some(_)) = lines.next_line().await {} });
        Ok(Self {
            child,
            address: listening,
        })
    }

    /// `host:port` the server listens on.
    pub fn address(&self) -> &str {
        &self.address
    }

    /// The server's process id (None once it has been waited for).
    pub fn pid(&self) -> Option<u32> {
        self.child.id()
    }

    /// Port the server listens on.
    pub fn port(&self) -> u16 {
        self.address
            .rsplit(':')
            .next()
            .and_then(|p| p.parse().ok())
            .unwrap_or(0)
    }

    /// Ask the server to shut down (SIGTERM) and wait up to 10 s, then kill it.
    pub async fn stop(mut self) -> Result<(), EnvError> {
        if let Some(pid) = self.child.id() {
            // `kill` failing only means the server already exited.
            let _ = std::process::Command::new("kill")
                .args(["-TERM", &pid.to_string()])
                .status();
        }
        match tokio::time::timeout(Duration::from_secs(10), self.child.wait()).await {
            Ok(_) => Ok(()),
            Err(_) => self
                .child
                .kill()
                .await
                .map_err(|e| EnvError::Process(e.to_string())),
        }
    }

    /// Kill the server at once (SIGKILL), as a crash would.
    pub async fn kill(mut self) -> Result<(), EnvError> {
        self.child
            .kill()
            .await
            .map_err(|e| EnvError::Process(e.to_string()))
    }
}
