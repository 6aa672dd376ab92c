//! `agent envs` and `agent demo`: list a server's envs, and step envs with random
//! actions to show the wire working.

use std::time::Instant;

use agent::core::spec::ClosedForm;
use agent::env::grpc::{EnvClient, RemoteEnv};
use agent::env::{Env, MakeOptions, random_action};
use agent::report::metrics::format_vector;
use anyhow::{Context, Result};
use indicatif::{ProgressBar, ProgressStyle};
use rand::SeedableRng;

use super::args::{ConnectionArgs, server_address};
use super::servers::{connect, stop};

/// `agent envs`'s flags.
#[derive(Debug, clap::Args)]
pub(crate) struct EnvsArgs {
    /// Server address host:port, https://host:port, dns:NAME:PORT or
    /// file:PATH (its first server). Omitted: start a local server
    /// for the listing.
    #[arg(long, value_name = "ADDRESS", value_parser = server_address)]
    server: Option<String>,
    #[command(flatten)]
    connection: ConnectionArgs,
}

impl EnvsArgs {
    pub(crate) async fn run(self) -> Result<()> {
        let (client, local) = connect(self.server, self.connection).await?;
        list_envs(&client).await?;
        stop(local).await
    }
}

/// `agent demo`'s flags.
#[derive(Debug, clap::Args)]
pub(crate) struct DemoArgs {
    /// Server address host:port, https://host:port, dns:NAME:PORT or
    /// file:PATH (its first server). Omitted: start a local server
    /// on 127.0.0.1.
    #[arg(long, value_name = "ADDRESS", value_parser = server_address)]
    server: Option<String>,
    #[command(flatten)]
    connection: ConnectionArgs,
    /// Env ids to run, in order.
    #[arg(long = "env", default_values = ["dst", "humanoid-run"])]
    envs: Vec<String>,
    /// Instances per session (B).
    #[arg(long, default_value_t = 4)]
    num_envs: usize,
    /// Episodes to finish per env.
    #[arg(long, default_value_t = 4)]
    episodes: usize,
    /// Seed for the envs and the random actions.
    #[arg(long, default_value_t = 0)]
    seed: u64,
}

impl DemoArgs {
    pub(crate) async fn run(self) -> Result<()> {
        let (client, local) = connect(self.server, self.connection).await?;
        for env_id in &self.envs {
            run_env(&client, env_id, self.num_envs, self.episodes, self.seed).await?;
        }
        stop(local).await
    }
}

/// Print the server's version, capabilities and env ids with their objectives.
async fn list_envs(client: &EnvClient) -> Result<()> {
    let version = client.version().await?;
    println!(
        "env_server {} (protocol {}) at {}",
        version.server_version,
        version.protocol_version,
        client.address()
    );
    for env in client.list_envs().await? {
        println!("\n{:<16} {}", env.env_id, env.description);
        for o in env.objectives {
            // What `source` other than "learned" the agent accepts for it.
            let closed = match o.closed_form {
                ClosedForm::ActionNorm => "  (closed form: source = \"action_norm\" allowed)",
                _ => "",
            };
            println!(
                "    {:<14} [{}, {}]  {}{closed}",
                o.name, o.min, o.max, o.description
            );
        }
    }
    Ok(())
}

/// Step `num_envs` instances of `env_id` with random actions for `episodes` episodes.
async fn run_env(
    client: &EnvClient,
    env_id: &str,
    num_envs: usize,
    episodes: usize,
    seed: u64,
) -> Result<()> {
    let options = MakeOptions {
        seed: Some(seed),
        ..MakeOptions::new(env_id, num_envs)
    };
    let mut env: RemoteEnv = client
        .make(&options)
        .await
        .with_context(|| format!("making {env_id}"))?;
    let spec = env.spec().clone();
    let names = spec.objective_names().join(", ");
    println!(
        "\n{env_id}: B={num_envs}, objectives [{names}], discount {}",
        spec.discount
    );
    env.reset(&[], &[]).await?;
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
    let bar = ProgressBar::new(episodes as u64).with_style(
        ProgressStyle::with_template(
            "{spinner} {msg:>14} episodes {pos}/{len} [{elapsed}] {per_sec}",
        )
        .expect("valid template"),
    );
    bar.set_message(env_id.to_string());
    let started = Instant::now();
    let (mut finished, mut steps) = (Vec::new(), 0u64);
    while finished.len() < episodes {
        let result = env
            .step(&random_action(&spec.action_space, num_envs, &mut rng))
            .await?;
        steps += num_envs as u64;
        for episode in result.episodes {
            bar.inc(1);
            finished.push(episode);
        }
    }
    bar.finish_and_clear();
    let elapsed = started.elapsed().as_secs_f64();
    println!("  episode  env  length  return [{names}]  discounted return");
    for (i, e) in finished.iter().take(episodes).enumerate() {
        println!(
            "  {i:>7}  {:>3}  {:>6}  {:<28}  {}",
            e.env_index,
            e.length,
            format_vector(&e.episode_return),
            format_vector(&e.discounted_return)
        );
    }
    println!(
        "  {steps} env steps in {elapsed:.2} s ({:.0} steps/s)",
        steps as f64 / elapsed
    );
    env.close().await?;
    Ok(())
}
