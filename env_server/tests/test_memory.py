"""A server that makes and closes sessions gives the memory back.

Measured on the 2-core machine, humanoid-run with B = 20 (Make, Reset, 5 Steps, Close):
before, the server's RSS went 366, 607, 691 MiB after the first three cycles and 1222 MiB
after sixty, with no session open (the lease reaper's loop variable kept a closed session
alive, its simulators waited for the cycle collector, and malloc kept the freed pages).
Now it stays at 120-130 MiB over sixty cycles (a few MiB of noise, 20 at most). So
CYCLES cycles, about 2 s each, tell the two apart by far more than MARGIN_MIB: the old
server passed the margin in its second cycle.
"""

from __future__ import annotations

import sys
import time

import grpc
import numpy as np
import pytest
from conftest import FRONTS, make, server_process, step

from env_server._proto.mo_env.v1 import env_pb2 as pb
from env_server._proto.mo_env.v1 import env_pb2_grpc
from env_server.service import RELEASE_DELAY_S

CYCLES = 6
B = 20
MARGIN_MIB = 60


def rss_mib(pid: int) -> float:
    with open(f"/proc/{pid}/status") as f:
        for line in f:
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) / 1024
    raise AssertionError(f"no VmRSS in /proc/{pid}/status")


def cycle(stub: env_pb2_grpc.EnvServiceStub) -> None:
    session_id = make(stub, "humanoid-run", B, seed=0).session_id
    stub.Reset(pb.ResetRequest(session_id=session_id))
    for _ in range(5):
        step(stub, session_id, np.zeros((B, 21), np.float32))
    stub.Close(pb.CloseRequest(session_id=session_id))
    time.sleep(RELEASE_DELAY_S + 0.5)  # the server releases memory shortly after a Close


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads /proc and needs glibc's malloc_trim")
@pytest.mark.parametrize("front", FRONTS)
def test_closed_sessions_give_their_memory_back(front: str) -> None:
    with server_process("--front", front) as (proc, addr), grpc.insecure_channel(addr) as channel:
        s = env_pb2_grpc.EnvServiceStub(channel)
        cycle(s)
        first = rss_mib(proc.pid)
        for _ in range(CYCLES - 1):
            cycle(s)
        last = rss_mib(proc.pid)
        assert last - first < MARGIN_MIB, f"RSS {first:.0f} MiB after the first cycle, {last:.0f} after {CYCLES}"
