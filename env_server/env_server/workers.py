"""Instances in worker processes: `WorkerInstances` splits a session's B instances into
contiguous shares, keeps the first and hands one to each worker process, and runs all
shares at the same time (the EnvPool / SubprocVecEnv design). MuJoCo and the Python
around it hold the GIL, so threads would not run in parallel; processes do, at the price
of a pipe round trip per worker per batch.

Workers are started with the "spawn" method: forking a process that runs gRPC's
threads is unsafe. A worker exits when its pipe closes, so a server that dies takes
its workers with it.
"""

from __future__ import annotations

import dataclasses
import logging
import multiprocessing
import multiprocessing.connection
import threading
from collections.abc import Callable, Sequence
from typing import Any

from env_server.errors import EnvServerError
from env_server.instances import (
    CLOSE_TIMEOUT_S,
    InstanceFailure,
    Instances,
    Outcomes,
    RenderBatch,
    Task,
    TaskInfo,
    build_tasks,
    check_cancel,
    close_tasks,
    render_tasks,
    run_tasks,
)

log = logging.getLogger(__name__)


@dataclasses.dataclass(frozen=True)
class _Failed:
    """A worker's reply when its batch or its start raised: an exception that pickles."""

    error: EnvServerError | InstanceFailure


def _worker_main(conn: multiprocessing.connection.Connection, build: Callable[[], Task], indices: list[int]) -> None:
    """A worker process: construct its share of Tasks, then serve batches until the pipe closes."""
    tasks: dict[int, Task] = {}
    try:
        try:
            tasks = build_tasks(build, indices)
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
                    reply: Any = render_tasks(tasks, batch)
                else:
                    reply = run_tasks(tasks, *batch)
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
        close_tasks(tasks)
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
            self._local = build_tasks(build, range(counts[0]), cancel)  # while the workers build theirs
            for worker in self._workers:
                check_cancel(cancel, len(self._local))
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
            replies[0] = run_tasks(self._local, share_steps[0], share_resets[0])
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
            replies[0] = render_tasks(self._local, dataclasses.replace(batch, indices=shares[0]))
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
        close_tasks(self._local)
        for worker in self._workers:
            worker.process.join(timeout=CLOSE_TIMEOUT_S)
            if worker.process.is_alive():
                log.error("worker %s did not exit in %g s; killing it", worker.process.name, CLOSE_TIMEOUT_S)
                worker.process.kill()
                worker.process.join()
            worker.conn.close()
        self._workers = []
        self._local = {}
