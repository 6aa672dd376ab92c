"""A Session: B Task instances stepped as one batch, with autoreset and episode accounting.

Where the instances run (in this process, or spread over worker processes) is the
business of instances.py, workers.py and construction.py; a Session hands them one batch of steps and resets per call.

This is the whole server minus gRPC: validation, seeding, autoreset, time limits and
server-side episode returns live here, so tools/bench_inprocess.py measures exactly what
the server does per Step except the transport. No grpc imports; errors are errors.py
types. construction.make_session builds a Session for a Make.

Buffers are preallocated per session and reused by every Step: a StepResult
(results.py) holds views into them that stay valid until the session's next call.
"""

from __future__ import annotations

import logging
import time
import uuid
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from env_server import spaces
from env_server.errors import FailedPrecondition, Internal, InvalidArgument, SimulatorError, quote
from env_server.instances import InstanceFailure, Instances, LocalInstances, Outcomes, RenderBatch
from env_server.results import EpisodeEnd, ResetResult, StepResult, info_array
from env_server.reward_scale import REWARD_SCALE, scaled
from env_server.shared import Autoreset, SessionSpec
from env_server.task import Objective, Task

log = logging.getLogger(__name__)

# np.count_nonzero minus its Python wrapper: the hot path tests bool buffers with it
# because ndarray.any() and np.count_nonzero each add a Python-level call.
count_nonzero = np.core.multiarray.count_nonzero

DEFAULT_DISCOUNT = 0.99


SEED_LIMIT = 2**32
"""Instance seeds must be below this: dm_control and NumPy's legacy RandomState take 32-bit
seeds, so one range for every env keeps a seed's meaning the same across envs."""


def check_seed_range(field: str, seeds: Sequence[int]) -> None:
    """Refuses instance seeds outside [0, 2**32) before any instance is touched."""
    bad = [s for s in seeds if not 0 <= s < SEED_LIMIT]
    if bad:
        raise InvalidArgument(
            f"{field}: expected instance seeds in [0, 2**32) (a seed s for B instances uses s .. s+B-1), got {bad[0]}"
        )


class Session:
    """B instances of one Task, stepped together."""

    def __init__(
        self,
        env_id: str,
        instances: Instances,
        *,
        seed: int | None = None,
        autoreset: Autoreset = Autoreset.SAME_STEP,
        discount: float = DEFAULT_DISCOUNT,
        info_keys: Sequence[str] = (),
        session_id: str | None = None,
        reward_scale: Mapping[str, float] | None = None,
    ) -> None:
        self.id = session_id or uuid.uuid4().hex
        self.env_id = env_id
        self._instances = instances
        first = instances.info
        b = instances.num_envs
        reward_scale = dict(reward_scale or {})
        names = [o.name for o in first.objectives]
        unknown = sorted(set(reward_scale) - set(names))
        if unknown:
            raise InvalidArgument(
                f"kwargs_json.{REWARD_SCALE}: expected objective names of {env_id}, one of {names}, "
                f"got {quote(unknown)}"
            )
        self.objectives: tuple[Objective, ...] = tuple(
            scaled(o, reward_scale[o.name]) if o.name in reward_scale else o for o in first.objectives
        )
        # None when nothing is scaled: the hot path then skips the multiply.
        self._scale = np.array([o.scale for o in self.objectives], np.float32) if reward_scale else None
        self._k = len(self.objectives)
        max_steps = first.max_episode_steps or 0
        self.spec = SessionSpec(
            env_id=env_id,
            num_envs=b,
            observation_space=first.observation_space,
            action_space=first.action_space,
            objectives=self.objectives,
            max_episode_steps=int(max_steps),
            autoreset=autoreset,
            discount=float(discount),
            info_keys=first.info_keys,
        )
        self._max_steps = int(max_steps)
        self._discount = float(discount)
        self._seed = seed
        self._info_keys = tuple(info_keys)
        self.validator = spaces.ActionValidator(first.action_space, b)
        self._discrete = self.validator.discrete
        if not self._discrete:
            self._actions = np.zeros(self.validator.shape, self.validator.dtype)
            self._all_rows = list(enumerate(self._actions))  # (index, action view) per instance
        self.leaves = spaces.leaves(first.observation_space)
        self._single_leaf = len(self.leaves) == 1 and not self.leaves[0].path
        self._obs = [np.zeros((b, *leaf.shape), leaf.dtype) for leaf in self.leaves]
        self._obs_out = list(zip(self.leaves, self._obs))
        self._reward = np.zeros((b, self._k), np.float32)
        self._terminated = np.zeros(b, np.bool_)
        self._truncated = np.zeros(b, np.bool_)
        self._live = np.ones(b, np.bool_)
        self._ep_len = np.zeros(b, np.int64)
        self._ep_ret = np.zeros((b, self._k), np.float64)
        self._ep_disc = np.zeros((b, self._k), np.float64)
        self._disc_pow = np.ones(b, np.float64)
        self._disc_col = self._disc_pow[:, None]  # a view, so the hot path skips the indexing
        self._disc_reward = np.zeros((b, self._k), np.float64)
        self._done = np.zeros(b, np.bool_)
        self._info: dict[str, np.ndarray] = {}
        self._seeded = np.zeros(b, np.bool_)  # has had its first reset
        self._needs_reset = np.ones(b, np.bool_)
        self._ended = np.zeros(b, np.bool_)  # NEXT_STEP / DISABLED: episode over, not yet reset
        self._failure = ""
        self.closed = False
        self.last_used = time.monotonic()

    # ------------------------------------------------------------------ helpers
    @property
    def num_envs(self) -> int:
        return self._instances.num_envs

    @property
    def tasks(self) -> tuple[Task, ...]:
        """The B Task instances of an in-process session (for benchmarks and tests)."""
        if not isinstance(self._instances, LocalInstances):
            raise TypeError(f"session {self.id} runs its instances in worker processes")
        return self._instances.tasks

    def _write_obs(self, i: int, obs: Any, bufs: Sequence[np.ndarray]) -> None:
        if self._single_leaf:
            bufs[0][i] = obs
            return
        for leaf, buf in zip(self.leaves, bufs):
            value = obs
            for key in leaf.path:
                value = value[key]
            buf[i] = value

    def _run(self, steps: Sequence[tuple[int, Any]], resets: Sequence[tuple[int, int | None]]) -> Outcomes:
        """One batch on the instances; the reset ones begin a new episode."""
        try:
            out = self._instances.run(steps, resets)
        except InstanceFailure as failure:
            self._needs_reset[:] = True
            self._failure = (
                f" (a simulator error in {failure.what} of instance {failure.index} left the session "
                "needing a full Reset)"
            )
            log.error(
                "env %s session %s instance %d: %s raised %s",
                self.env_id,
                self.id,
                failure.index,
                failure.what,
                failure.error,
                exc_info=failure.__cause__,
            )
            raise SimulatorError(
                f"env {self.env_id} session {self.id} instance {failure.index}: {failure.error}"
            ) from failure
        for i, _ in resets:
            self._seeded[i] = True
            self._needs_reset[i] = False
            self._ended[i] = False
            self._ep_len[i] = 0
            self._ep_ret[i] = 0.0
            self._ep_disc[i] = 0.0
            self._disc_pow[i] = 1.0
        return out

    def _collect_info(self, i: int, info: Mapping[str, Any]) -> None:
        for key in self._info_keys:
            if key not in info:
                continue
            value = info_array(info[key])
            buf = self._info.get(key)
            if buf is None:
                buf = self._info[key] = np.zeros((self.num_envs, *value.shape), value.dtype)
            buf[i] = value

    # ------------------------------------------------------------------ API
    def reset(self, env_indices: Sequence[int] = (), seeds: Sequence[int] = ()) -> ResetResult:
        """Reset the given instances (all when empty); see ResetRequest for the seed rules."""
        self.last_used = time.monotonic()
        b = self.num_envs
        indices = list(env_indices) if len(env_indices) else list(range(b))
        for i in indices:
            if not 0 <= i < b:
                raise InvalidArgument(f"env_indices: expected 0 <= index < {b} (num_envs={b}), got {i}")
        if len(set(indices)) != len(indices):
            raise InvalidArgument(f"env_indices: expected distinct indices, got {quote(indices)}")
        n = len(indices)
        if len(seeds) == 0:
            per = [self._seed + i if self._seed is not None and not self._seeded[i] else None for i in indices]
        elif len(seeds) == 1:
            per = [int(seeds[0]) + pos for pos in range(n)]
        elif len(seeds) == n:
            per = [int(s) for s in seeds]
        else:
            raise InvalidArgument(f"seeds: expected 0, 1 or {n} values (one per reset instance), got {len(seeds)}")
        check_seed_range("seeds", [s for s in per if s is not None])
        bufs = [np.zeros((n, *leaf.shape), leaf.dtype) for leaf in self.leaves]
        outcomes = self._run((), list(zip(indices, per))).resets
        infos = [out.info for out in outcomes]
        for pos, out in enumerate(outcomes):
            self._write_obs(pos, out.observation, bufs)
        if not self._needs_reset.any():
            self._failure = ""
        info_out = []
        for key in self._info_keys:
            values = [info_array(info[key]) for info in infos if key in info]
            if not values:
                continue
            arr = np.zeros((n, *values[0].shape), values[0].dtype)
            for pos, info in enumerate(infos):
                if key in info:
                    arr[pos] = info_array(info[key])
            info_out.append((key, arr))
        return ResetResult(list(zip(self.leaves, bufs)), info_out)

    def step(self, dtype: str, shape: Sequence[int], data: bytes) -> StepResult:
        """Validate one action per instance (wire pieces) and step every instance."""
        self.last_used = time.monotonic()
        if count_nonzero(self._needs_reset):
            raise FailedPrecondition(f"session {self.id}: call Reset before Step{self._failure}")
        actions = self.validator.decode(dtype, shape, data)
        return self.step_actions(actions)

    def step_actions(self, actions: np.ndarray) -> StepResult:
        """Step with an already validated [B, ...] action array."""
        autoreset = self.spec.autoreset
        if autoreset is Autoreset.DISABLED and self._ended.any():
            ended = np.flatnonzero(self._ended).tolist()
            raise FailedPrecondition(
                f"session {self.id}: instances {ended} ended their episode; call Reset with "
                f"env_indices={ended} before Step (autoreset mode DISABLED)"
            )
        if self._discrete:
            rows: list[tuple[int, Any]] = list(enumerate(actions.tolist()))
        else:
            np.copyto(self._actions, actions)
            rows = self._all_rows
        for buf in self._info.values():
            buf.fill(0)
        next_step_reset = autoreset is Autoreset.NEXT_STEP and self._ended.any()
        resets: list[tuple[int, int | None]] = []
        if next_step_reset:
            # Instances whose episode ended last Step reset now instead of stepping.
            np.logical_not(self._ended, out=self._live)
            resets = [(i, None) for i in np.flatnonzero(self._ended).tolist()]
            rows = [row for row in rows if self._live[row[0]]]
        outcomes = self._run(rows, resets)
        self._write_resets(resets, outcomes.resets)
        self._write_steps(rows, outcomes.steps)
        if self._scale is not None:
            self._reward *= self._scale
        self._count_step(next_step_reset)
        episodes, finals = self._end_episodes(autoreset)
        info = [(key, self._info[key]) for key in self._info_keys if key in self._info]
        return StepResult(self._obs_out, self._reward, self._terminated, self._truncated, info, episodes, finals)

    def _write_resets(self, resets: Sequence[tuple[int, int | None]], outcomes: Sequence[Any]) -> None:
        """NEXT_STEP's resets: a new first observation, no reward, not done."""
        for (i, _), reset in zip(resets, outcomes):
            self._write_obs(i, reset.observation, self._obs)
            self._reward[i] = 0.0
            self._terminated[i] = self._truncated[i] = False
            if self._info_keys:
                self._collect_info(i, reset.info)

    def _write_steps(self, rows: Sequence[tuple[int, Any]], outcomes: Sequence[Any]) -> None:
        reward, terminated, truncated, k = self._reward, self._terminated, self._truncated, self._k
        for (i, _), out in zip(rows, outcomes):
            r = out.reward
            if getattr(r, "shape", None) != (k,):
                r = np.asarray(r, np.float32)
                if r.shape != (k,):
                    task = self._instances.info.task_class
                    self._needs_reset[:] = True
                    self._failure = f" (task {task} returned a malformed reward)"
                    raise Internal(
                        f"env {self.env_id} session {self.id} instance {i}: task {task} "
                        f"returned a reward of shape {list(r.shape)}, expected [{k}] (one entry per "
                        f"objective: {[o.name for o in self.objectives]})"
                    )
            reward[i] = r
            terminated[i] = out.terminated
            truncated[i] = out.truncated
            self._write_obs(i, out.observation, self._obs)
            if self._info_keys:
                self._collect_info(i, out.info)

    def _count_step(self, next_step_reset: bool) -> None:
        """The step's reward into the episode returns, and the time limit's truncations."""
        reward, terminated, truncated = self._reward, self._terminated, self._truncated
        if next_step_reset:
            self._account(self._live)
            terminated &= self._live
        else:
            # In place and into preallocated buffers: right after the simulator step the
            # caches are cold and every temporary costs microseconds.
            self._ep_len += 1
            self._ep_ret += reward
            np.multiply(self._disc_col, reward, out=self._disc_reward)
            self._ep_disc += self._disc_reward
            self._disc_pow *= self._discount
        if self._max_steps and np.maximum.reduce(self._ep_len) >= self._max_steps:
            truncated |= ~terminated & (self._ep_len >= self._max_steps)

    def _end_episodes(self, autoreset: Autoreset) -> tuple[list[EpisodeEnd], list[tuple[spaces.Leaf, np.ndarray]]]:
        """The records of the episodes this step ended and, under SAME_STEP, their last
        observations (the instances reset at once)."""
        episodes: list[EpisodeEnd] = []
        finals: list[tuple[spaces.Leaf, np.ndarray]] = []
        terminated, truncated = self._terminated, self._truncated
        done = np.logical_or(terminated, truncated, out=self._done)
        if not count_nonzero(done):
            return episodes, finals
        ended = np.flatnonzero(done)
        for i in ended.tolist():
            episodes.append(
                EpisodeEnd(
                    i,
                    self._ep_ret[i].copy(),
                    self._ep_disc[i].copy(),
                    int(self._ep_len[i]),
                    bool(terminated[i]),
                    bool(truncated[i]),
                )
            )
        if autoreset is Autoreset.SAME_STEP:
            finals = [(leaf, buf[ended]) for leaf, buf in zip(self.leaves, self._obs)]
            ended_list = ended.tolist()
            for i, out in zip(ended_list, self._run((), [(i, None) for i in ended_list]).resets):
                self._write_obs(i, out.observation, self._obs)
        else:
            self._ended[ended] = True
        return episodes, finals

    @property
    def cameras(self) -> tuple[str, ...]:
        return self._instances.info.cameras

    @property
    def render_fps(self) -> float:
        return self._instances.info.render_fps

    def render_indices(self, env_indices: Sequence[int]) -> list[int]:
        """The instances a Render asks for (all when empty), checked like Reset's."""
        b = self.num_envs
        indices = list(env_indices) if len(env_indices) else list(range(b))
        for i in indices:
            if not 0 <= i < b:
                raise InvalidArgument(f"env_indices: expected 0 <= index < {b} (num_envs={b}), got {i}")
        return indices

    def render(self, indices: Sequence[int], width: int, height: int, camera: str) -> np.ndarray:
        """uint8 [len(indices), height, width, 3]: each instance's current frame.

        Rendering leaves the episodes as they are, so a failed frame does not need a Reset.
        """
        self.last_used = time.monotonic()
        info = self._instances.info
        if not info.renders:
            raise FailedPrecondition(f"env {self.env_id}: its task {info.task_class} has no renderer (Task.render)")
        if camera and camera not in info.cameras:
            raise InvalidArgument(
                f'camera: env {self.env_id} has no camera {quote(camera)}; expected "" (the default view) '
                f"or one of {list(info.cameras)}"
            )
        unreset = [i for i in indices if not self._seeded[i]]
        if unreset:
            raise FailedPrecondition(f"session {self.id}: call Reset before Render (instances {quote(unreset)})")
        try:
            frames = self._instances.render(RenderBatch(list(indices), width, height, camera))
        except InstanceFailure as failure:
            log.error(
                "env %s session %s instance %d: render raised %s",
                self.env_id,
                self.id,
                failure.index,
                failure.error,
                exc_info=failure.__cause__,
            )
            raise SimulatorError(
                f"env {self.env_id} session {self.id} instance {failure.index}: render raised {failure.error}"
            ) from failure
        out = np.empty((len(frames), height, width, 3), np.uint8)
        for pos, frame in enumerate(frames):
            frame = np.asarray(frame)
            if frame.shape != (height, width, 3) or frame.dtype != np.uint8:
                raise Internal(
                    f"env {self.env_id} instance {indices[pos]}: task {info.task_class} rendered "
                    f"{frame.dtype} {list(frame.shape)}, expected uint8 [{height}, {width}, 3]"
                )
            out[pos] = frame
        return out

    def _account(self, live: np.ndarray) -> None:
        self._ep_len[live] += 1
        r = self._reward[live]
        self._ep_ret[live] += r
        self._ep_disc[live] += self._disc_pow[live, None] * r
        self._disc_pow[live] *= self._discount

    def close(self) -> None:
        """Close every instance; errors are logged, never raised (closing must not fail)."""
        if self.closed:
            return
        self.closed = True
        self._instances.close()
