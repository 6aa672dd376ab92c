//! The base seed of a learning test and the line that reports what it measured, so
//! that `scripts/learning_seeds.sh` can check a threshold on other seeds (float kernels
//! differ between CPUs: one seed's trajectory differs between machines). The same two
//! functions as `integration_tests::test_seed` / `report_figures`, which this crate's
//! tests cannot depend on.
#![allow(dead_code, unreachable_pub, reason = "each test file uses a subset")]

/// 0, or `MO_MPO_TEST_SEED` when set. A test adds it to the seeds it trains from, so
/// that the default run is unchanged and `MO_MPO_TEST_SEED=s` moves every seed by `s`.
pub fn test_seed() -> u64 {
    std::env::var("MO_MPO_TEST_SEED").map_or(0, |v| {
        v.parse()
            .unwrap_or_else(|_| panic!("MO_MPO_TEST_SEED: expected an unsigned integer, got {v:?}"))
    })
}

/// Prints a learning test's measured figures on the line `scripts/learning_seeds.sh`
/// collects (cargo shows it with `--nocapture`).
pub fn report_figures(test: &str, figures: &str) {
    eprintln!("learning-figures {test} seed {}: {figures}", test_seed());
}
