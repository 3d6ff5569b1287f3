"""Reaching a Dask cluster (docs/fleet.md): a scheduler's address and its TLS files checked,
a client connected within a deadline, a local cluster of worker processes started (forked
from a preloaded fork server, SIGINT ignored by its workers). Every failure is a
:class:`FleetError` in one line. The runners that use them are :mod:`hdrd.analysis.fleet`'s.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import signal
import threading
from collections.abc import Iterator
from dataclasses import dataclass
from typing import Any

from hdrd.errors import HdrdError, clipped
from hdrd.io.files.access import printable

__all__ = [
    "INSTALL",
    "FleetError",
    "TlsFiles",
    "connect",
    "connect_timeout",
    "import_distributed",
    "local_cluster",
    "scheduler_warning",
    "sigint_ignored",
    "start_forkserver",
]

INSTALL = "pip install 'hdrd[fleet]'"


class FleetError(HdrdError, RuntimeError):
    """The cluster could not do the work (Dask missing, the scheduler unreachable, a task's
    worker died too often); the message says what, in one line."""


@dataclass(frozen=True)
class TlsFiles:
    """The client's TLS files for a ``tls://`` scheduler (PEM paths): the cluster's CA
    certificate, this client's certificate and its key (None: the key is in the certificate's
    file). Any left None comes from the Dask configuration (``distributed.comm.tls.ca-file``,
    ``distributed.comm.tls.client.cert``, ``distributed.comm.tls.client.key``)."""

    ca_file: str | None = None
    cert: str | None = None
    key: str | None = None

    def given(self) -> dict[str, str]:
        """The files given, as ``distributed.security.Security`` takes them."""
        fields = {"tls_ca_file": self.ca_file, "tls_client_cert": self.cert}
        fields["tls_client_key"] = self.key
        return {k: v for k, v in fields.items() if v is not None}


SCHEMES = ("tcp", "tls")
"""The scheduler addresses hdrd connects to: plain TCP, or TLS (docs/fleet.md, "Trust")."""
TLS_HELP = (
    "--tls-ca-file CA.pem --tls-cert CLIENT.pem [--tls-key CLIENT.key], or "
    "distributed.comm.tls.ca-file and distributed.comm.tls.client.cert/key in the Dask "
    "configuration"
)


def one_line(e: BaseException) -> str:

    text = " ".join(str(e).split())
    return clipped(printable(text), 200) or type(e).__name__


def _scheme(address: str) -> tuple[str, str]:
    """(scheme, host) of a scheduler's address (no scheme: tcp); FleetError for an address
    that is not one, or a scheme hdrd does not connect to."""
    from distributed.comm.addressing import parse_address, parse_host_port

    try:
        scheme, loc = parse_address(address, strict=False)
    except (ValueError, TypeError) as e:
        raise FleetError(f"--scheduler {address}: not an address ({one_line(e)})") from None
    if scheme not in SCHEMES:
        raise FleetError(
            f"--scheduler {address}: the {scheme}:// scheme is not supported; give "
            "tcp://HOST:PORT or tls://HOST:PORT"
        )
    try:
        host, _ = parse_host_port(loc, 8786)
    except (ValueError, TypeError) as e:
        raise FleetError(f"--scheduler {address}: not an address ({one_line(e)})") from None
    return scheme, host


def scheduler_warning(address: str | None) -> str | None:
    """The warning a scheduler's address deserves: plain TCP to another machine than this one
    (no encryption, no proof of whom it reaches; docs/fleet.md, "Trust"), else None."""
    if not address:
        return None
    try:
        scheme, host = _scheme(address)
    except FleetError:
        return None  # said as an error when it is used
    if scheme != "tcp" or host == "localhost" or _loopback(host):
        return None
    return (
        f"{address} is plain TCP to another machine: no encryption, and no proof that the "
        "scheduler there is yours (a scheduler runs code in this process); use tls:// "
        '(docs/fleet.md, "Trust")'
    )


def _loopback(host: str) -> bool:
    import ipaddress

    try:
        return ipaddress.ip_address(host.strip("[]")).is_loopback
    except ValueError:
        return False


def _security(distributed: Any, address: str, scheme: str, tls: TlsFiles) -> Any:
    """The client's ``Security`` for ``scheme``: TLS from ``tls`` and the Dask configuration;
    FleetError when TLS files are given for a tcp:// address, are missing for a tls:// one, or
    cannot be loaded."""
    given = tls.given()
    if scheme != "tls":
        if given:
            raise FleetError(f"--tls-* options need a tls:// scheduler address, not {address}")
        return None
    sec = distributed.Security(**given)
    if not (sec.tls_ca_file and sec.tls_client_cert):
        raise FleetError(
            f"{address}: TLS needs the cluster's CA certificate and a client certificate: "
            + TLS_HELP
        )
    try:
        sec.get_connection_args("client")  # loads the files now: an error says which
    except (OSError, ValueError) as e:  # ssl.SSLError is an OSError
        used = f"CA {sec.tls_ca_file}, certificate {sec.tls_client_cert}, key "
        used += sec.tls_client_key or "(in the certificate's file)"
        raise FleetError(f"{address}: cannot load the TLS files ({used}): {one_line(e)}") from None
    return sec


def connect_timeout() -> float:
    """Seconds to reach a scheduler and finish the handshake with it: Dask's
    ``distributed.comm.timeouts.connect`` (30 s by default)."""
    import dask
    from dask.utils import parse_timedelta

    return float(parse_timedelta(dask.config.get("distributed.comm.timeouts.connect"), "s"))


def connect(distributed: Any, address: str, tls: TlsFiles) -> Any:
    """A client of the scheduler at ``address``, connected and past the handshake within
    :func:`connect_timeout` (a listener that accepts and says nothing included); FleetError
    in one line for anything else."""
    scheme, _ = _scheme(address)
    security = _security(distributed, address, scheme, tls)
    deadline = connect_timeout()

    class Bounded(distributed.Client):
        failed = False

        def start(self, **kwargs: Any) -> None:
            # Dask bounds the connection, not the handshake after it: the whole start is.
            kwargs.setdefault("callback_timeout", deadline)
            try:
                super().start(**kwargs)
            except BaseException:
                self.failed = True  # closed here, not again (with a traceback) at exit
                with contextlib.suppress(Exception):
                    self.close(timeout=1)
                raise

        def __del__(self) -> None:
            if not self.failed:
                super().__del__()

    try:
        return Bounded(address, security=security, timeout=deadline)
    except (TimeoutError, asyncio.TimeoutError):
        raise FleetError(
            f"cannot reach the Dask scheduler at {address}: no answer within {deadline:g} s "
            "(distributed.comm.timeouts.connect)"
        ) from None
    except OSError as e:  # refused, closed, TLS refused (ssl.SSLError)
        raise FleetError(f"cannot reach the Dask scheduler at {address}: {one_line(e)}") from None
    except Exception as e:  # noqa: BLE001 - whatever answered, one line, never a traceback
        raise FleetError(
            f"what answered at {address} is not a Dask scheduler this client can use "
            f"({type(e).__name__}: {one_line(e)})"
        ) from None


def import_distributed() -> Any:
    try:
        import distributed
    except ImportError:
        raise FleetError(f"--workers and --scheduler need Dask: {INSTALL}") from None
    return distributed


def dask_setup(worker: Any) -> None:
    """Dask's preload hook, run in each worker process of a local cluster (``--workers``) as
    it starts, a restarted one included. Ctrl-C at a terminal sends SIGINT to every process of
    the command; the command says "interrupted" in one line and closes its cluster, so its
    workers ignore SIGINT (else each prints a traceback)."""
    if threading.current_thread() is threading.main_thread():
        signal.signal(signal.SIGINT, signal.SIG_IGN)


LOCAL_CLUSTER_CONFIG: dict[str, Any] = {
    # What a local cluster of one-thread workers running coarse tasks does not need; each
    # costs CPU that the work would otherwise have (bench/fleet.py, bench/RESULTS.md).
    "distributed.worker.profile.enabled": False,  # a stack sample of the task every 10 ms
    "distributed.scheduler.work-stealing": False,  # the client sizes and spreads the tasks
    "distributed.admin.tick.interval": "1s",  # every server's event-loop check, 20 ms
    "distributed.admin.system-monitor.interval": "5s",  # psutil in every server, 500 ms
    "distributed.admin.system-monitor.disk": False,
    "distributed.worker.memory.monitor-interval": "1s",  # the nannies' psutil, 100 ms
}
FORKSERVER_PRELOAD = ("distributed", "numpy", "hdrd.analysis.fleet_jobs")
"""What a local cluster's workers import once, in the fork server they are forked from
(where there is one, as on Linux), instead of each importing it: a worker starts in a tenth
of the time and CPU."""


def start_forkserver() -> None:
    """The fork server a local cluster's workers are forked from (where there is one, as on
    Linux), started now, having imported :data:`FORKSERVER_PRELOAD` (its start returns at
    once; it imports while this process goes on)."""
    import multiprocessing

    if "forkserver" not in multiprocessing.get_all_start_methods():
        return
    from multiprocessing import forkserver

    ctx = multiprocessing.get_context("forkserver")
    ctx.set_forkserver_preload(list(FORKSERVER_PRELOAD))
    forkserver.ensure_running()


def local_cluster(distributed: Any, workers: int) -> tuple[Any, Any]:
    """(client, cluster): a local cluster of ``workers`` one-thread worker processes with
    :data:`LOCAL_CLUSTER_CONFIG`, forked from the fork server (:func:`start_forkserver`),
    their environment without Dask's ``MALLOC_TRIM_THRESHOLD_`` (which hands freed memory
    back to the system at once, and makes every large numpy array a fresh mapping).
    FleetError if it cannot be started."""
    import multiprocessing

    import dask

    environ = dict(dask.config.get("distributed.nanny.pre-spawn-environ", {}) or {})
    environ.pop("MALLOC_TRIM_THRESHOLD_", None)
    conf = {**LOCAL_CLUSTER_CONFIG, "distributed.nanny.pre-spawn-environ": environ}
    if "forkserver" in multiprocessing.get_all_start_methods():
        conf["distributed.worker.multiprocessing-method"] = "forkserver"
        start_forkserver()  # (Dask's preload list does not name hdrd's module)
    cluster = None
    try:
        with dask.config.set(conf):
            cluster = distributed.LocalCluster(
                n_workers=workers,
                threads_per_worker=1,
                processes=True,
                dashboard_address=None,
                # its HTTP routes (health, metrics) on a free port of localhost, not 8787:
                # two fleets at once neither collide nor warn
                scheduler_kwargs={"dashboard_address": "127.0.0.1:0"},
                silence_logs=logging.CRITICAL,  # its shutdown races are not the user's
                preload=[__name__],  # dask_setup, in every worker process
            )
        return distributed.Client(cluster), cluster
    except BaseException as e:
        if cluster is not None:
            cluster.close()
        if isinstance(e, (OSError, TimeoutError, RuntimeError)):
            raise FleetError(
                f"cannot start a local Dask cluster of {workers} workers: {one_line(e)}"
            ) from None
        raise


@contextlib.contextmanager
def sigint_ignored() -> Iterator[None]:
    """SIGINT ignored meanwhile (in the main thread; elsewhere nothing changes): the processes
    started meanwhile (the fork server, and so every worker forked from it) inherit it, and
    Python leaves a SIGINT ignored at its start ignored. A Ctrl-C meanwhile is lost (a signal
    cannot be both ignored by them and caught here): the fork server's start, milliseconds,
    with :meth:`hdrd.analysis.fleet.DaskRunner.start`; the whole cluster's with :meth:`hdrd.analysis.fleet.DaskRunner.open`."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    previous = signal.signal(signal.SIGINT, signal.SIG_IGN)
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, previous)
