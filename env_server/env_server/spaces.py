"""The server's side of the spaces: observation leaves and action validation.

No gRPC here. The spaces <-> spec dicts mapping, which the client uses too, is in
shared.py.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence

import gymnasium
import numpy as np

from env_server.errors import InvalidArgument, quote
from env_server.shared import leaf_dtype


@dataclasses.dataclass(frozen=True)
class Leaf:
    """One array of a (possibly nested) observation: its wire name and per-instance layout."""

    name: str  # "" for a non-Dict space, nested Dict keys joined with "."
    path: tuple[str, ...]  # keys to walk from the observation to this leaf
    dtype: np.dtype
    shape: tuple[int, ...]


def leaves(space: gymnasium.spaces.Space, _prefix: tuple[str, ...] = ()) -> list[Leaf]:
    """Flatten a Box/Discrete/Dict tree into leaves in Dict order."""
    if isinstance(space, gymnasium.spaces.Dict):
        out: list[Leaf] = []
        for key, sub in space.spaces.items():
            out.extend(leaves(sub, _prefix + (str(key),)))
        return out
    shape = () if isinstance(space, gymnasium.spaces.Discrete) else tuple(int(d) for d in space.shape)
    return [Leaf(".".join(_prefix), _prefix, leaf_dtype(space), shape)]


def _fmt_index(index: tuple[int, ...]) -> str:
    return "(" + ", ".join(str(int(i)) for i in index) + ("," if len(index) == 1 else "") + ")"


class ActionValidator:
    """Checks a batch of actions [B, *action_shape] against one action space, vectorised.

    Built once per session so the per-step cost is one dtype compare, one shape compare
    and a few numpy reductions over the whole batch: two (min and max) when every
    element shares finite bounds, which matters because right after a simulator step
    the caches are cold and each numpy call costs microseconds.
    """

    def __init__(self, space: gymnasium.spaces.Space, num_envs: int) -> None:
        self.space = space
        self.num_envs = num_envs
        self.dtype = leaf_dtype(space)
        self.dtype_name = self.dtype.name  # dtype.name is a Python property costing microseconds
        self.discrete = isinstance(space, gymnasium.spaces.Discrete)
        item_shape = () if self.discrete else tuple(int(d) for d in space.shape)
        self.shape = (num_envs, *item_shape)
        self.nbytes = math.prod(self.shape) * self.dtype.itemsize
        if self.discrete:
            self.low = np.int64(space.start)
            self.high = np.int64(space.start + space.n - 1)
            self._check_bounds = True
            self._check_finite = False
        else:
            self.low = np.asarray(space.low)
            self.high = np.asarray(space.high)
            self._check_finite = self.dtype.kind == "f"
            self._check_bounds = bool(np.isfinite(self.low).any() or np.isfinite(self.high).any())
        # With every bound finite and shared by all elements, min and max settle validity
        # (NaN propagates through both and fails the comparison); else check_values' passes.
        low, high = np.unique(self.low), np.unique(self.high)
        shared = low.size == high.size == 1 and np.isfinite(low[0]) and np.isfinite(high[0])
        self._range = (low[0], high[0]) if shared and self.nbytes else None

    def decode(self, dtype: str, shape: Sequence[int], data: bytes) -> np.ndarray:
        """Validate wire pieces and return a read-only [B, ...] view of `data`.

        Raises InvalidArgument naming the field, the expectation and what arrived.
        """
        if dtype != self.dtype_name:
            raise InvalidArgument(f"action: expected dtype {self.dtype_name}, got {dtype}")
        if tuple(shape) != self.shape:
            raise InvalidArgument(
                f"action: expected shape {list(self.shape)} (num_envs={self.num_envs}, "
                f"action space {self.space}), got {quote(list(shape))}"
            )
        if len(data) != self.nbytes:
            raise InvalidArgument(
                f"action: expected {self.nbytes} data bytes for shape {list(self.shape)} "
                f"{self.dtype.name}, got {len(data)}"
            )
        actions = np.frombuffer(data, dtype=self.dtype).reshape(self.shape)
        if self._range is None or not (
            self._range[0] <= np.minimum.reduce(actions, axis=None)
            and np.maximum.reduce(actions, axis=None) <= self._range[1]
        ):
            self.check_values(actions)
        return actions

    def check_values(self, actions: np.ndarray) -> None:
        """NaN/inf and bounds, one pass each over the batch; diagnostics only on failure."""
        if self._check_finite and not np.isfinite(actions).all():
            index = tuple(np.argwhere(~np.isfinite(actions))[0])
            raise InvalidArgument(
                f"action: env {index[0]} element {_fmt_index(index[1:])} is {actions[index]}; expected finite values"
            )
        if self._check_bounds and not ((actions >= self.low) & (actions <= self.high)).all():
            bad = (actions < self.low) | (actions > self.high)
            index = tuple(np.argwhere(bad)[0])
            value = actions[index]
            if self.discrete:
                raise InvalidArgument(
                    f"action: env {index[0]} = {value} is outside {self.space}: "
                    f"expected {self.low} <= action <= {self.high}"
                )
            low = np.broadcast_to(self.low, self.shape[1:])[index[1:]]
            high = np.broadcast_to(self.high, self.shape[1:])[index[1:]]
            raise InvalidArgument(
                f"action: env {index[0]} element {_fmt_index(index[1:])} = {value} is outside "
                f"the Box bounds: expected {low} <= action <= {high}"
            )
