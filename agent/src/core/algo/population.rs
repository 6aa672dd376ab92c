//! Which learner configs can train as one population (docs/design.md, "Populations"), and
//! each member's slice of a population's state.
//!
//! Members share everything a batched program cannot vary per member: algorithm,
//! architecture, batch, sequence length, pace, learning rates and trust-region bounds.
//! They differ in `seed` (initialisation and every random stream), the objectives' ε
//! and the scalarization weights (and ε): those become `[P, K]` tensors. The check
//! compares the configs with those fields blanked, so that a new shared field is
//! shared without anyone listing it here.
//!
//! Shape legend: P members, K objectives.

use crate::core::learner_config::{Algorithm, Architecture, ConfigError, LearnerConfig};

/// A config with the per-member fields blanked: two configs with the same key can be
/// members of one population.
pub fn population_key(cfg: &LearnerConfig) -> LearnerConfig {
    let mut key = cfg.clone();
    key.seed = 0;
    for objective in &mut key.objectives {
        objective.epsilon = 0.0;
    }
    if let Algorithm::ScalarizedMpo { epsilon, weights }
    | Algorithm::ScalarizedVmpo { epsilon, weights } = &mut key.algorithm
    {
        *epsilon = 0.0;
        for w in weights {
            w.weight = 0.0;
        }
    }
    key
}

/// Why `cfg` cannot be a member of a population of more than one, if it cannot.
pub fn unbatchable(cfg: &LearnerConfig) -> Option<&'static str> {
    if cfg.conditioning.is_some() {
        Some("an ε-conditioned learner (learner.conditioning)")
    } else if !matches!(cfg.network.architecture, Architecture::Mlp) {
        Some("a mocap torso (network.architecture)")
    } else {
        None
    }
}

/// Checks that `cfgs` can train as one population: at least one; with two or more,
/// all of one population key and of a kind that batches.
pub fn check_population(cfgs: &[LearnerConfig]) -> Result<(), ConfigError> {
    let Some(first) = cfgs.first() else {
        return Err(ConfigError::Invalid {
            field: "population".into(),
            requirement: "at least one member".into(),
            got: "none".into(),
        });
    };
    if cfgs.len() == 1 {
        return Ok(());
    }
    if let Some(what) = unbatchable(first) {
        return Err(ConfigError::Invalid {
            field: "population".into(),
            requirement: "members that batch (unconditioned learners with plain networks)".into(),
            got: format!("{} members of {what}", cfgs.len()),
        });
    }
    let key = population_key(first);
    for (p, cfg) in cfgs.iter().enumerate().skip(1) {
        if population_key(cfg) != key {
            return Err(ConfigError::Invalid {
                field: format!("population member {p}"),
                requirement: "the first member's learner config except seed, ε and \
                              scalarization weights"
                    .into(),
                got: first_difference(&key, &population_key(cfg)),
            });
        }
    }
    Ok(())
}

/// The first top-level field of two configs that differs, as `name: a vs b`.
fn first_difference(a: &LearnerConfig, b: &LearnerConfig) -> String {
    let (a, b) = (
        serde_json::to_value(a).unwrap_or_default(),
        serde_json::to_value(b).unwrap_or_default(),
    );
    if let (Some(a), Some(b)) = (a.as_object(), b.as_object()) {
        for (name, value) in a {
            if b.get(name) != Some(value) {
                let other = b.get(name).cloned().unwrap_or_default();
                return format!("{name}: {value} vs {other}");
            }
        }
    }
    "a different config".into()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::core::learner_config::{ObjectiveConfig, ObjectiveWeight};

    fn member(seed: u64, eps: f64) -> LearnerConfig {
        LearnerConfig {
            seed,
            objectives: vec![ObjectiveConfig {
                name: "task".into(),
                epsilon: eps,
                source: Default::default(),
            }],
            ..LearnerConfig::default()
        }
    }

    #[test]
    fn seeds_and_epsilons_vary_everything_else_is_shared() {
        assert!(check_population(&[member(0, 0.1), member(1, 0.5)]).is_ok());
        let mut other = member(1, 0.5);
        other.mpo.batch_size = 7;
        let err = check_population(&[member(0, 0.1), other]).unwrap_err();
        let text = err.to_string();
        assert!(
            text.contains("population member 1") && text.contains("mpo"),
            "{text}"
        );
        assert!(check_population(&[]).is_err());
    }

    #[test]
    fn scalarization_weights_vary_v_mpo_batches_and_mocap_does_not() {
        let scalarized = |w: f64| LearnerConfig {
            algorithm: Algorithm::ScalarizedMpo {
                epsilon: 0.1,
                weights: vec![ObjectiveWeight {
                    name: "task".into(),
                    weight: w,
                }],
            },
            ..LearnerConfig::default()
        };
        assert!(check_population(&[scalarized(1.0), scalarized(0.2)]).is_ok());
        let vmpo = |seed, eps| LearnerConfig {
            algorithm: Algorithm::MoVmpo,
            ..member(seed, eps)
        };
        assert!(check_population(&[vmpo(0, 0.1), vmpo(1, 0.3)]).is_ok());
        let mut mocap = vmpo(0, 0.1);
        mocap.network.architecture = Architecture::Mocap {
            latent_dim: 60,
            encoder_layers: vec![32],
            reference_match: "reference".into(),
        };
        let err = check_population(&[mocap.clone(), mocap.clone()]).unwrap_err();
        assert!(err.to_string().contains("mocap torso"), "{err}");
        assert!(
            check_population(&[mocap]).is_ok(),
            "one member always batches"
        );
    }
}
