//! How long the agent waits for an env server: a deadline on every call, and when a
//! server that keeps missing them counts as lost (`[env.deadlines]`).
//!
//! No paper equation here: this is the transport's side of the actors (Algorithm 2).
//! A Step's deadline follows the session's own pace: `step_multiple` times the slowest
//! of its last 128 to 256 Steps (its Reset's time before the first Step), kept between
//! `floor_seconds` and `ceiling_seconds`; a window rather than the slowest ever, so
//! that one slow moment (a loaded machine, a slow link) does not lengthen every later
//! deadline of the session. A Reset's follows the slowest Reset or Step
//! (the Make's time before the first Reset). Make and Render build or draw, which no
//! step time predicts, so they get the ceiling; GetVersion, ListEnvs, Close and a
//! connection's set-up get the floor. A missed deadline is an error the actor turns
//! into a session restart, on another server first ([`crate::env::pool::ServerPool`]).

use std::time::{Duration, Instant};

use serde::{Deserialize, Serialize};

use crate::core::learner_config::ConfigError;

/// How long each env call may wait for its answer, and what a run does about servers
/// that miss their deadlines.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct DeadlineConfig {
    /// Shortest deadline of any call, in seconds, and the deadline of GetVersion,
    /// ListEnvs, Close and a connection's set-up. Chosen far above a step of any shipped
    /// task (a humanoid step with workers takes milliseconds) so that a loaded machine
    /// never trips it, and short enough that a server that stopped answering is given
    /// up within it rather than after its 120 s session lease.
    pub floor_seconds: f64,
    /// Longest deadline of a Step or Reset, and the deadline of Make and Render (which
    /// build instances or draw frames: seconds for large humanoid sessions).
    pub ceiling_seconds: f64,
    /// A Step's deadline in multiples of the slowest of the session's last 128 to 256
    /// Steps (its Reset's time before the first Step), between the floor and the
    /// ceiling; a Reset's in multiples of the slowest Reset or recent Step (the Make's
    /// time before the first Reset).
    pub step_multiple: f64,
    /// Consecutive failures (missed deadlines or refused connections) after which a
    /// server counts as lost: actors looking for a new home try it after every other
    /// server until it answers again.
    pub lost_after: u32,
    /// How long an actor whose session was lost goes on trying to make it again, on
    /// any server, before the run stops with an error, in seconds; also how long the
    /// run's spec probe and final evaluation try again after a lost session.
    pub reconnect_seconds: f64,
}

impl Default for DeadlineConfig {
    fn default() -> Self {
        Self {
            floor_seconds: 10.0,
            ceiling_seconds: 60.0,
            step_multiple: 20.0,
            lost_after: 3,
            reconnect_seconds: 300.0,
        }
    }
}

impl DeadlineConfig {
    /// Positive, finite times; the ceiling at or above the floor.
    pub fn validate(&self) -> Result<(), ConfigError> {
        let invalid = |field: &str, requirement: String, got: String| {
            Err(ConfigError::Invalid {
                field: format!("env.deadlines.{field}"),
                requirement,
                got,
            })
        };
        for (field, v) in [
            ("floor_seconds", self.floor_seconds),
            ("ceiling_seconds", self.ceiling_seconds),
            ("reconnect_seconds", self.reconnect_seconds),
        ] {
            if !(v.is_finite() && v > 0.0) {
                return invalid(field, "finite and > 0".into(), v.to_string());
            }
        }
        if self.ceiling_seconds < self.floor_seconds {
            return invalid(
                "ceiling_seconds",
                format!(">= env.deadlines.floor_seconds = {}", self.floor_seconds),
                self.ceiling_seconds.to_string(),
            );
        }
        if !(self.step_multiple.is_finite() && self.step_multiple >= 1.0) {
            return invalid(
                "step_multiple",
                "finite and >= 1".into(),
                self.step_multiple.to_string(),
            );
        }
        if self.lost_after == 0 {
            return invalid("lost_after", ">= 1".into(), "0".into());
        }
        Ok(())
    }

    /// The shortest deadline (calls with no measured pace).
    pub fn floor(&self) -> Duration {
        Duration::from_secs_f64(self.floor_seconds)
    }

    /// The longest deadline (Make, Render).
    pub fn ceiling(&self) -> Duration {
        Duration::from_secs_f64(self.ceiling_seconds)
    }

    /// How long to keep trying to make a lost session again.
    pub fn reconnect(&self) -> Duration {
        Duration::from_secs_f64(self.reconnect_seconds)
    }

    /// `step_multiple` times `measured`, between the floor and the ceiling.
    fn paced(&self, measured: Duration) -> Duration {
        let secs = measured.as_secs_f64() * self.step_multiple;
        Duration::from_secs_f64(secs.clamp(self.floor_seconds, self.ceiling_seconds))
    }
}

/// Steps per half of the window the slowest recent Step is taken over.
const WINDOW_HALF: u32 = 128;

/// The waits between rounds of attempts to reach a server again: 0.2 s doubling to 5 s,
/// enough for a server (or its replacement) to start without a busy loop against
/// servers that are down, until `reconnect_seconds` have passed.
#[derive(Debug)]
pub struct Backoff {
    delay: Duration,
    give_up: Instant,
}

impl Backoff {
    /// Rounds from now until `config.reconnect_seconds` pass.
    pub fn new(config: &DeadlineConfig) -> Self {
        Self {
            delay: Duration::from_millis(200),
            give_up: Instant::now() + config.reconnect(),
        }
    }

    /// Wait before the next round; false (without waiting) when it would end after
    /// the give-up time.
    pub async fn wait(&mut self) -> bool {
        if Instant::now() + self.delay >= self.give_up {
            return false;
        }
        tokio::time::sleep(self.delay).await;
        self.delay = (self.delay * 2).min(Duration::from_secs(5));
        true
    }
}

/// The times one session's calls took, which its later deadlines follow.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct CallTimes {
    /// The Make that created the session.
    make: Duration,
    /// The slowest Reset so far.
    slowest_reset: Option<Duration>,
    /// The slowest Step of the current half-window, and how many it has seen.
    current: Option<Duration>,
    current_steps: u32,
    /// The slowest Step of the half-window before.
    previous: Option<Duration>,
}

impl CallTimes {
    /// A session whose Make took `make`.
    pub fn after_make(make: Duration) -> Self {
        Self {
            make,
            ..Self::default()
        }
    }

    /// Record a Step's time.
    pub fn stepped(&mut self, took: Duration) {
        if self.current_steps == WINDOW_HALF {
            self.previous = self.current.take();
            self.current_steps = 0;
        }
        self.current = Some(self.current.map_or(took, |s| s.max(took)));
        self.current_steps += 1;
    }

    /// The slowest of the last 128 to 256 Steps.
    fn slowest_step(&self) -> Option<Duration> {
        match (self.current, self.previous) {
            (Some(c), Some(p)) => Some(c.max(p)),
            (c, p) => c.or(p),
        }
    }

    /// Record a Reset's time.
    pub fn reset(&mut self, took: Duration) {
        self.slowest_reset = Some(self.slowest_reset.map_or(took, |s| s.max(took)));
    }

    /// The next Step's deadline.
    pub fn step_deadline(&self, config: &DeadlineConfig) -> Duration {
        let measured = self
            .slowest_step()
            .or(self.slowest_reset)
            .unwrap_or(self.make);
        config.paced(measured)
    }

    /// The next Reset's deadline.
    pub fn reset_deadline(&self, config: &DeadlineConfig) -> Duration {
        let measured = self
            .slowest_reset
            .unwrap_or(self.make)
            .max(self.slowest_step().unwrap_or_default());
        config.paced(measured)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn ms(v: u64) -> Duration {
        Duration::from_millis(v)
    }

    #[test]
    fn a_step_deadline_follows_the_slowest_step_between_floor_and_ceiling() {
        let config = DeadlineConfig {
            floor_seconds: 1.0,
            ceiling_seconds: 10.0,
            step_multiple: 20.0,
            ..DeadlineConfig::default()
        };
        let mut times = CallTimes::after_make(ms(2_000));
        // Before any Reset: the Make's pace, capped by the ceiling (20 x 2 s = 40 s).
        assert_eq!(times.reset_deadline(&config), ms(10_000));
        times.reset(ms(100));
        // Before any Step: the Reset's pace (20 x 0.1 s).
        assert_eq!(times.step_deadline(&config), ms(2_000));
        times.stepped(ms(1));
        // A fast step: the floor.
        assert_eq!(times.step_deadline(&config), ms(1_000));
        times.stepped(ms(150));
        times.stepped(ms(3));
        // The slowest step sets the pace, not the latest.
        assert_eq!(times.step_deadline(&config), ms(3_000));
        assert_eq!(times.reset_deadline(&config), ms(3_000));
        // Until it is more than a window old: 125 more steps fill the first half (128
        // steps), 128 the second; the slow step leaves the window with the next one.
        for _ in 0..125 + 128 {
            times.stepped(ms(2));
        }
        assert_eq!(times.step_deadline(&config), ms(3_000));
        times.stepped(ms(2));
        assert_eq!(times.step_deadline(&config), ms(1_000));
        // A Reset's deadline keeps the slowest Reset.
        assert_eq!(times.reset_deadline(&config), ms(2_000));
    }

    #[test]
    fn validate_names_the_field_and_quotes_the_value() {
        let d = DeadlineConfig::default();
        let cases = [
            (
                DeadlineConfig {
                    ceiling_seconds: 5.0,
                    floor_seconds: 8.0,
                    ..d
                },
                "env.deadlines.ceiling_seconds must be >= env.deadlines.floor_seconds = 8, got 5",
            ),
            (
                DeadlineConfig {
                    step_multiple: 0.5,
                    ..d
                },
                "env.deadlines.step_multiple must be finite and >= 1, got 0.5",
            ),
            (
                DeadlineConfig {
                    floor_seconds: f64::NAN,
                    ..d
                },
                "env.deadlines.floor_seconds must be finite and > 0, got NaN",
            ),
            (
                DeadlineConfig { lost_after: 0, ..d },
                "env.deadlines.lost_after must be >= 1, got 0",
            ),
        ];
        for (bad, expected) in cases {
            assert_eq!(bad.validate().unwrap_err().to_string(), expected);
        }
        assert!(d.validate().is_ok());
    }
}
