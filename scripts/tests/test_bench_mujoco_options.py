"""scripts/bench_mujoco.sh refuses a bad option before it builds or starts anything: the
error names the option, what it expects and what it got, and the exit status is 2.
(A good invocation trains for minutes; docs/benchmarks/mujoco.md has a short one.)
"""

from __future__ import annotations

import pathlib
import subprocess

import pytest

SCRIPT = pathlib.Path(__file__).resolve().parents[1] / "bench_mujoco.sh"


@pytest.mark.parametrize(
    ("args", "expected"),
    [
        (["--eval-episodes", "0"], ["--eval-episodes", "positive integer", "'0'"]),
        (["--eval-episodes", "ten"], ["--eval-episodes", "positive integer", "'ten'"]),
        (["--eval-episodes"], ["--eval-episodes", "expected a value"]),
        (["--tasks", "Walker2d-v5"], ["--tasks", "Hopper-v5", "'Walker2d-v5'"]),
        (["--sides", "ours,theirs"], ["--sides", "ours and/or peers", "'theirs'"]),
        (["--config", "Hopper-v5"], ["--config", "TASK=FILE", "'Hopper-v5'"]),
        (["--speed", "1"], ["unknown option", "'--speed'"]),
    ],
)
def test_a_bad_option_is_refused_with_its_name_what_was_expected_and_what_came(
    args: list[str], expected: list[str]
) -> None:
    done = subprocess.run(["bash", str(SCRIPT), *args], capture_output=True, text=True, timeout=60)
    assert done.returncode == 2, done
    for part in expected:
        assert part in done.stderr, (part, done.stderr)
    # Refused before the build and the session's output folder.
    assert "Finished" not in done.stderr + done.stdout and "==> session" not in done.stdout
