"""What a Session's Reset and Step return, and the dtypes an info value is kept in.

The results hold views into the session's preallocated buffers, valid until its next
call; wire.py encodes them.
"""

from __future__ import annotations

import dataclasses
from typing import Any

import numpy as np

from env_server import spaces


@dataclasses.dataclass
class EpisodeEnd:
    """An episode that ended in a Step, with its server-side returns."""

    env_index: int
    episode_return: np.ndarray  # float64 [K]
    discounted_return: np.ndarray  # float64 [K]
    length: int
    terminated: bool
    truncated: bool


@dataclasses.dataclass
class StepResult:
    """One batch step; arrays are views into session buffers, valid until the next call."""

    observation: list[tuple[spaces.Leaf, np.ndarray]]  # [B, ...] per leaf
    reward: np.ndarray  # float32 [B, K]
    terminated: np.ndarray  # bool [B]
    truncated: np.ndarray  # bool [B]
    info: list[tuple[str, np.ndarray]]  # [B, ...] per requested key
    episodes: list[EpisodeEnd]
    final_observation: list[tuple[spaces.Leaf, np.ndarray]]  # [len(episodes), ...] per leaf


@dataclasses.dataclass
class ResetResult:
    observation: list[tuple[spaces.Leaf, np.ndarray]]  # [n, ...] per leaf
    info: list[tuple[str, np.ndarray]]


def info_array(value: Any) -> np.ndarray:
    """An info value as the wire carries it: float32 or float64, bool, or int64."""
    arr = np.asarray(value)
    if arr.dtype.kind == "f":
        return arr.astype(np.float64 if arr.dtype == np.float64 else np.float32)
    if arr.dtype.kind == "b":
        return arr.astype(np.bool_)
    if arr.dtype.kind in "iu":
        return arr.astype(np.int64)
    raise TypeError(f"info value of dtype {arr.dtype} is not numeric")
