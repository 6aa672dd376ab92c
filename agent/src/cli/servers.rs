//! Where a command's env servers are: the ones given, or a local env_server it starts
//! and stops.

use agent::env::connection::ConnectionConfig;
use agent::env::grpc::EnvClient;
use agent::env::pool::ServerPool;
use agent::env::server_process::{LocalServer, ServerOptions};
use anyhow::{Context, Result, bail};

use super::args::ConnectionArgs;

/// Connect to `server`, or start a local one when none is given.
pub(crate) async fn connect(
    server: Option<String>,
    connection: ConnectionArgs,
) -> Result<(EnvClient, Option<LocalServer>)> {
    let connection = connection.apply(ConnectionConfig::default());
    connection.validate()?;
    match server {
        Some(address) => {
            // Any address form, a dns: name or a file: list included: its first server.
            let servers = ServerPool::connect(&[address], &connection).await?;
            Ok((servers.first().client, None))
        }
        None => {
            let local = start_local(&connection).await?;
            Ok((EnvClient::connect(local.address()).await?, Some(local)))
        }
    }
}

/// A local server is plain loopback: TLS or token settings without a server are a
/// mistake (probably a forgotten --server), not something to drop silently.
fn refuse_credentials_for_local(connection: &ConnectionConfig) -> Result<()> {
    if !connection.is_empty() {
        bail!(
            "--tls-ca/--tls-client-cert/--token-file (env.connection): expected with --server or \
             env.servers, got no server (the local env_server a command starts is plain loopback \
             and takes no token): {connection:?}"
        );
    }
    Ok(())
}

/// The configured servers, or a local one started for this command.
pub(crate) async fn server_addresses(
    configured: &[String],
    connection: &ConnectionConfig,
) -> Result<(Vec<String>, Option<LocalServer>)> {
    if !configured.is_empty() {
        return Ok((configured.to_vec(), None));
    }
    let local = start_local(connection).await?;
    Ok((vec![local.address().to_string()], Some(local)))
}

/// Stop the local server a command started, if it started one.
pub(crate) async fn stop(local: Option<LocalServer>) -> Result<()> {
    if let Some(local) = local {
        local.stop().await?;
    }
    Ok(())
}

/// A local env_server for this command (plain loopback, so no credentials).
async fn start_local(connection: &ConnectionConfig) -> Result<LocalServer> {
    refuse_credentials_for_local(connection)?;
    let local = LocalServer::start(&ServerOptions::default())
        .await
        .context("starting a local env_server")?;
    tracing::info!(address = local.address(), "started local env_server");
    Ok(local)
}
