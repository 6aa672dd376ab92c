//! A fault-injection TCP proxy for the end-to-end tests: it sits between the agent and a
//! real env_server on 127.0.0.1, forwards bytes both ways, and on command delays,
//! drops, resets, blackholes, throttles, trickles or slow-closes them (the faults of
//! Toxiproxy, in process: no extra binary to install).
//!
//! A fault holds from [`FaultProxy::set`] until the next `set` (or [`FaultProxy::clear`],
//! which returns to the baseline: no fault, or [`FaultProxy::set_baseline`]'s) and
//! applies to open connections and new ones alike. Every fault set is kept with its
//! time ([`FaultProxy::history`]), and every chunk forwarded with its time and
//! direction ([`FaultProxy::traffic`]), so a test can say when the agent stopped and
//! started talking to a server.

use std::net::SocketAddr;
use std::pin::pin;
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::net::tcp::{OwnedReadHalf, OwnedWriteHalf};
use tokio::net::{TcpListener, TcpStream};
use tokio::sync::watch;
use tokio::task::JoinHandle;

/// What the proxy does to the bytes it carries.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Fault {
    /// Forward every chunk as it arrives.
    None,
    /// Hold every chunk this long before forwarding it (both ways): a slow link, or a
    /// server that answers slowly.
    Delay(Duration),
    /// Read and discard everything (both ways); connections stay open. After the fault
    /// the HTTP/2 stream on them is corrupt (bytes went missing mid-frame).
    Drop,
    /// Reset every open connection (RST to both ends) and every new one at once.
    Reset,
    /// Read nothing and forward nothing, keeping what was sent (a partition: the
    /// senders' kernels hold the bytes, which arrive once the fault is cleared). New
    /// connections are accepted (the kernel completes the handshake) and held too.
    Blackhole,
    /// At most this many bytes per second each way.
    Throttle(u64),
    /// When one end closes its side, wait this long before closing the other end's.
    SlowClose(Duration),
    /// Forward one byte at a time, this long apart (a message trickled byte by byte).
    Trickle(Duration),
}

/// Which way a chunk went.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Direction {
    /// Agent to server.
    Up,
    /// Server to agent.
    Down,
}

/// One chunk the proxy forwarded.
#[derive(Debug, Clone, Copy)]
pub struct Chunk {
    /// When it was written to its destination.
    pub at: Instant,
    /// Which way.
    pub direction: Direction,
    /// Its size.
    pub bytes: usize,
}

#[derive(Debug, Default)]
struct Log {
    faults: Vec<(Instant, Fault)>,
    traffic: Vec<Chunk>,
    connections: usize,
    /// When an end closed its side: `Up` the agent's, `Down` the server's.
    closes: Vec<(Instant, Direction)>,
    /// What `clear` returns to.
    baseline: Option<Fault>,
}

/// A running proxy; it stops (and resets what it carries) when dropped.
#[derive(Debug)]
pub struct FaultProxy {
    address: SocketAddr,
    fault: watch::Sender<Fault>,
    log: Arc<Mutex<Log>>,
    accept: JoinHandle<()>,
}

impl FaultProxy {
    /// A proxy on 127.0.0.1 (an OS-chosen port) to `upstream` (`host:port`).
    pub async fn start(upstream: &str) -> FaultProxy {
        let listener = TcpListener::bind("127.0.0.1:0")
            .await
            .expect("bind the proxy");
        let address = listener.local_addr().expect("the proxy's address");
        let (fault, _) = watch::channel(Fault::None);
        let log = Arc::new(Mutex::new(Log::default()));
        let upstream = upstream.to_string();
        let accept = tokio::spawn({
            let (fault, log) = (fault.clone(), log.clone());
            async move {
                while let Ok((client, _)) = listener.accept().await {
                    log.lock().unwrap().connections += 1;
                    let link = Link {
                        fault: fault.subscribe(),
                        log: log.clone(),
                    };
                    tokio::spawn(link.carry(client, upstream.clone()));
                }
            }
        });
        FaultProxy {
            address,
            fault,
            log,
            accept,
        }
    }

    /// `127.0.0.1:port`, for `--server` / `env.servers`.
    pub fn address(&self) -> String {
        self.address.to_string()
    }

    /// Apply `fault` from now on, to open and new connections.
    pub fn set(&self, fault: Fault) {
        self.log
            .lock()
            .unwrap()
            .faults
            .push((Instant::now(), fault));
        self.fault.send_replace(fault);
    }

    /// Back to the baseline: forward as received, or as [`Self::set_baseline`] said.
    pub fn clear(&self) {
        let baseline = self.log.lock().unwrap().baseline.unwrap_or(Fault::None);
        self.set(baseline);
    }

    /// What holds when no fault does, from now on: e.g. a small delay, which makes a
    /// run at least as long as its steps times twice the delay, on any machine.
    pub fn set_baseline(&self, fault: Fault) {
        self.log.lock().unwrap().baseline = Some(fault);
        self.set(fault);
    }

    /// Every fault set so far, with when.
    pub fn history(&self) -> Vec<(Instant, Fault)> {
        self.log.lock().unwrap().faults.clone()
    }

    /// Every chunk forwarded so far.
    pub fn traffic(&self) -> Vec<Chunk> {
        self.log.lock().unwrap().traffic.clone()
    }

    /// Connections accepted so far.
    pub fn connections(&self) -> usize {
        self.log.lock().unwrap().connections
    }

    /// When an end closed its side of a connection (a FIN read), and which: `Up` the
    /// agent's, `Down` the server's.
    pub fn closes(&self) -> Vec<(Instant, Direction)> {
        self.log.lock().unwrap().closes.clone()
    }
}

impl Drop for FaultProxy {
    fn drop(&mut self) {
        self.accept.abort();
        self.fault.send_replace(Fault::Reset);
    }
}

/// How one direction of a connection ended.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum End {
    /// Its source closed its side (FIN), passed on.
    Closed,
    /// Reset: by the fault, or by an end (a read or write error).
    Reset,
}

/// What every direction of every connection shares.
struct Link {
    fault: watch::Receiver<Fault>,
    log: Arc<Mutex<Log>>,
}

impl Link {
    /// Carry one accepted connection until both directions end, or reset both ends.
    async fn carry(self, client: TcpStream, upstream: String) {
        let server = match TcpStream::connect(&upstream).await {
            Ok(server) => server,
            Err(_) => return reset(&client),
        };
        let _ = (client.set_nodelay(true), server.set_nodelay(true));
        let (mut client_read, mut client_write) = client.into_split();
        let (mut server_read, mut server_write) = server.into_split();
        let ended = {
            let up = pin!(self.pump(&mut client_read, &mut server_write, Direction::Up));
            let down = pin!(self.pump(&mut server_read, &mut client_write, Direction::Down));
            both(up, down).await
        };
        if ended == End::Reset {
            reset(client_read.as_ref());
            reset(server_read.as_ref());
        }
    }

    /// Forward `from` to `to` under the current fault until `from` closes or a reset.
    async fn pump(&self, from: &mut OwnedReadHalf, to: &mut OwnedWriteHalf, way: Direction) -> End {
        let mut fault = self.fault.clone();
        let mut buf = vec![0u8; 16 * 1024];
        loop {
            // While blackholed nothing is read, so the sender's kernel holds the bytes.
            let current = *fault
                .wait_for(|f| *f != Fault::Blackhole)
                .await
                .expect("the proxy outlives its links");
            let limit = match current {
                Fault::Reset => return End::Reset,
                Fault::Throttle(rate) => (rate as usize / 20).clamp(1, buf.len()),
                _ => buf.len(),
            };
            let read = tokio::select! {
                read = from.read(&mut buf[..limit]) => read,
                // The fault changed while waiting: look again (a read is cancel safe).
                _ = fault.changed() => continue,
            };
            let n = match read {
                Ok(0) => {
                    self.log.lock().unwrap().closes.push((Instant::now(), way));
                    let now = *fault.borrow();
                    if let Fault::SlowClose(d) = now {
                        tokio::time::sleep(d).await;
                    }
                    let _ = to.shutdown().await;
                    return End::Closed;
                }
                Ok(n) => n,
                Err(_) => return End::Reset,
            };
            if self.forward(&buf[..n], to, &mut fault, way).await.is_err() {
                return End::Reset;
            }
        }
    }

    /// Write one chunk under the fault that holds now (a blackhole keeps it until it
    /// lifts, so nothing read is lost unless the fault is `Drop`).
    async fn forward(
        &self,
        chunk: &[u8],
        to: &mut OwnedWriteHalf,
        fault: &mut watch::Receiver<Fault>,
        way: Direction,
    ) -> std::io::Result<()> {
        let current = *fault
            .wait_for(|f| *f != Fault::Blackhole)
            .await
            .expect("the proxy outlives its links");
        match current {
            Fault::Drop => return Ok(()),
            Fault::Reset => return Err(std::io::ErrorKind::ConnectionReset.into()),
            Fault::Delay(d) => tokio::time::sleep(d).await,
            Fault::Trickle(d) => {
                for byte in chunk {
                    to.write_all(std::slice::from_ref(byte)).await?;
                    self.record(way, 1);
                    tokio::time::sleep(d).await;
                }
                return Ok(());
            }
            _ => {}
        }
        to.write_all(chunk).await?;
        self.record(way, chunk.len());
        if let Fault::Throttle(rate) = current {
            tokio::time::sleep(Duration::from_secs_f64(chunk.len() as f64 / rate as f64)).await;
        }
        Ok(())
    }

    fn record(&self, direction: Direction, bytes: usize) {
        self.log.lock().unwrap().traffic.push(Chunk {
            at: Instant::now(),
            direction,
            bytes,
        });
    }
}

/// Both directions' end: `Reset` as soon as either is reset, else `Closed` once both
/// have closed.
async fn both(
    mut up: std::pin::Pin<&mut impl std::future::Future<Output = End>>,
    mut down: std::pin::Pin<&mut impl std::future::Future<Output = End>>,
) -> End {
    let (mut up_open, mut down_open) = (true, true);
    while up_open || down_open {
        let end = tokio::select! {
            end = &mut up, if up_open => { up_open = false; end }
            end = &mut down, if down_open => { down_open = false; end }
        };
        if end == End::Reset {
            return End::Reset;
        }
    }
    End::Closed
}

/// Close `socket` with a RST rather than a FIN once its last handle goes.
fn reset(socket: &TcpStream) {
    let _ = socket.set_zero_linger();
}
