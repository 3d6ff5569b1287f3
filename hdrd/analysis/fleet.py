"""Running per-drive work over a fleet of drive logs: in this process, or on a Dask cluster
(docs/fleet.md).

Two runners with one interface, so that a command has one code path and the cluster changes
where the work runs, never what it computes:

- :class:`LocalRunner`: this process, one drive after the other (the default; Dask is not
  imported);
- :class:`DaskRunner`: a ``dask.distributed`` cluster, a local one of worker processes
  (``--workers N``) or an existing one (``--scheduler ADDRESS``).

:meth:`map` runs a function on every item and yields the results *in the items' order*
whatever order they finish in, as soon as the ones before are in; on a cluster it keeps a
bounded number of tasks in flight, each a batch of items, so neither the client nor the
scheduler ever holds the whole fleet and the per-task overhead is shared by a batch. Items
are small (paths: a worker reads its drives itself) and so are results. :meth:`persist`
computes values that stay where they were computed (a worker's memory; Dask recomputes them
if that worker dies) and :meth:`share` sends one value to every worker once.

A worker that dies mid-run loses its tasks; the scheduler runs them again elsewhere (up to
``distributed.scheduler.allowed-failures`` times, then :class:`FleetError`). The functions
run are pure, so a task run twice gives the same result. Reaching the cluster (its address,
TLS, a local cluster's start) is :mod:`hdrd.analysis.cluster`'s.
"""

from __future__ import annotations

import functools
import threading
import weakref
from collections.abc import Callable, Generator, Iterator, Sequence
from dataclasses import dataclass, field
from typing import Any, TypeVar

from hdrd.analysis.cluster import (
    INSTALL,
    FleetError,
    TlsFiles,
    connect,
    import_distributed,
    local_cluster,
    sigint_ignored,
    start_forkserver,
)

__all__ = [
    "MIN_CLUSTER_WORK_S",
    "MIN_WORK_ENV",
    "DaskRunner",
    "LocalRunner",
    "Runner",
    "Where",
    "batches",
    "open_runner",
    "run_batch",
]

GUIDE = 4
"""A task takes 1/(GUIDE x threads) of the items not yet sent (guided self-scheduling): large
tasks first, where the per-task cost matters, then ever smaller ones, so that the workers
finish together (the last tasks are single drives)."""
MAX_BATCH = 64
"""At most this many items in one task (a retried task redoes no more than this)."""
WINDOW_PER_THREAD = 4
"""Tasks in flight per worker thread (at least :data:`MIN_WINDOW`): enough to keep every
worker busy while results travel, few enough that nothing piles up."""
MIN_WINDOW = 8

Progress = Callable[[int, int], None]
R = TypeVar("R", bound="Runner")


MIN_CLUSTER_WORK_S = 4.0
"""``--workers N`` runs in this process when the work is estimated below this many seconds of
one process: a local cluster's start, stop and upkeep (about 1.5 s of CPU, and the start's
second or so of waiting) would not pay for themselves (bench/fleet.py: 60 drives of 12
minutes, about 1.3 s, were slower on two workers than in one process)."""


MIN_WORK_ENV = "HDRD_FLEET_MIN_WORK_S"
"""The environment variable that sets :data:`MIN_CLUSTER_WORK_S` (0: always the cluster)."""


@dataclass(frozen=True)
class Where:
    """Where a command's work runs (``--workers``, ``--scheduler``, ``--tls-*``): in this
    process (neither), on a local cluster of ``workers`` processes, or on the cluster whose
    scheduler is at ``scheduler``."""

    workers: int | None = None
    scheduler: str | None = None
    tls: TlsFiles = field(default_factory=lambda: TlsFiles())
    min_work_s: float = MIN_CLUSTER_WORK_S
    """Work (estimated seconds in one process) below which ``workers`` runs in this process."""

    def __post_init__(self) -> None:
        if self.tls.given() and not self.scheduler:
            raise FleetError("the --tls-* options are for a tls:// --scheduler")

    @property
    def cluster(self) -> bool:
        """True if the work runs on a Dask cluster."""
        return bool(self.workers or self.scheduler)


def run_batch(fn: Callable[..., Any], items: Sequence[Any], *args: Any) -> list[Any]:
    """``[fn(item, *args) for item in items]``: one task's work on a cluster."""
    return [fn(item, *args) for item in items]


def batches(n: int, threads: int) -> list[range]:
    """The items of each task, for n items on ``threads`` worker threads: each takes
    1/(:data:`GUIDE` x threads) of the items left, at least 1, at most :data:`MAX_BATCH`."""
    out: list[range] = []
    a = 0
    while a < n:
        size = min(MAX_BATCH, max(1, -(-(n - a) // (GUIDE * max(1, threads)))))
        out.append(range(a, min(n, a + size)))
        a += size
    return out


class Runner:
    """What a command needs of a runner (see the module docstring)."""

    threads = 1
    """Worker threads that run tasks (1 in this process)."""
    distributed = False

    def map(
        self,
        fn: Callable[..., Any],
        items: Sequence[Any],
        *args: Any,
        progress: Progress | None = None,
        weights: Sequence[int] | None = None,
        batch: int | None = None,
    ) -> Iterator[Any]:
        """``fn(item, *args)`` for every item, yielded in the items' order. progress(done,
        total) as each task's results are handed over (a task finished out of order waits for
        those before it: what progress shows done is what the caller has, so a Ctrl-C keeps
        it), in items (or in ``weights``, one per item). batch:
        items per task (default :func:`batches`); 1 passes the item itself (a handle from
        :meth:`persist` or :meth:`share` is then resolved to its value)."""
        raise NotImplementedError

    def persist(self, fn: Callable[..., Any], items: Sequence[Any], *args: Any) -> list[Any]:
        """Handles of ``fn(item, *args)`` for each item, computed where they will be used."""
        raise NotImplementedError

    def share(self, value: Any) -> Any:
        """A handle of ``value`` that every task can take as an argument."""
        raise NotImplementedError

    def close(self) -> None:
        pass

    def __enter__(self: R) -> R:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


class LocalRunner(Runner):
    """This process, item after item; a handle is the value itself."""

    def map(
        self,
        fn: Callable[..., Any],
        items: Sequence[Any],
        *args: Any,
        progress: Progress | None = None,
        weights: Sequence[int] | None = None,
        batch: int | None = None,
    ) -> Iterator[Any]:
        w = list(weights) if weights is not None else [1] * len(items)
        total, done = sum(w), 0
        for i, item in enumerate(items):
            out = fn(item, *args)
            done += w[i]
            if progress is not None:
                progress(done, total)
            yield out

    def persist(self, fn: Callable[..., Any], items: Sequence[Any], *args: Any) -> list[Any]:
        return [fn(item, *args) for item in items]

    def share(self, value: Any) -> Any:
        return value


class DaskRunner(Runner):
    """A ``dask.distributed`` client (and the local cluster it started, if any).

    A local cluster may still be starting (:meth:`start`): until it is up, :meth:`map` runs
    the first items in this process, in order (the same functions: the same results), and
    hands the rest to the cluster once it is; :meth:`persist` and :meth:`share` wait for it.
    """

    distributed = True

    def __init__(self, client: Any = None, cluster: Any = None, threads: int = 0) -> None:
        self.client = client
        self.cluster = cluster
        self.threads = threads or max(1, sum(client.nthreads().values()))
        self._open: weakref.WeakSet[Generator[Any, None, None]] = weakref.WeakSet()
        self._up = threading.Event()  # the client is there (or its start failed)
        self._start_error: BaseException | None = None
        self._starting: threading.Thread | None = None
        if client is not None:
            self._up.set()

    @classmethod
    def open(
        cls, workers: int | None = None, scheduler: str | None = None, tls: TlsFiles | None = None
    ) -> DaskRunner:
        """A local cluster of ``workers`` processes (one thread each), or the cluster whose
        scheduler is at ``scheduler`` (``tcp://host:8786``, ``tls://host:8786`` with ``tls``
        or the Dask configuration's TLS files), up when this returns. FleetError if it cannot
        be had."""
        distributed = import_distributed()
        if scheduler:
            return cls(connect(distributed, scheduler, tls or TlsFiles()))
        if workers is None or workers < 1:
            raise FleetError(f"--workers must be >= 1, got {workers}")
        with sigint_ignored():  # the worker processes inherit it (and see dask_setup)
            client, cluster = local_cluster(distributed, workers)
        return cls(client, cluster)

    @classmethod
    def start(cls, workers: int) -> DaskRunner:
        """A local cluster of ``workers`` processes (one thread each), started in the
        background: this process works meanwhile (the class docstring). FleetError (when the
        cluster is first needed) if it cannot be had."""
        if workers < 1:
            raise FleetError(f"--workers must be >= 1, got {workers}")
        import importlib.util

        if importlib.util.find_spec("distributed") is None:
            import_distributed()  # the one-line error, now
        with sigint_ignored():  # the fork server, and so every worker, inherits it
            start_forkserver()
        runner = cls(threads=workers)
        runner._starting = threading.Thread(
            target=runner._start, args=(workers,), name="hdrd-cluster-start", daemon=True
        )
        runner._starting.start()
        return runner

    def _start(self, workers: int) -> None:
        try:
            self.client, self.cluster = local_cluster(import_distributed(), workers)
        except BaseException as e:  # noqa: BLE001 - raised where the cluster is needed
            self._start_error = e
        finally:
            self._up.set()

    def _ready(self) -> None:
        """Wait for the cluster; its start's error (FleetError) if it failed."""
        self._up.wait()
        if self._start_error is not None:
            raise self._start_error

    def close(self) -> None:
        # A map left half-read (its consumer raised) cancels its tasks now, while the client
        # is open, not when it is collected after the client closed (which would wait forever).
        for gen in list(self._open):
            gen.close()
        if self._starting is not None:
            self._starting.join()  # a cluster still starting is closed once up
        try:
            if self.client is not None:
                self.client.close()
        finally:
            if self.cluster is not None:
                self.cluster.close()

    def _result(self, fut: Any, what: Callable[[], str]) -> Any:
        distributed = import_distributed()
        try:
            return fut.result()
        except distributed.KilledWorker as e:
            raise FleetError(
                f"{what()}: its workers died too often (distributed.scheduler."
                f"allowed-failures); giving up: {e}"
            ) from None
        except distributed.client.FutureCancelledError:
            raise FleetError(f"{what()}: the task was cancelled by the cluster") from None
        except (ImportError, AttributeError, RuntimeError) as e:
            # The scheduler or a worker could not load the task: another hdrd, or none.
            first = " ".join(str(e).split())[:160] or type(e).__name__
            raise FleetError(
                f"{what()}: the cluster cannot run hdrd's code ({first}); install the same hdrd "
                f"on the scheduler and every worker: {INSTALL}"
            ) from None

    def map(
        self,
        fn: Callable[..., Any],
        items: Sequence[Any],
        *args: Any,
        progress: Progress | None = None,
        weights: Sequence[int] | None = None,
        batch: int | None = None,
    ) -> Iterator[Any]:
        gen = self._map(fn, items, args, progress, weights, batch)
        self._open.add(gen)
        return gen

    def _map(
        self,
        fn: Callable[..., Any],
        items: Sequence[Any],
        args: tuple[Any, ...],
        progress: Progress | None,
        weights: Sequence[int] | None,
        batch: int | None,
    ) -> Generator[Any, None, None]:
        w = list(weights) if weights is not None else [1] * len(items)
        total = sum(w)
        first = yield from self._while_starting(fn, items, args, progress, w)
        if first == len(items):
            return
        self._ready()
        done, items, w, n = sum(w[:first]), items[first:], w[first:], len(items) - first
        distributed = import_distributed()
        chunks = [range(a, min(n, a + batch)) for a in range(0, n, batch)] if batch else []
        chunks = chunks or batches(n, self.threads)
        window = max(MIN_WINDOW, WINDOW_PER_THREAD * self.threads)
        pending = distributed.as_completed()
        chunk_of: dict[str, int] = {}
        finished: dict[int, list[Any]] = {}
        submitted = 0
        yielded = 0  # chunks yielded so far

        def top_up() -> None:
            nonlocal submitted
            while submitted < len(chunks) and submitted < yielded + window:
                idx = chunks[submitted]
                if batch == 1:
                    fut = self.client.submit(fn, items[idx.start], *args, pure=False)
                else:
                    part = [items[i] for i in idx]
                    fut = self.client.submit(run_batch, fn, part, *args, pure=False)
                chunk_of[fut.key] = submitted
                pending.add(fut)
                submitted += 1

        try:
            top_up()
            for fut in pending:
                ci = chunk_of.pop(fut.key)
                out = self._result(fut, functools.partial(_describe, items, chunks[ci]))
                fut.release()
                finished[ci] = [out] if batch == 1 else out
                while yielded in finished:  # in order; progress counts what was handed over
                    results = finished.pop(yielded)
                    done += sum(w[i] for i in chunks[yielded])
                    if progress is not None:
                        progress(done, total)
                    yielded += 1
                    top_up()
                    yield from results
        finally:
            for f in list(pending.futures):
                f.cancel()
            pending.clear()

    def _while_starting(
        self,
        fn: Callable[..., Any],
        items: Sequence[Any],
        args: tuple[Any, ...],
        progress: Progress | None,
        w: list[int],
    ) -> Generator[Any, None, int]:
        """``fn`` on the first items in this process, in order, while the cluster starts;
        returns how many."""
        total, done, first = sum(w), 0, 0
        while first < len(items) and not self._up.is_set():
            out = fn(items[first], *args)
            done += w[first]
            first += 1
            if progress is not None:
                progress(done, total)
            yield out
        return first

    def persist(self, fn: Callable[..., Any], items: Sequence[Any], *args: Any) -> list[Any]:
        self._ready()
        return [self.client.submit(fn, item, *args, pure=False) for item in items]

    def share(self, value: Any) -> Any:
        self._ready()
        # In a list: a dict given alone would be scattered as named values, one per key.
        return self.client.scatter([value], broadcast=True, hash=False)[0]


def _describe(items: Sequence[Any], idx: range) -> str:
    """The drives of a task, for a message: their names where items have one."""
    names = [str(getattr(items[i], "name", i)) for i in idx]
    return names[0] if len(names) == 1 else f"{names[0]} .. {names[-1]} ({len(names)} drives)"


def open_runner(
    where: Where, work_s: float | None = None, say: Callable[[str], None] | None = None
) -> Runner:
    """The runner ``where`` asks for: a :class:`DaskRunner` with ``workers`` or ``scheduler``,
    else a :class:`LocalRunner` (and Dask is never imported). ``work_s``: the work's
    estimated seconds in one process; below ``where.min_work_s``, ``workers`` runs in this
    process all the same (``say`` is told so, as it is told of the local cluster started)."""
    if where.workers and work_s is not None and work_s < where.min_work_s:
        if say is not None:
            say(
                f"about {work_s:.1f} s of work: run in this process (a local cluster pays "
                f"for its start from about {where.min_work_s:g} s: {MIN_WORK_ENV})"
            )
        return LocalRunner()
    if not where.cluster:
        return LocalRunner()
    workers = where.workers
    if workers is not None and not (isinstance(workers, int) and workers >= 1):
        raise FleetError(f"--workers must be >= 1, got {workers}")
    if workers:
        runner = DaskRunner.start(workers)
        if say is not None and work_s is not None:
            say(f"about {work_s:.1f} s of work: on a local cluster of {workers} workers")
        return runner
    return DaskRunner.open(None, where.scheduler, where.tls)
