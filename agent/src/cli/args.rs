//! Flags more than one subcommand takes: what `train` and `sweep` override of a run
//! config, how to reach servers (TLS, token), how to render videos, and the `--server`
//! value's check.

use std::path::PathBuf;

use agent::core::learner_config::DeviceChoice;
use agent::env::connection::ConnectionConfig;
use agent::report::video::VideoOptions;
use clap::Args;

/// What `train` and `sweep` take in place of their config's fields (a sweep's base
/// config: every run's).
#[derive(Debug, clap::Args)]
pub(crate) struct RunArgs {
    /// Server address (repeatable): host:port, https://host:port, dns:NAME:PORT
    /// (every address of NAME), dns://NAMESERVER/NAME:PORT or file:PATH (one address
    /// per line, re-read when a server is lost); overrides the config's env.servers
    /// (default: the config's, or a local server).
    #[arg(long = "server", value_name = "ADDRESS", value_parser = server_address)]
    pub(crate) servers: Vec<String>,
    #[command(flatten)]
    pub(crate) connection: ConnectionArgs,
    /// Override run.total_env_steps (a sweep file's total_env_steps: every run's).
    #[arg(long)]
    pub(crate) total_env_steps: Option<u64>,
    /// Override any config field, `dotted.path=toml_value` (repeatable), e.g.
    /// `--set seed=3 --set learner.mpo.batch_size=64 --set learner.objectives.1.epsilon=0.0`.
    /// A sweep applies them to its base config after the sweep file's `set`, before the
    /// grid. With `train --resume` only the budget, periods, checkpoint_replay,
    /// eval_episodes, servers and device may change (an error names any other field).
    #[arg(long = "set", value_name = "PATH=VALUE")]
    pub(crate) overrides: Vec<String>,
    /// Override learner.device (a sweep's: every run's).
    #[arg(long, value_enum)]
    pub(crate) device: Option<DeviceChoice>,
}

/// How to reach servers that take TLS or a bearer token (env_server's --tls-cert,
/// --tls-client-ca, --auth-token-file); each flag replaces the config's
/// `env.connection` field of the same meaning.
#[derive(Debug, Clone, clap::Args)]
pub(crate) struct ConnectionArgs {
    /// PEM certificate of the CA that signed the servers' certificates; servers are
    /// then reached over TLS (https).
    #[arg(long, value_name = "PEM")]
    tls_ca: Option<PathBuf>,
    /// PEM client certificate, for servers that require mutual TLS (--tls-client-ca).
    #[arg(long, value_name = "PEM", requires = "tls_client_key")]
    tls_client_cert: Option<PathBuf>,
    /// PEM private key of --tls-client-cert.
    #[arg(long, value_name = "PEM", requires = "tls_client_cert")]
    tls_client_key: Option<PathBuf>,
    /// File holding the bearer token, one line (`token` or `name:token`).
    #[arg(long, value_name = "FILE")]
    token_file: Option<PathBuf>,
}

impl ConnectionArgs {
    /// `base` with every flag that was given in place of its field.
    pub(crate) fn apply(self, mut base: ConnectionConfig) -> ConnectionConfig {
        let pairs = [
            (self.tls_ca, &mut base.tls_ca_file),
            (self.tls_client_cert, &mut base.tls_client_cert_file),
            (self.tls_client_key, &mut base.tls_client_key_file),
            (self.token_file, &mut base.token_file),
        ];
        for (flag, field) in pairs {
            if flag.is_some() {
                *field = flag;
            }
        }
        base
    }
}

/// How videos are rendered (with `--video` or `--video-every`).
#[derive(Debug, Clone, Args)]
pub(crate) struct VideoArgs {
    /// Width of each instance's frame in pixels (0 = the server's default, 320).
    #[arg(long, default_value_t = 0)]
    video_width: u32,
    /// Height of each instance's frame in pixels (0 = the server's default, 240).
    #[arg(long, default_value_t = 0)]
    video_height: u32,
    /// Camera the env names ("" = the task's default view).
    #[arg(long, default_value = "")]
    video_camera: String,
    /// Frames per second (default: the task's real time, or 30 when it does not say).
    #[arg(long)]
    video_fps: Option<f64>,
}

impl VideoArgs {
    pub(crate) fn options(&self) -> VideoOptions {
        VideoOptions {
            width: self.video_width,
            height: self.video_height,
            camera: self.video_camera.clone(),
            fps: self.video_fps,
        }
    }
}

/// `--server`'s value, checked when the command line is read, so that a bad one is
/// reported against the flag (clap names it) rather than the config field it replaces.
pub(crate) fn server_address(text: &str) -> Result<String, String> {
    agent::env::discovery::ServerSource::parse(text)
        .map(|_| text.to_string())
        .map_err(|e| e.to_string())
}
