//! `agent eval` and `agent act`: a checkpoint's deterministic policy, evaluated through a
//! server, or applied to observations from a file.

use std::collections::BTreeMap;
use std::path::PathBuf;

use agent::core::algo::preferences::parse_setting;
use agent::env::connection::ConnectionConfig;
use agent::runtime::eval::evaluate_checkpoint_at;
use anyhow::{Context, Result};

use super::args::{ConnectionArgs, VideoArgs, server_address};
use super::servers::{server_addresses, stop};

/// `agent eval`'s flags.
#[derive(Debug, clap::Args)]
pub(crate) struct EvalArgs {
    /// A run directory (its latest checkpoint) or one checkpoints/step_<n> directory.
    #[arg(long)]
    checkpoint: PathBuf,
    /// Episodes to run.
    #[arg(long, default_value_t = 10)]
    episodes: usize,
    /// Server address (repeatable): host:port, https://host:port, dns:NAME:PORT,
    /// dns://NAMESERVER/NAME:PORT or file:PATH (the first address found is used);
    /// default: a local server.
    #[arg(long = "server", value_name = "ADDRESS", value_parser = server_address)]
    servers: Vec<String>,
    /// How to reach --server (the run's own env.connection is not used).
    #[command(flatten)]
    connection: ConnectionArgs,
    /// Write a video of the evaluation here (e.g. out.mp4; .webm and .gif work too):
    /// the instances tiled, each objective's running return under its frame.
    #[arg(long, value_name = "PATH")]
    video: Option<PathBuf>,
    #[command(flatten)]
    video_args: VideoArgs,
    /// An ε-conditioned policy's preference, e.g. `task=0.1,action_norm=0.02`:
    /// conditioned objectives only, any ε > 0 (on its training grid or not);
    /// default: the grid's middle point.
    #[arg(long, value_name = "NAME=EPS,...", value_parser = parse_setting)]
    epsilon: Option<BTreeMap<String, f64>>,
    /// Also write the report as JSON here: each episode's returns (undiscounted and
    /// discounted), env instance and length, the means, γ and the objectives' names,
    /// for scripts (`scripts/bench_hold.sh` reads it) rather than the printout.
    #[arg(long, value_name = "PATH")]
    json: Option<PathBuf>,
}

impl EvalArgs {
    pub(crate) async fn run(self) -> Result<()> {
        let connection = self.connection.apply(ConnectionConfig::default());
        connection.validate()?;
        let (addresses, local) = server_addresses(&self.servers, &connection).await?;
        let options = self.video_args.options();
        let video = self.video.as_deref().map(|path| (path, &options));
        let report = evaluate_checkpoint_at(
            &self.checkpoint,
            self.epsilon.as_ref(),
            &addresses,
            &connection,
            self.episodes,
            video,
        )
        .await;
        stop(local).await?;
        let report = report?;
        super::report::eval(&report);
        if let Some(path) = &self.json {
            let text = serde_json::to_string_pretty(&report)?;
            std::fs::write(path, text + "\n")
                .with_context(|| format!("writing the evaluation report to {}", path.display()))?;
        }
        Ok(())
    }
}

/// `agent act`'s flags.
#[derive(Debug, clap::Args)]
pub(crate) struct ActArgs {
    /// A run directory (its latest checkpoint) or one checkpoints/step_<n> directory.
    #[arg(long)]
    checkpoint: PathBuf,
    /// The observations, a .npy or .json file.
    #[arg(long, value_name = "FILE")]
    observations: PathBuf,
    /// Write the actions here (.npy or .json); default: print them as JSON.
    #[arg(long, value_name = "FILE")]
    out: Option<PathBuf>,
    /// An ε-conditioned policy's preference, as for `eval --epsilon`; the
    /// observations are then the env's, without the preference features.
    #[arg(long, value_name = "NAME=EPS,...", value_parser = parse_setting)]
    epsilon: Option<BTreeMap<String, f64>>,
}

impl ActArgs {
    pub(crate) fn run(self) -> Result<()> {
        let printed = agent::runtime::act::act_on_file(
            &self.checkpoint,
            &self.observations,
            self.out.as_deref(),
            self.epsilon.as_ref(),
        )?;
        if let Some(json) = printed {
            println!("{json}");
        }
        Ok(())
    }
}
