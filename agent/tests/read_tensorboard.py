"""Print the scalars of a TensorBoard log directory as JSON: {tag: [[step, value], ...]}.

Read with the `tensorboard` package's own EventAccumulator, so that agent/tests/interrupt.rs
checks the agent's event files against TensorBoard's reader, not against our own parser.
"""

import json
import sys

from tensorboard.backend.event_processing import event_accumulator


def main(log_dir: str) -> None:
    acc = event_accumulator.EventAccumulator(log_dir, size_guidance={event_accumulator.SCALARS: 0})
    acc.Reload()
    scalars = {tag: [[e.step, e.value] for e in acc.Scalars(tag)] for tag in acc.Tags()["scalars"]}
    json.dump(scalars, sys.stdout)


if __name__ == "__main__":
    main(sys.argv[1])
