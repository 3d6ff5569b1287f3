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
run are pure, so a task run twice gives the same result.
"""

from __future__ import annotations

import argparse
import functools
import logging
import weakref
from collections.abc import Callable, Generator, Iterator, Sequence
from typing import Any, TypeVar

from hdrd.errors import HdrdError

__all__ = [
    "INSTALL",
    "DaskRunner",
    "FleetError",
    "LocalRunner",
    "Runner",
    "batches",
    "fleet_requested",
    "open_runner",
    "run_batch",
]

INSTALL = "pip install 'hdrd[fleet]'"
GUIDE = 8
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


class FleetError(HdrdError, RuntimeError):
    """The cluster could not do the work (Dask missing, the scheduler unreachable, a task's
    worker died too often); the message says what, in one line."""


def fleet_requested(args: argparse.Namespace) -> bool:
    """True if the command line asks for a cluster (``--workers`` or ``--scheduler``)."""
    return bool(getattr(args, "workers", None) or getattr(args, "scheduler", None))


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
        total) after each finished task, in items (or in ``weights``, one per item). batch:
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


def _dask() -> Any:
    try:
        import distributed
    except ImportError:
        raise FleetError(f"--workers and --scheduler need Dask: {INSTALL}") from None
    return distributed


class DaskRunner(Runner):
    """A ``dask.distributed`` client (and the local cluster it started, if any)."""

    distributed = True

    def __init__(self, client: Any, cluster: Any = None) -> None:
        self.client = client
        self.cluster = cluster
        self.threads = max(1, sum(client.nthreads().values()))
        self._open: weakref.WeakSet[Generator[Any, None, None]] = weakref.WeakSet()

    @classmethod
    def open(cls, workers: int | None = None, scheduler: str | None = None) -> DaskRunner:
        """A local cluster of ``workers`` processes (one thread each), or the cluster whose
        scheduler is at ``scheduler`` (``tcp://host:8786``). FleetError if it cannot be had."""
        distributed = _dask()
        if scheduler:
            try:  # waits distributed.comm.timeouts.connect (30 s) for the scheduler
                client = distributed.Client(scheduler)
            except (OSError, TimeoutError, ValueError) as e:
                raise FleetError(f"cannot reach the Dask scheduler at {scheduler}: {e}") from None
            return cls(client)
        if workers is None or workers < 1:
            raise FleetError(f"--workers must be >= 1, got {workers}")
        try:
            cluster = distributed.LocalCluster(
                n_workers=workers,
                threads_per_worker=1,
                processes=True,
                dashboard_address=None,
                silence_logs=logging.CRITICAL,  # its shutdown races are not the user's concern
            )
        except (OSError, TimeoutError, RuntimeError) as e:
            raise FleetError(
                f"cannot start a local Dask cluster of {workers} workers: {e}"
            ) from None
        try:
            client = distributed.Client(cluster)
        except BaseException:
            cluster.close()
            raise
        return cls(client, cluster)

    def close(self) -> None:
        # A map left half-read (its consumer raised) cancels its tasks now, while the client
        # is open, not when it is collected after the client closed (which would wait forever).
        for gen in list(self._open):
            gen.close()
        try:
            self.client.close()
        finally:
            if self.cluster is not None:
                self.cluster.close()

    def _result(self, fut: Any, what: Callable[[], str]) -> Any:
        distributed = _dask()
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
        distributed = _dask()
        n = len(items)
        if batch:
            chunks = [range(a, min(n, a + batch)) for a in range(0, n, batch)]
        else:
            chunks = batches(n, self.threads)
        w = list(weights) if weights is not None else [1] * n
        total, done = sum(w), 0
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
                done += sum(w[i] for i in chunks[ci])
                if progress is not None:
                    progress(done, total)
                while yielded in finished:
                    results = finished.pop(yielded)
                    yielded += 1
                    top_up()
                    yield from results
        finally:
            for f in list(pending.futures):
                f.cancel()
            pending.clear()

    def persist(self, fn: Callable[..., Any], items: Sequence[Any], *args: Any) -> list[Any]:
        return [self.client.submit(fn, item, *args, pure=False) for item in items]

    def share(self, value: Any) -> Any:
        # In a list: a dict given alone would be scattered as named values, one per key.
        return self.client.scatter([value], broadcast=True, hash=False)[0]


def _describe(items: Sequence[Any], idx: range) -> str:
    """The drives of a task, for a message: their names where items have one."""
    names = [str(getattr(items[i], "name", i)) for i in idx]
    return names[0] if len(names) == 1 else f"{names[0]} .. {names[-1]} ({len(names)} drives)"


def open_runner(args: argparse.Namespace) -> Runner:
    """The runner a command line asks for: a :class:`DaskRunner` with ``--workers N`` or
    ``--scheduler ADDRESS``, else a :class:`LocalRunner` (and Dask is never imported)."""
    if not fleet_requested(args):
        return LocalRunner()
    workers = getattr(args, "workers", None)
    if workers is not None and not (isinstance(workers, int) and workers >= 1):
        raise FleetError(f"--workers must be >= 1, got {workers}")
    return DaskRunner.open(workers, getattr(args, "scheduler", None))
