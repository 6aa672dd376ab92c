//! The one error type of config validation, and the checks every config section
//! shares: each failure names the field, what it must be and the value received.

use super::ObjectiveSource;

/// What is wrong with a list of objective names, naming only the kinds that occur.
fn name_problems(missing: &[String], extra: &[String], duplicate: &[String]) -> String {
    [
        ("missing", missing),
        ("not objectives of this env", extra),
        ("named more than once", duplicate),
    ]
    .iter()
    .filter(|(_, names)| !names.is_empty())
    .map(|(what, names)| format!("{what} {names:?}"))
    .collect::<Vec<_>>()
    .join("; ")
}

/// A configuration that cannot be used; the message quotes the received values.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum ConfigError {
    /// One field has an invalid value.
    #[error("{field} must be {requirement}, got {got}")]
    Invalid {
        /// Dotted field path, e.g. `network.min_variance`.
        field: String,
        /// What the value must satisfy.
        requirement: String,
        /// The received value.
        got: String,
    },
    /// Config names and env objective names do not match one to one.
    #[error(
        "{what} must name each of the env's objectives {env:?} once, got {given:?}: {}",
        name_problems(.missing, .extra, .duplicate)
    )]
    ObjectiveNames {
        /// The config field: `learner.objectives` or `learner.algorithm.weights`.
        what: String,
        /// The env's objective names in reward-column order.
        env: Vec<String>,
        /// The names the config gave, in its order.
        given: Vec<String>,
        /// Env objectives the config does not mention.
        missing: Vec<String>,
        /// Config names the env does not have.
        extra: Vec<String>,
        /// Names given more than once.
        duplicate: Vec<String>,
    },
    /// A closed-form source on an objective the env does not declare with that closed form.
    #[error(
        "{field}: source = \"{given}\" computes objective {name:?} in closed form, which needs the env to declare {wanted} for it; the env declares {declared}{}",
        undeclared_hint(.declared)
    )]
    Undeclared {
        /// The config field, `learner.objectives.<i>.source`.
        field: String,
        /// The objective's name.
        name: String,
        /// The source the config gave.
        given: ObjectiveSource,
        /// The closed form that source needs.
        wanted: crate::core::spec::ClosedForm,
        /// What the env declares for the objective.
        declared: crate::core::spec::ClosedForm,
    },
    /// A closed-form objective that the action space or algorithm does not allow.
    #[error("objective {name:?} has source {kind:?}, which {reason}")]
    Unsupported {
        /// Objective name.
        name: String,
        /// Its source.
        kind: ObjectiveSource,
        /// Why not, e.g. "needs continuous actions".
        reason: String,
    },
}

fn undeclared_hint(declared: &crate::core::spec::ClosedForm) -> &'static str {
    match declared {
        crate::core::spec::ClosedForm::Undeclared => {
            ": its server is older than ObjectiveSpec.closed_form, or runs a native front built before it (rebuild it with scripts/setup.sh); upgrade it, or use source = \"learned\""
        }
        _ => " (use source = \"learned\")",
    }
}

pub(crate) fn invalid(field: &str, requirement: &str, got: impl std::fmt::Debug) -> ConfigError {
    ConfigError::Invalid {
        field: field.into(),
        requirement: requirement.into(),
        got: format!("{got:?}"),
    }
}

pub(crate) fn check(
    ok: bool,
    field: &str,
    requirement: &str,
    got: impl std::fmt::Debug,
) -> Result<(), ConfigError> {
    if ok {
        Ok(())
    } else {
        Err(invalid(field, requirement, got))
    }
}

pub(crate) fn finite_pos(x: f64) -> bool {
    x.is_finite() && x > 0.0
}

pub(crate) fn non_negative(field: &str, x: f64) -> Result<(), ConfigError> {
    check(x >= 0.0 && x.is_finite(), field, ">= 0", x)
}
