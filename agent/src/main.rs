//! `agent`: command-line entry point (the only place that uses `anyhow`).
#![allow(clippy::print_stdout, reason = "a CLI prints its results")]

use std::time::Instant;

use agent::env::grpc::{EnvClient, RemoteEnv};
use agent::env::server_process::{LocalServer, ServerOptions};
use agent::env::{Env, MakeOptions, random_action};
use anyhow::{Context, Result};
use clap::{Parser, Subcommand};
use indicatif::{ProgressBar, ProgressStyle};
use rand::SeedableRng;

/// Multi-objective MPO agents for env_server environments.
#[derive(Debug, Parser)]
#[command(version, about)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Debug, Subcommand)]
enum Command {
    /// List the envs a server offers, with their objectives.
    Envs {
        /// Server address host:port. Omitted: start a local server for the listing.
        #[arg(long)]
        server: Option<String>,
    },
    /// Step envs with uniformly random actions and print per-episode vector returns.
    Demo {
        /// Server address host:port. Omitted: start a local server on 127.0.0.1.
        #[arg(long)]
        server: Option<String>,
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
    },
}

#[tokio::main]
async fn main() -> Result<()> {
    tracing_subscriber::fmt()
        .with_env_filter(tracing_subscriber::EnvFilter::try_from_default_env().unwrap_or_else(|_| "info".into()))
        .with_writer(std::io::stderr)
        .init();
    match Cli::parse().command {
        Command::Envs { server } => {
            let (client, local) = connect(server).await?;
            print_envs(&client).await?;
            if let Some(local) = local {
                local.stop().await?;
            }
        }
        Command::Demo { server, envs, num_envs, episodes, seed } => {
            let (client, local) = connect(server).await?;
            for env_id in &envs {
                demo(&client, env_id, num_envs, episodes, seed).await?;
            }
            if let Some(local) = local {
                local.stop().await?;
            }
        }
    }
    Ok(())
}

/// Connect to `server`, or start a local one when none is given.
async fn connect(server: Option<String>) -> Result<(EnvClient, Option<LocalServer>)> {
    match server {
        Some(address) => Ok((EnvClient::connect(&address).await?, None)),
        None => {
            let local = LocalServer::start(&ServerOptions::default()).await.context("starting a local env_server")?;
            tracing::info!(address = local.address(), "started local env_server");
            Ok((EnvClient::connect(local.address()).await?, Some(local)))
        }
    }
}

async fn print_envs(client: &EnvClient) -> Result<()> {
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
            println!("    {:<14} [{}, {}]  {}", o.name, o.min, o.max, o.description);
        }
    }
    Ok(())
}

async fn demo(client: &EnvClient, env_id: &str, num_envs: usize, episodes: usize, seed: u64) -> Result<()> {
    let options = MakeOptions { seed: Some(seed), ..MakeOptions::new(env_id, num_envs) };
    let mut env: RemoteEnv = client.make(&options).await.with_context(|| format!("making {env_id}"))?;
    let spec = env.spec().clone();
    let names = spec.objective_names().join(", ");
    println!("\n{env_id}: B={num_envs}, objectives [{names}], discount {}", spec.discount);
    env.reset(&[], &[]).await?;
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
    let bar = ProgressBar::new(episodes as u64).with_style(
        ProgressStyle::with_template("{spinner} {msg:>14} episodes {pos}/{len} [{elapsed}] {per_sec}")
            .expect("valid template"),
    );
    bar.set_message(env_id.to_string());
    let started = Instant::now();
    let (mut finished, mut steps) = (Vec::new(), 0u64);
    while finished.len() < episodes {
        let result = env.step(&random_action(&spec.action_space, num_envs, &mut rng)).await?;
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
    println!("  {steps} env steps in {elapsed:.2} s ({:.0} steps/s)", steps as f64 / elapsed);
    env.close().await?;
    Ok(())
}

fn format_vector(values: &[f64]) -> String {
    let parts: Vec<String> = values.iter().map(|v| format!("{v:.2}")).collect();
    format!("[{}]", parts.join(", "))
}
