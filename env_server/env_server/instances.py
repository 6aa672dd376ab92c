"""Where a session's B Task instances live: the interface, and the instances that live in
the server process (`LocalInstances`); worker processes are workers.py, building and
checking instances construction.py.

A Session (session.py) owns validation, autoreset and episode accounting; what it asks
of its instances is one batch at a time: step these instances with these actions, reset
those with these seeds. `LocalInstances` runs the batch in a loop in the calling process.
"""

from __future__ import annotations

import abc
import dataclasses
import logging
import os
import threading
from collections.abc import Callable, Iterable, Mapping, Sequence
from typing import Any

import gymnasium

from env_server.errors import Cancelled, EnvServerError
from env_server.task import Objective, StepOutcome, Task

log = logging.getLogger(__name__)

#: How long a closing worker gets to close its Tasks before it is killed.
CLOSE_TIMEOUT_S = 5.0
#: Worker processes one session may ask for unless the server says otherwise: one per CPU.
DEFAULT_MAX_WORKERS = os.cpu_count() or 1


@dataclasses.dataclass(frozen=True)
class TaskInfo:
    """What a Session needs of its Tasks, read from the first instance."""

    task_class: str
    observation_space: gymnasium.spaces.Space
    action_space: gymnasium.spaces.Space
    objectives: tuple[Objective, ...]
    max_episode_steps: int | None
    info_keys: tuple[str, ...]
    cameras: tuple[str, ...]
    renders: bool  # the Task class implements render
    render_fps: float

    @classmethod
    def of(cls, task: Task) -> TaskInfo:
        return cls(
            type(task).__name__,
            task.observation_space,
            task.action_space,
            tuple(task.objectives),
            task.max_episode_steps,
            tuple(task.info_keys),
            tuple(task.cameras),
            type(task).render is not Task.render,
            float(task.render_fps),
        )


@dataclasses.dataclass
class ResetOutcome:
    """What one instance returns from one reset."""

    observation: Any
    info: dict[str, Any]


@dataclasses.dataclass
class Outcomes:
    """A batch's results, aligned with the batch's `steps` and `resets` lists."""

    steps: list[StepOutcome]
    resets: list[ResetOutcome]


@dataclasses.dataclass(frozen=True)
class RenderBatch:
    """Frames of these instances, all of one size and camera."""

    indices: list[int]
    width: int
    height: int
    camera: str


class InstanceFailure(Exception):
    """Instance `index` raised (or its worker died) in `what` ("step", "reset" or "render").

    `error` is "<ExceptionType>: <message>"; the exception itself may live in another
    process. The Session turns this into a SimulatorError naming env, session and instance.
    """

    def __init__(self, index: int, what: str, error: str) -> None:
        super().__init__(f"instance {index}: {what} raised {error}")
        self.index = index
        self.what = what
        self.error = error

    def __reduce__(self) -> tuple[Any, ...]:  # travels from worker processes
        return (InstanceFailure, (self.index, self.what, self.error))

    @classmethod
    def of(cls, index: int, what: str, exc: BaseException) -> InstanceFailure:
        failure = cls(index, what, f"{type(exc).__name__}: {exc}")
        failure.__cause__ = exc
        return failure


class Instances(abc.ABC):
    """B Task instances that run batches of steps and resets."""

    info: TaskInfo
    num_envs: int

    @abc.abstractmethod
    def run(self, steps: Sequence[tuple[int, Any]], resets: Sequence[tuple[int, int | None]]) -> Outcomes:
        """Step each (index, action) and reset each (index, seed); an index appears at most once.

        Raises InstanceFailure naming the first instance to fail in the lowest failing
        share (later ones in that share may not have run), or an EnvServerError a Task
        raised itself. Either way the Session then needs a full Reset.
        """

    @abc.abstractmethod
    def render(self, batch: RenderBatch) -> list[Any]:
        """One frame per index of `batch`, in its order; failures as in `run`."""

    @abc.abstractmethod
    def close(self) -> None:
        """Close every instance; errors are logged, never raised."""


def run_tasks(
    tasks: Mapping[int, Task], steps: Sequence[tuple[int, Any]], resets: Sequence[tuple[int, int | None]]
) -> Outcomes:
    """The batch loop shared by LocalInstances and the worker processes."""
    out = Outcomes([], [])
    what, i = "reset", -1
    try:
        for i, seed in resets:
            obs, info = tasks[i].reset(seed=seed)
            out.resets.append(ResetOutcome(obs, info))
        what = "step"
        for i, action in steps:
            out.steps.append(tasks[i].step(action))
    except EnvServerError:
        raise
    except Exception as exc:
        raise InstanceFailure.of(i, what, exc) from exc
    return out


def render_tasks(tasks: Mapping[int, Task], batch: RenderBatch) -> list[Any]:
    """The render loop shared by LocalInstances and the worker processes."""
    frames = []
    i = -1
    try:
        for i in batch.indices:
            frames.append(tasks[i].render(batch.width, batch.height, batch.camera))
    except EnvServerError:
        raise
    except Exception as exc:
        raise InstanceFailure.of(i, "render", exc) from exc
    return frames


def build_tasks(
    build: Callable[[], Task], indices: Iterable[int], cancel: threading.Event | None = None
) -> dict[int, Task]:
    """One Task per index; a constructor's exception becomes an InstanceFailure ("construct").

    `cancel` set (the Make's client went away) stops the loop before the next
    construction and closes what was built: B slow constructors must not keep running
    for a client that is gone.
    """
    tasks: dict[int, Task] = {}
    try:
        for i in indices:
            check_cancel(cancel, len(tasks))
            try:
                tasks[i] = build()
            except EnvServerError:
                raise
            except Exception as exc:
                raise InstanceFailure.of(i, "construct", exc) from exc
    except BaseException:
        close_tasks(tasks)
        raise
    return tasks


def check_cancel(cancel: threading.Event | None, built: int) -> None:
    if cancel is not None and cancel.is_set():
        raise Cancelled(f"Make: the client went away; stopped building after {built} instances")


def close_tasks(tasks: Mapping[int, Task]) -> None:
    for i, task in tasks.items():
        try:
            task.close()
        except Exception:
            log.exception("instance %d: close raised", i)


class LocalInstances(Instances):
    """The instances as Task objects in this process, run one after another."""

    def __init__(self, tasks: Sequence[Task]) -> None:
        if not tasks:
            raise ValueError("a session needs at least one Task")
        self.tasks = tuple(tasks)
        self._by_index = dict(enumerate(self.tasks))
        self.num_envs = len(self.tasks)
        self.info = TaskInfo.of(self.tasks[0])

    def run(self, steps: Sequence[tuple[int, Any]], resets: Sequence[tuple[int, int | None]]) -> Outcomes:
        return run_tasks(self._by_index, steps, resets)

    def render(self, batch: RenderBatch) -> list[Any]:
        return render_tasks(self._by_index, batch)

    def close(self) -> None:
        close_tasks(self._by_index)
