#!/usr/bin/env bash
# Runs the end-to-end learning tests with other seeds and prints what each measured,
# so that a learning threshold is checked on seeds other than the one the test
# command trains (float kernels differ between CPUs: one seed's trajectory differs
# between machines, a threshold must hold across seeds). Each test reads its base
# seed from MO_MPO_TEST_SEED (tests/src/lib.rs::test_seed, agent/tests/seed) and prints its figures on
# a "learning-figures" line; record the seeds and figures in the test's comment.
#
#   scripts/learning_seeds.sh                 # seeds 1-5, every learning test
#   scripts/learning_seeds.sh "6 7" learning  # seeds 6 and 7, tests/tests/learning.rs only
#
# Not part of the test command (each seed re-runs minutes of training).
set -uo pipefail
cd "$(dirname "$0")/.."
seeds=${1:-1 2 3 4 5}
shift || true
# The test binary of every end-to-end learning test (names are unique in the workspace).
tests=(learning main_job conditioned onpolicy onpolicy_preferences resume_continuity
  behaviour vmpo_behaviour scale_invariance python_policy)
if [[ $# -gt 0 ]]; then
  wanted=" $* "
  tests=($(printf '%s\n' "${tests[@]}" | while read -r t; do [[ $wanted == *" $t "* ]] && echo "$t"; done))
fi
scripts/setup.sh
failed=0
# --workspace, not -p PACKAGE: -p resolves the dependencies' features for one package,
# which differ from the workspace's, and would compile tonic, tch and the rest again
# beside the test command's build.
for test in "${tests[@]}"; do
  cargo test --locked -q --workspace --test "$test" --no-run 2>/dev/null || { echo "$test: does not build" >&2; exit 1; }
  for seed in $seeds; do
    out=$(MO_MPO_TEST_SEED=$seed cargo test --locked -q --workspace --test "$test" -- --nocapture 2>&1)
    status=$([[ $? -eq 0 ]] && echo passed || echo FAILED)
    [[ $status == FAILED ]] && failed=$((failed + 1))
    figures=$(grep -o 'learning-figures .*' <<<"$out" | sed 's/^learning-figures //' | paste -sd ';' -)
    echo "$test seed $seed: $status ${figures:-(no figures printed)}"
    [[ $status == FAILED ]] && grep -E "panicked|assertion" <<<"$out" | head -3 | sed 's/^/    /'
  done
done
echo "$failed failed"
[[ $failed -eq 0 ]]
