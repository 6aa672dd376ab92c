"""`python -m env_server.tools.ray --sweep-shards S --sweep-dir DIR -- agent sweep --config C`: a sweep's shards as Ray tasks.

Shard I of S is one Ray task that runs `agent sweep --config C --shard I/S --dir
DIR/shard-I-of-S --server file:PATH` against the launcher's servers. Ray retries a task whose
node or worker is lost (`max_retries`), and the retry resumes the shard's folder (`agent sweep
--resume`) wherever Ray places it: finished runs are kept, the others continue from their
checkpoints. So DIR, the address file and COMMAND's files must be reachable at the same paths
from every node (shared storage, or one machine). When every shard has finished, the launcher
merges them on its own node: `agent sweep --report DIR/shard-* --dir DIR/front`.

Each task appends one JSON line per attempt to `DIR/shard-I-of-S.attempts` (node, pid, and
whether it resumed), which is how a retry can be seen after the fact.
"""

from __future__ import annotations

import ctypes
import json
import os
import signal
import subprocess
import sys
from typing import Any

_PR_SET_PDEATHSIG = 1
# Looked up here, not between fork and exec, where only async-signal-safe work is wise.
_prctl = ctypes.CDLL(None, use_errno=True).prctl if sys.platform.startswith("linux") else None

DROPPED_ON_RESUME = ("--config", "--set", "--total-env-steps")
"""`agent sweep` flags a resume takes from the folder instead (each with one value)."""

OWN_FLAGS = ("--shard", "--resume", "--report", "--dir", "--server")
"""`agent sweep` flags the launcher sets itself, refused in COMMAND."""


def _die_with_parent() -> None:
    """In the agent child, before exec: SIGKILL when the task's worker dies, as the node's loss would."""
    if _prctl is not None:
        _prctl(_PR_SET_PDEATHSIG, signal.SIGKILL)


def check_command(command: list[str]) -> str | None:
    """Why COMMAND cannot be cut into shards (None when it can): it must be `... sweep --config C ...`."""
    if "sweep" not in command:
        return f"expected a COMMAND of the form `agent sweep --config FILE ...`, got {command}"
    flags = command[command.index("sweep") + 1 :]
    names = [f.split("=", 1)[0] for f in flags]
    if "--config" not in names:
        return f"expected `agent sweep --config FILE` (the sweep to cut into shards), got {command}"
    taken = sorted({n for n in names if n in OWN_FLAGS})
    if taken:
        return f"expected no {', '.join(taken)} in COMMAND (the launcher sets them for each shard), got {command}"
    return None


def absolute(command: list[str]) -> list[str]:
    """COMMAND with the program and the sweep file as absolute paths: a task's working directory is not ours."""
    out = list(command)
    if os.sep in out[0]:
        out[0] = os.path.abspath(out[0])
    for i, arg in enumerate(out):
        if arg == "--config" and i + 1 < len(out):
            out[i + 1] = os.path.abspath(out[i + 1])
        elif arg.startswith("--config="):
            out[i] = "--config=" + os.path.abspath(arg.split("=", 1)[1])
    return out


def shard_dir(root: str, index: int, count: int) -> str:
    return os.path.join(root, f"shard-{index}-of-{count}")


def start_argv(command: list[str], index: int, count: int, folder: str) -> list[str]:
    """`agent sweep --config C ... --shard I/S --dir FOLDER`."""
    return [*command, "--shard", f"{index}/{count}", "--dir", folder]


def resume_argv(command: list[str], folder: str) -> list[str]:
    """`agent sweep --resume FOLDER` with COMMAND's other flags (device, TLS, token, video)."""
    at = command.index("sweep") + 1
    kept, rest = [], command[at:]
    i = 0
    while i < len(rest):
        name = rest[i].split("=", 1)[0]
        if name in DROPPED_ON_RESUME:
            i += 1 if "=" in rest[i] else 2
            continue
        kept.append(rest[i])
        i += 1
    return [*command[:at], "--resume", folder, *kept]


def report_argv(command: list[str], folders: list[str], out: str) -> list[str]:
    """`agent sweep --report FOLDER... --dir OUT`: the merge (no server, no training flags)."""
    return [*command[: command.index("sweep") + 1], "--report", *folders, "--dir", out]


def run_shard(command: list[str], index: int, count: int, root: str, address_file: str, env: dict[str, str]) -> dict:
    """Ray task body: start or resume shard `index` of `count` under `root`; its exit code and attempts."""
    import ray

    folder = shard_dir(root, index, count)
    resume = os.path.exists(os.path.join(folder, "sweep.json"))
    argv = resume_argv(command, folder) if resume else start_argv(command, index, count, folder)
    argv += ["--server", f"file:{address_file}"]
    attempt = {"node": ray.get_runtime_context().get_node_id(), "pid": os.getpid(), "resume": resume}
    with open(folder + ".attempts", "a") as f:
        f.write(json.dumps(attempt) + "\n")
    proc = subprocess.Popen(
        argv,
        env={**os.environ, **env, "ENV_SERVER_ADDRESS_FILE": address_file},
        stdin=subprocess.DEVNULL,
        preexec_fn=_die_with_parent,
    )
    return {"code": proc.wait(), "attempts": read_attempts(folder)}


def read_attempts(folder: str) -> list[dict[str, Any]]:
    """The attempts a shard's tasks recorded, oldest first."""
    try:
        with open(folder + ".attempts") as f:
            return [json.loads(line) for line in f if line.strip()]
    except FileNotFoundError:
        return []
