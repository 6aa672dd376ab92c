"""What the server and its Python client both use, so that neither imports the other's code.

The client side (client.py, remote.py, connection.py, trained_policy.py) imports from
the server package only this module and the generated protobuf; the server's modules
import it too (session.py, task.py, spaces.py and security.py re-export its names). A
test checks the rule (tests/test_layout.py). Here:

- a session as both sides see it: `Autoreset`, `Objective` (and its `ClosedForm`),
  `SessionSpec`;
- gymnasium spaces <-> plain spec dicts, the one mapping wire.py turns into protobuf and
  the client turns back into spaces. Spec dicts (one key each):
      {"box": {"dtype": "float32", "shape": [21], "low": [-1.0], "high": [1.0]}}
      {"discrete": {"n": 4, "start": 0}}
      {"dict": [("joint", <spec>), ("target", <spec>)]}
  Box low/high hold one value when every element shares it, else prod(shape) values;
- the ids of the shipped envs, which the client registers with gymnasium without
  importing the envs (each loads its simulator);
- the token file format, which the server's --auth-token-file and the client's
  `token_file=` both read: one token per line, optionally `name:token`; blank lines and
  lines starting with `#` are skipped. A token is at least 16 printable ASCII characters
  without spaces or `:` (`python -c "import secrets; print(secrets.token_urlsafe(32))"`).
  A line without a name is named `token-<line number>`.
"""

from __future__ import annotations

import dataclasses
import enum
import math
from collections.abc import Sequence
from typing import Any

import gymnasium
import numpy as np


# ---------------------------------------------------------------- a session
class Autoreset(enum.IntEnum):
    """What happens to an instance whose episode ended (numbers match the proto enum)."""

    SAME_STEP = 1
    NEXT_STEP = 2
    DISABLED = 3


class ClosedForm(enum.Enum):
    """What an objective's per-step reward is as a function of the step's action alone.

    Declared on the `Objective` and served as `ObjectiveSpec.closed_form`: a learner may
    compute a declared objective from the action instead of learning it (the agent's
    `source = "action_norm"`), and refuses to for an objective that declares nothing.
    """

    #: No closed form: the reward depends on more than the action (the default).
    NONE = "none"
    #: reward = -||a||_2 (times `Objective.scale`): `a` is the action `Task.step`
    #: receives, which is the client's action exactly as sent (the server refuses
    #: actions outside the Box; nothing clips or rescales them), and ||.||_2 the
    #: Euclidean norm over all its elements. Box action spaces only; `min` and `max`
    #: must be the exact bounds of that over the Box (the server checks): for Box(-2, 2,
    #: (1,)) min = -2, max = 0. A reward of -a^2 or -||a||_1 is NOT this: leave NONE.
    ACTION_NORM = "action_norm"
    #: Not declared either way: only on objectives a client read from a server older
    #: than `ObjectiveSpec.closed_form` (a Task never sets it).
    UNDECLARED = "undeclared"


@dataclasses.dataclass(frozen=True)
class Objective:
    """One entry of the vector reward."""

    name: str
    description: str
    min: float = -math.inf
    max: float = math.inf
    #: What the session multiplies this reward by (Make kwarg `reward_scale`); min and
    #: max are already scaled.
    scale: float = 1.0
    #: The reward's closed form, if it has one a learner may use instead of a critic.
    closed_form: ClosedForm = ClosedForm.NONE


@dataclasses.dataclass(frozen=True)
class SessionSpec:
    """Everything a client needs to know about a session (the EnvSpec)."""

    env_id: str
    num_envs: int
    observation_space: gymnasium.spaces.Space
    action_space: gymnasium.spaces.Space
    objectives: tuple[Objective, ...]
    max_episode_steps: int  # 0 = no time limit
    autoreset: Autoreset
    discount: float
    info_keys: tuple[str, ...]  # every key the task can report


# ---------------------------------------------------------------- spaces
#: The dtypes the wire format carries, by numpy name.
SUPPORTED_DTYPES: tuple[str, ...] = ("float32", "float64", "int32", "int64", "uint8", "bool")


def leaf_dtype(space: gymnasium.spaces.Space) -> np.dtype:
    """The dtype a Box/Discrete value travels as (Discrete always as int64)."""
    if isinstance(space, gymnasium.spaces.Discrete):
        return np.dtype(np.int64)
    if isinstance(space, gymnasium.spaces.Box):
        dtype = np.dtype(space.dtype)
        if dtype.name not in SUPPORTED_DTYPES:
            raise TypeError(f"Box dtype {dtype.name} is not supported; expected one of {SUPPORTED_DTYPES}")
        return dtype
    raise TypeError(f"space {space} is not supported here; expected Box or Discrete")


def _bound_list(values: np.ndarray) -> list[float]:
    flat = np.asarray(values, dtype=np.float64).reshape(-1)
    if flat.size and np.all(flat == flat[0]):
        return [float(flat[0])]
    return [float(v) for v in flat]


def space_to_spec(space: gymnasium.spaces.Space) -> dict[str, Any]:
    """Describe a gymnasium space as a spec dict (see module docstring)."""
    if isinstance(space, gymnasium.spaces.Dict):
        return {"dict": [(str(k), space_to_spec(s)) for k, s in space.spaces.items()]}
    if isinstance(space, gymnasium.spaces.Discrete):
        return {"discrete": {"n": int(space.n), "start": int(space.start)}}
    if isinstance(space, gymnasium.spaces.Box):
        return {
            "box": {
                "dtype": leaf_dtype(space).name,
                "shape": [int(d) for d in space.shape],
                "low": _bound_list(space.low),
                "high": _bound_list(space.high),
            }
        }
    raise TypeError(f"space {space} is not supported; expected Box, Discrete or Dict")


def spec_to_space(spec: dict[str, Any]) -> gymnasium.spaces.Space:
    """Rebuild a gymnasium space from a spec dict."""
    if "dict" in spec:
        # A sequence of pairs keeps the wire order (a plain dict would be re-sorted).
        return gymnasium.spaces.Dict([(k, spec_to_space(s)) for k, s in spec["dict"]])
    if "discrete" in spec:
        return gymnasium.spaces.Discrete(spec["discrete"]["n"], start=spec["discrete"]["start"])
    box = spec["box"]
    dtype = np.dtype(box["dtype"])
    shape = tuple(box["shape"])

    def bound(values: Sequence[float]) -> np.ndarray:
        arr = np.asarray(values, dtype=np.float64)
        arr = np.full(shape, arr[0]) if arr.size == 1 else arr.reshape(shape)
        if dtype.kind in "iub":
            info = np.iinfo(dtype) if dtype.kind != "b" else None
            lo, hi = (0, 1) if info is None else (info.min, info.max)
            arr = np.clip(np.nan_to_num(arr, posinf=hi, neginf=lo), lo, hi)
        return arr.astype(dtype)

    return gymnasium.spaces.Box(bound(box["low"]), bound(box["high"]), shape=shape, dtype=dtype)


# ---------------------------------------------------------------- shipped envs
SHIPPED_ENV_IDS: tuple[str, ...] = (
    "dst",
    "humanoid-mocap",
    "humanoid-run",
    "pendulum",
    "sawyer-peg",
    "shadow-orient",
    "shadow-touch",
    "shadow-turn",
)
"""The keys of `env_server.envs.REGISTRY`, in its order (tests/test_layout.py checks they
agree): a shipped env is a file in envs/, a line there and its id here."""


# ---------------------------------------------------------------- token files
MIN_TOKEN_CHARS = 16


class SecurityConfigError(ValueError):
    """A token file, TLS file or bind address the server refuses to start with (a client's
    `token_file=` raises it for a bad token file too)."""


def parse_token_lines(text: str, source: str) -> list[tuple[str, str]]:
    """(name, token) for every token line of a token file's `text` (see the module doc)."""
    entries: list[tuple[str, str]] = []
    for number, raw in enumerate(text.splitlines(), start=1):
        line = raw.strip()
        if not line or line.startswith("#"):
            continue
        name, sep, token = line.rpartition(":")
        if not sep:
            name = f"token-{number}"
        where = f"{source} line {number}"
        if not name or any(c.isspace() for c in name):
            raise SecurityConfigError(f"{where}: expected 'name:token' with a name without spaces, got an empty name")
        if len(token) < MIN_TOKEN_CHARS or not token.isascii() or not token.isprintable() or " " in token:
            raise SecurityConfigError(
                f"{where}: expected a token of at least {MIN_TOKEN_CHARS} printable ASCII characters without "
                f"spaces or ':', got one of {len(token)} characters"
            )
        entries.append((name, token))
    return entries
