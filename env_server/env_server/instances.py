"""Where a session's B Task instances live (the server process, or worker processes), and
how they are built and checked (`build_instances`).

A Session (session.py) owns validation, autoreset and episode accounting; what it asks
of its instances is one batch at a time: step these instances with these actions, reset
those with these seeds. `LocalInstances` runs the batch in a loop in the calling process;
`WorkerInstances` splits the B instances into contiguous shares, keeps the first and
hands one to each worker process, and runs all shares at the same time (the EnvPool /
SubprocVecEnv design). MuJoCo and the Python around it hold the GIL, so threads would
not run in parallel; processes do, at the price of a pipe round trip per worker per batch.

Workers are started with the "spawn" method: forking a process that runs gRPC's
threads is unsafe. A worker exits when its pipe closes, so a server that dies takes
its workers with it.
"""

from __future__ import annotations

import abc
import dataclasses
import functools
import logging
import math
import multiprocessing
import multiprocessing.connection
import os
import threading
from collections.abc import Callable, Iterable, Mapping, Sequence
from typing import Any

import gymnasium

from env_server import spaces
from env_server.errors import Cancelled, ConstructorError, EnvServerError, Internal, InvalidArgument, quote
from env_server.registry import EnvEntry, construct
from env_server.task import ClosedForm, Objective, StepOutcome, Task, action_norm_bounds

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


def _run_tasks(
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


def _render_tasks(tasks: Mapping[int, Task], batch: RenderBatch) -> list[Any]:
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


def _build_tasks(
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
            _check_cancel(cancel, len(tasks))
            try:
                tasks[i] = build()
            except EnvServerError:
                raise
            except Exception as exc:
                raise InstanceFailure.of(i, "construct", exc) from exc
    except BaseException:
        _close_tasks(tasks)
        raise
    return tasks


def _check_cancel(cancel: threading.Event | None, built: int) -> None:
    if cancel is not None and cancel.is_set():
        raise Cancelled(f"Make: the client went away; stopped building after {built} instances")


def _close_tasks(tasks: Mapping[int, Task]) -> None:
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
        return _run_tasks(self._by_index, steps, resets)

    def render(self, batch: RenderBatch) -> list[Any]:
        return _render_tasks(self._by_index, batch)

    def close(self) -> None:
        _close_tasks(self._by_index)


# ---------------------------------------------------------------------- workers
@dataclasses.dataclass(frozen=True)
class _Failed:
    """A worker's reply when its batch or its start raised: an exception that pickles."""

    error: EnvServerError | InstanceFailure


def _worker_main(conn: multiprocessing.connection.Connection, build: Callable[[], Task], indices: list[int]) -> None:
    """A worker process: construct its share of Tasks, then serve batches until the pipe closes."""
    tasks: dict[int, Task] = {}
    try:
        try:
            tasks = _build_tasks(build, indices)
        except EnvServerError as exc:
            conn.send(_Failed(exc))
            return
        except InstanceFailure as exc:
            # The traceback lives here only: log it before the failure crosses the pipe.
            log.error("instance %d: the constructor raised", exc.index, exc_info=exc.__cause__)
            conn.send(_Failed(exc))
            return
        conn.send(TaskInfo.of(tasks[indices[0]]))
        while True:
            try:
                batch = conn.recv()
            except (EOFError, OSError):
                return  # the server went away
            if batch is None:
                return
            try:
                if isinstance(batch, RenderBatch):
                    reply: Any = _render_tasks(tasks, batch)
                else:
                    reply = _run_tasks(tasks, *batch)
                conn.send(reply)
            except EnvServerError as exc:
                conn.send(_Failed(exc))
            except InstanceFailure as exc:
                # The traceback lives here only: log it before the failure crosses the pipe.
                log.error("instance %d: %s raised", exc.index, exc.what, exc_info=exc.__cause__)
                conn.send(_Failed(exc))
            except Exception as exc:  # e.g. an observation that does not pickle
                log.error("instances %s: the batch's reply failed", indices, exc_info=exc)
                conn.send(_Failed(InstanceFailure.of(indices[0], "step", exc)))
    finally:
        _close_tasks(tasks)
        conn.close()


@dataclasses.dataclass
class _Worker:
    process: multiprocessing.process.BaseProcess
    conn: multiprocessing.connection.Connection
    first: int  # its share is instances first .. first + count - 1
    count: int


class WorkerInstances(Instances):
    """The instances split into num_workers + 1 shares, all stepped at the same time.

    Share 0 stays in this process and runs while the worker processes run theirs: the
    server's CPU is awake anyway, and each process hop costs two wake-ups.
    """

    def __init__(
        self, build: Callable[[], Task], num_envs: int, num_workers: int, cancel: threading.Event | None = None
    ) -> None:
        """Start `num_workers` processes that each call `build()` for their share of `num_envs`.

        `build` must pickle (a functools.partial over a module-level callable does).
        Raises what a constructor raised (or InstanceFailure); no worker outlives a failed
        start. `cancel` stops the local share's loop and fails the start, whose cleanup ends
        the workers (a worker still building is killed after CLOSE_TIMEOUT_S).
        """
        if not 1 <= num_workers < num_envs:
            raise ValueError(f"num_workers must be in 1..{num_envs - 1}, got {num_workers}")
        self.num_envs = num_envs
        context = multiprocessing.get_context("spawn")
        self._workers: list[_Worker] = []
        self._local: dict[int, Task] = {}
        base, extra = divmod(num_envs, num_workers + 1)
        counts = [base + (share < extra) for share in range(num_workers + 1)]
        self._share = [share for share, count in enumerate(counts) for _ in range(count)]  # index -> share
        try:
            first = counts[0]
            for w, count in enumerate(counts[1:]):
                parent, child = context.Pipe()
                process = context.Process(
                    target=_worker_main,
                    args=(child, build, list(range(first, first + count))),
                    name=f"env_server-worker-{w}",
                    daemon=True,
                )
                process.start()
                child.close()
                self._workers.append(_Worker(process, parent, first, count))
                first += count
            self._local = _build_tasks(build, range(counts[0]), cancel)  # while the workers build theirs
            for worker in self._workers:
                _check_cancel(cancel, len(self._local))
                self._receive(worker, "construct")
        except BaseException:
            self.close()
            raise
        self.info = TaskInfo.of(self._local[0])

    @staticmethod
    def _died(worker: _Worker, what: str) -> InstanceFailure:
        worker.process.join(timeout=1.0)
        return InstanceFailure(
            worker.first,
            what,
            f"WorkerDied: the worker process for instances {worker.first}..{worker.first + worker.count - 1} "
            f"exited (exit code {worker.process.exitcode}); close this session and make a new one",
        )

    def _receive(self, worker: _Worker, what: str) -> Any:
        try:
            reply = worker.conn.recv()
        except (EOFError, OSError):
            raise self._died(worker, what) from None
        if isinstance(reply, _Failed):
            raise reply.error
        return reply

    def run(self, steps: Sequence[tuple[int, Any]], resets: Sequence[tuple[int, int | None]]) -> Outcomes:
        n = len(self._workers) + 1
        share_steps: list[list[tuple[int, Any]]] = [[] for _ in range(n)]
        share_resets: list[list[tuple[int, int | None]]] = [[] for _ in range(n)]
        for op in steps:
            share_steps[self._share[op[0]]].append(op)
        for op in resets:
            share_resets[self._share[op[0]]].append(op)
        what = ["step" if share_steps[s] else "reset" for s in range(n)]
        failures: dict[int, EnvServerError | InstanceFailure] = {}
        sent = []
        for s in range(1, n):
            if share_steps[s] or share_resets[s]:
                try:
                    self._workers[s - 1].conn.send((share_steps[s], share_resets[s]))
                    sent.append(s)
                except OSError:
                    failures[s] = self._died(self._workers[s - 1], what[s])
        replies: dict[int, Outcomes] = {}
        try:
            replies[0] = _run_tasks(self._local, share_steps[0], share_resets[0])
        except (EnvServerError, InstanceFailure) as exc:
            failures[0] = exc
        for s in sent:  # every reply is read, even after a failure, so the pipes stay in step
            try:
                replies[s] = self._receive(self._workers[s - 1], what[s])
            except (EnvServerError, InstanceFailure) as exc:
                failures[s] = exc
        if failures:
            raise failures[min(failures)]  # the lowest share's, so the lowest failing index
        # Back into the order of `steps` and `resets`.
        step_iters = {s: iter(reply.steps) for s, reply in replies.items()}
        reset_iters = {s: iter(reply.resets) for s, reply in replies.items()}
        return Outcomes(
            [next(step_iters[self._share[i]]) for i, _ in steps],
            [next(reset_iters[self._share[i]]) for i, _ in resets],
        )

    def render(self, batch: RenderBatch) -> list[Any]:
        n = len(self._workers) + 1
        shares: list[list[int]] = [[] for _ in range(n)]
        for i in batch.indices:
            shares[self._share[i]].append(i)
        failures: dict[int, EnvServerError | InstanceFailure] = {}
        sent = []
        for s in range(1, n):
            if shares[s]:
                try:
                    self._workers[s - 1].conn.send(dataclasses.replace(batch, indices=shares[s]))
                    sent.append(s)
                except OSError:
                    failures[s] = self._died(self._workers[s - 1], "render")
        replies: dict[int, list[Any]] = {}
        try:
            replies[0] = _render_tasks(self._local, dataclasses.replace(batch, indices=shares[0]))
        except (EnvServerError, InstanceFailure) as exc:
            failures[0] = exc
        for s in sent:  # every reply is read, even after a failure, so the pipes stay in step
            try:
                replies[s] = self._receive(self._workers[s - 1], "render")
            except (EnvServerError, InstanceFailure) as exc:
                failures[s] = exc
        if failures:
            raise failures[min(failures)]
        frames = {s: iter(reply) for s, reply in replies.items()}
        return [next(frames[self._share[i]]) for i in batch.indices]

    def close(self) -> None:
        for worker in self._workers:
            try:
                worker.conn.send(None)
            except (OSError, ValueError):
                pass  # already gone
        _close_tasks(self._local)
        for worker in self._workers:
            worker.process.join(timeout=CLOSE_TIMEOUT_S)
            if worker.process.is_alive():
                log.error("worker %s did not exit in %g s; killing it", worker.process.name, CLOSE_TIMEOUT_S)
                worker.process.kill()
                worker.process.join()
            worker.conn.close()
        self._workers = []
        self._local = {}


# ---------------------------------------------------------------------- construction
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
            instances = LocalInstances(list(_build_tasks(build, range(num_envs), cancel).values()))
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
        spaces.space_to_spec(task.observation_space)
        spaces.leaf_dtype(task.action_space)
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
