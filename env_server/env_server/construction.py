"""Building a session: `make_session` checks a Make's options and wraps the instances
`build_instances` builds, in the server process or in worker processes, with the checks
every env must pass before a client sees it (unique objective names, servable spaces,
info keys, closed-form action-norm bounds), in a Session.
"""

from __future__ import annotations

import functools
import math
import threading
from collections.abc import Mapping, Sequence
from typing import Any

import gymnasium

from env_server import shared
from env_server.errors import ConstructorError, Internal, InvalidArgument, quote
from env_server.instances import InstanceFailure, Instances, LocalInstances, TaskInfo, build_tasks
from env_server.registry import EnvEntry, construct
from env_server.reward_scale import REWARD_SCALE, check_reward_scale
from env_server.session import DEFAULT_DISCOUNT, Session
from env_server.shared import Autoreset
from env_server.task import ClosedForm, Objective, action_norm_bounds
from env_server.workers import WorkerInstances


def make_session(
    entry: EnvEntry,
    num_envs: int,
    kwargs: Mapping[str, Any],
    *,
    seed: int | None = None,
    autoreset: Autoreset = Autoreset.SAME_STEP,
    discount: float | None = None,
    info_keys: Sequence[str] = (),
    session_id: str | None = None,
    num_workers: int = 0,
    cancel: threading.Event | None = None,
) -> Session:
    """Validate the request, construct num_envs Tasks and wrap them in a Session.

    num_workers = 0 keeps the Tasks in this process; N >= 1 splits them into N + 1
    shares, one kept here and one per worker process, stepped in parallel. May take
    seconds for heavy simulators; the server runs it in a thread, and sets `cancel` when
    the client goes away (construction stops before the next instance).
    """
    if num_envs < 1:
        raise InvalidArgument(f"num_envs: expected >= 1, got {num_envs}")
    discount = DEFAULT_DISCOUNT if discount is None else float(discount)
    if not (math.isfinite(discount) and 0.0 <= discount <= 1.0):
        raise InvalidArgument(f"discount: expected 0 <= discount <= 1, got {discount}")
    kwargs = dict(kwargs)
    reward_scale = check_reward_scale(kwargs.pop(REWARD_SCALE, None))
    instances = build_instances(entry, kwargs, num_envs, num_workers, info_keys, cancel)
    try:
        return Session(
            entry.env_id,
            instances,
            seed=seed,
            autoreset=autoreset,
            discount=discount,
            info_keys=info_keys,
            session_id=session_id,
            reward_scale=reward_scale,
        )
    except BaseException:
        instances.close()
        raise


def build_instances(
    entry: EnvEntry,
    kwargs: Mapping[str, Any],
    num_envs: int,
    num_workers: int,
    info_keys: Sequence[str],
    cancel: threading.Event | None = None,
) -> Instances:
    """Construct num_envs instances of `entry` (in num_workers worker processes too) and check them.

    Errors name the field: a bad num_workers or info key is InvalidArgument, a raising
    constructor a ConstructorError naming the env and its package. Nothing is left
    running on failure.
    """
    if isinstance(entry.factory, type):
        # Reject unknown info keys before paying for a simulator load when the class declares them.
        _check_info_keys(entry.env_id, tuple(entry.factory.info_keys), info_keys)
    if not 0 <= num_workers < num_envs:
        raise InvalidArgument(
            f"num_workers: expected 0 (no worker processes) to num_envs - 1 = {num_envs - 1} "
            f"(the server steps one share itself), got {num_workers}"
        )
    build = functools.partial(construct, entry, kwargs)
    try:
        if num_workers:
            instances: Instances = WorkerInstances(build, num_envs, num_workers, cancel)
        else:
            instances = LocalInstances(list(build_tasks(build, range(num_envs), cancel).values()))
    except InstanceFailure as failure:
        # Logged by Registry.note_make, once per reason, however often clients retry.
        raise ConstructorError(
            f"env {entry.env_id} (package {entry.package}): constructor raised {failure.error}", failure.error
        ) from failure
    try:
        _check_task(entry.env_id, instances.info, info_keys)
    except BaseException:
        instances.close()
        raise
    return instances


def _check_info_keys(env_id: str, available: tuple[str, ...], info_keys: Sequence[str]) -> None:
    unknown = [key for key in info_keys if key not in available]
    if unknown:
        raise InvalidArgument(f"info_keys: env '{env_id}' cannot report {quote(unknown)}; available: {list(available)}")


def _check_task(env_id: str, task: TaskInfo, info_keys: Sequence[str]) -> None:
    _check_info_keys(env_id, task.info_keys, info_keys)
    names = [o.name for o in task.objectives]
    if not names or len(set(names)) != len(names):
        raise Internal(f"env '{env_id}': objectives must be non-empty with unique names, got {names}")
    try:
        shared.space_to_spec(task.observation_space)
        shared.leaf_dtype(task.action_space)
    except TypeError as exc:
        raise InvalidArgument(f"env_id: env '{env_id}' cannot be served: {exc}") from exc
    for objective in task.objectives:
        if objective.closed_form is ClosedForm.ACTION_NORM:
            _check_action_norm(env_id, objective, task.action_space)


def _check_action_norm(env_id: str, objective: Objective, action_space: gymnasium.spaces.Space) -> None:
    """An objective declared `ClosedForm.ACTION_NORM` has a Box action space and exactly the
    bounds of -scale * ||a||_2 over it, so a learner that computes it gets the env's reward."""
    where = f"env '{env_id}' objective {objective.name!r} (closed_form = action_norm)"
    if not isinstance(action_space, gymnasium.spaces.Box):
        raise Internal(f"{where}: expected a Box action space, got {action_space}")
    want = tuple(objective.scale * bound + 0.0 for bound in action_norm_bounds(action_space))  # + 0.0: no -0

    def same(a: float, b: float) -> bool:
        return a == b or math.isclose(a, b, rel_tol=1e-6, abs_tol=1e-9)

    if not (same(objective.min, want[0]) and same(objective.max, want[1])):
        raise Internal(
            f"{where}: expected min, max = {want[0]:.9g}, {want[1]:.9g} (-||a||_2 over the action "
            f"space {action_space}), got {objective.min:.9g}, {objective.max:.9g}"
        )
