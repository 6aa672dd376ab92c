//! What a user sees and does while a run trains: the progress bar and its message,
//! and the signals (Ctrl-C, SIGTERM) that end a run early with its report.

use std::sync::{Arc, Mutex};
use std::time::Duration;

use indicatif::{ProgressBar, ProgressStyle};
use tokio::task::JoinHandle;

use crate::core::algo::LearnerStats;
use crate::report::metrics::format_temperatures;
use crate::runtime::run_config::TrainConfig;
use crate::runtime::schedule::{Counters, Schedule};

/// Resolves on the first Ctrl-C (SIGINT) or SIGTERM, with its name.
async fn interrupt_signal() -> &'static str {
    #[cfg(unix)]
    {
        use tokio::signal::unix::{SignalKind, signal};
        match signal(SignalKind::terminate()) {
            Ok(mut term) => tokio::select! {
                name = ctrl_c() => name,
                _ = term.recv() => "SIGTERM",
            },
            Err(e) => {
                tracing::warn!("cannot listen for SIGTERM ({e}); only Ctrl-C stops the run early");
                ctrl_c().await
            }
        }
    }
    #[cfg(not(unix))]
    {
        ctrl_c().await
    }
}

/// Resolves on Ctrl-C; never, when the handler cannot be installed.
async fn ctrl_c() -> &'static str {
    if let Err(e) = tokio::signal::ctrl_c().await {
        tracing::warn!("cannot listen for Ctrl-C ({e})");
        std::future::pending::<()>().await;
    }
    "Ctrl-C"
}

/// Every 250 ms until the run stops: moves the bar and its message. The first Ctrl-C or
/// SIGTERM interrupts the run (a final checkpoint and report follow); a second Ctrl-C
/// exits at once.
pub(super) fn spawn_ticker(
    schedule: Arc<Schedule>,
    latest: Arc<Mutex<Option<LearnerStats>>>,
    bar: ProgressBar,
    names: Vec<String>,
    learner_objectives: usize,
) -> JoinHandle<()> {
    tokio::spawn(async move {
        let mut signal = std::pin::pin!(interrupt_signal());
        let mut signalled = false;
        loop {
            tokio::select! {
                _ = tokio::time::sleep(Duration::from_millis(250)) => {}
                name = &mut signal, if !signalled => {
                    signalled = true;
                    tracing::warn!("{name}: stopping after a final checkpoint and report (Ctrl-C again to exit at once)");
                    schedule.interrupt(name);
                    tokio::spawn(async {
                        if tokio::signal::ctrl_c().await.is_ok() {
                            std::process::exit(130);
                        }
                    });
                }
            }
            let c = schedule.counters();
            bar.set_position(c.env_steps);
            bar.set_message(progress_message(
                &c,
                &names,
                learner_objectives,
                latest.lock().unwrap_or_else(|e| e.into_inner()).as_ref(),
            ));
            if c.stop {
                break;
            }
        }
    })
}

pub(super) fn progress_bar(enabled: bool, cfg: &TrainConfig, schedule: &Schedule) -> ProgressBar {
    if !enabled {
        return ProgressBar::hidden();
    }
    let bar = ProgressBar::new(cfg.run.total_env_steps).with_style(
        ProgressStyle::with_template(
            "{bar:30} {pos:>8}/{len} env steps [{elapsed_precise}<{eta}] {msg}",
        )
        .expect("valid template"),
    );
    bar.set_position(schedule.counters().env_steps);
    bar
}

/// `learner_objectives`: how many E-step objectives the temperatures are listed by.
fn progress_message(
    c: &Counters,
    names: &[String],
    learner_objectives: usize,
    stats: Option<&LearnerStats>,
) -> String {
    let fmt = |v: &[f64]| {
        v.iter()
            .map(|x| format!("{x:.2}"))
            .collect::<Vec<_>>()
            .join(", ")
    };
    let mut msg = format!(
        "learner {} | ep {} | return [{}]=[{}]",
        c.learner_steps,
        c.episodes,
        names.join(", "),
        fmt(&c.recent_mean_return())
    );
    if let Some(s) = stats {
        let kl: Vec<f64> = s.policy_kl.iter().map(|&x| f64::from(x)).collect();
        msg.push_str(&format!(
            " | eta {} | KL [{}]",
            format_temperatures(&s.temperature, learner_objectives),
            kl.iter()
                .map(|x| format!("{x:.1e}"))
                .collect::<Vec<_>>()
                .join(", ")
        ));
    }
    msg
}
