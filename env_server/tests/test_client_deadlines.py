"""The Python client's deadlines: no call waits forever on a server that does not answer.

"Does not answer" is real here: a server process stopped with SIGSTOP (its socket open,
the kernel still accepting connections for it), and a TCP listener that accepts and
never speaks. Each bound allows the call's `timeout` plus 10 s for a loaded machine to
schedule the watchdog and grpc's cancellation; the point is that it ends, and says why.
"""

from __future__ import annotations

import contextlib
import os
import signal
import socket
import time
from collections.abc import Iterator

import numpy as np
import pytest
from conftest import FRONTS, proc_stat, server_process

from env_server.client import DeadlineExceededError, RemoteEnv, RemoteVectorEnv, list_envs

TIMEOUT = 1.0
SLACK = 10.0


@contextlib.contextmanager
def stopped(pid: int) -> Iterator[None]:
    # kill() returns before the signal has stopped the process: on a loaded machine a
    # call sent at once could still be answered (seen once beside the Rust tests).
    os.kill(pid, signal.SIGSTOP)
    deadline = time.monotonic() + 10
    while proc_stat(pid)[0] != "T":
        assert time.monotonic() < deadline, f"pid {pid} not stopped 10 s after SIGSTOP"
        time.sleep(0.005)
    try:
        yield
    finally:
        os.kill(pid, signal.SIGCONT)


def takes(call) -> tuple[Exception, float]:
    """The exception `call()` raises and the seconds it took."""
    started = time.monotonic()
    with pytest.raises(DeadlineExceededError) as info:
        call()
    return info.value, time.monotonic() - started


@pytest.mark.parametrize("front", FRONTS)
def test_a_reset_and_a_step_on_a_stopped_server_give_up(front: str) -> None:
    with server_process("--front", front) as (proc, address):
        env = RemoteVectorEnv(address, "dst", 2, seed=0, timeout=TIMEOUT)
        try:
            env.reset()
            env.step(np.array([1, 1]))  # the step stream is open
            with stopped(proc.pid):
                err, took = takes(lambda: env.reset())
            assert "Reset: expected an answer within timeout=1 s, got none" in str(err), err
            assert TIMEOUT <= took < TIMEOUT + SLACK, took
            # A unary call that ran out leaves the session: it goes on once the server answers.
            env.reset(seed=0)
            _, reward, *_ = env.step(np.array([1, 1]))
            assert reward.shape == (2, 2)
            with stopped(proc.pid):
                err, took = takes(lambda: env.step(np.array([1, 1])))
            assert "Step: expected an answer within timeout=1 s, got none" in str(err), err
            assert isinstance(err, TimeoutError)
            assert TIMEOUT <= took < TIMEOUT + SLACK, took
        finally:
            env.close()  # the server closed the session with its broken stream: close still returns
        with RemoteVectorEnv(address, "dst", 2, seed=0, timeout=TIMEOUT) as again:  # the server serves on
            again.reset()
            _, reward, *_ = again.step(np.array([1, 1]))
            assert reward.shape == (2, 2)


def test_make_and_list_envs_on_a_server_that_never_answers_give_up() -> None:
    with socket.socket() as silent:
        silent.bind(("127.0.0.1", 0))
        silent.listen()
        address = f"127.0.0.1:{silent.getsockname()[1]}"
        err, took = takes(lambda: RemoteEnv(address, "dst", timeout=TIMEOUT))
        assert "Make: expected an answer within timeout=1 s, got none" in str(err), err
        assert TIMEOUT <= took < TIMEOUT + SLACK, took
        err, took = takes(lambda: list_envs(address, timeout=TIMEOUT))
        assert "ListEnvs: expected an answer within timeout=1 s" in str(err), err


@pytest.mark.parametrize("bad", [0, -1.0, float("nan"), float("inf"), "60"])
def test_a_bad_timeout_is_refused_naming_it(bad) -> None:
    with pytest.raises(ValueError, match=r"timeout: expected finite seconds > 0 or None \(wait forever\), got"):
        RemoteEnv("127.0.0.1:1", "dst", timeout=bad)
