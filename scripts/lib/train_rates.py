"""Print one row of `agent train` throughput from a finished run directory.

The rates are taken between the first and the last learner.jsonl record, so the replay
warm-up before the first learner step is left out; `step ms` is the median learner step.
Used by scripts/bench_throughput.sh and scripts/bench_scaling.sh.

    python scripts/lib/train_rates.py RUN_DIR LABEL
"""

import json
import statistics
import sys


def main() -> None:
    run_dir, label = sys.argv[1:3]
    with open(f"{run_dir}/summary.json") as f:
        device = json.load(f)["learner_device"]
    with open(f"{run_dir}/learner.jsonl") as f:
        records = [json.loads(line) for line in f]
    first, last = records[0], records[-1]
    seconds = last["wall_seconds"] - first["wall_seconds"]
    env_steps = last["env_steps"] - first["env_steps"]
    learner_steps = last["learner_step"] - first["learner_step"]
    step_ms = statistics.median(r["step_ms"] for r in records)
    print(
        f"{label:<40} {env_steps:>10} {env_steps / seconds:>14.1f} {learner_steps / seconds:>18.1f}"
        f" {step_ms:>14.1f}  {device}"
    )


if __name__ == "__main__":
    main()
