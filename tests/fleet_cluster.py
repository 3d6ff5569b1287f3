"""A real Dask cluster for tests/test_fleet.py, in its own process (so that the test process
never holds Dask's threads and sockets): ``python tests/fleet_cluster.py COMMAND ...``.

- ``serve N``: a LocalCluster of N worker processes; prints its scheduler's address, serves
  until its stdin closes, then closes the cluster.
- ``kill DIR OUT.json``: evaluates the drives under DIR on a LocalCluster of 2 worker
  processes where the first task to start kills its own worker process (SIGKILL, mid-task;
  the nanny starts a new one); writes the fleet's and this process's results as JSON, and
  what the scheduler saw.
- ``always DIR OUT.json``: a drive whose task kills its worker every time: after Dask's
  allowed failures (set to 1 here), a one-line FleetError naming the drive, not a missing row.
- ``order OUT.json``: items that finish in the reverse of their order come back in order;
  the progress shown at each call, and how many items the caller had by then.
- ``hybrid OUT.json``: a cluster started in the background (as ``--workers`` starts it): the
  items this process takes while it starts and those the workers take, in order.
- ``foreign ADDRESS``: a task the cluster cannot load (its module exists only here) is a
  one-line FleetError; prints it.
- ``certs DIR``: a certificate authority for a cluster (``ca.pem``), a certificate and key
  signed by it (``node.pem``, ``node.key``) and a second, unrelated authority
  (``stranger.pem``).
- ``serve-tls N DIR``: as ``serve``, a cluster that speaks only TLS with DIR's certificates.
- ``fake MODE MARKER``: not a scheduler, something listening where one might be: ``silent``
  accepts and says nothing, ``garbage`` answers with bytes that are not Dask's protocol,
  ``pickle`` answers the handshake with a pickled object whose unpickling creates the file
  MARKER (what a hostile scheduler can do to a client). Prints its address, serves until its
  stdin closes.
"""

from __future__ import annotations

import json
import os
import signal
import sys
import time
from collections import Counter
from pathlib import Path
from typing import Any

from hdrd.analysis.cluster import FleetError
from hdrd.analysis.evaluate import to_json
from hdrd.analysis.fleet import DaskRunner, LocalRunner
from hdrd.analysis.fleet_jobs import DriveOutcome, EvaluateJob, evaluate_one, evaluate_refs
from hdrd.io.files.drivefiles import DriveRef, find_drives


def die_once(ref: DriveRef, job: EvaluateJob, marker: str) -> DriveOutcome:
    """evaluate_one, but the first call anywhere (a marker file says) kills its process."""
    try:
        fd = os.open(marker, os.O_CREAT | os.O_EXCL | os.O_WRONLY)
    except FileExistsError:
        return evaluate_one(ref, job)
    os.write(fd, f"{os.getpid()} {ref.name}".encode())
    os.close(fd)
    os.kill(os.getpid(), signal.SIGKILL)
    raise AssertionError("unreachable")


def die_always(ref: DriveRef, job: EvaluateJob) -> DriveOutcome:
    if ref.name == "rural":
        os.kill(os.getpid(), signal.SIGKILL)
    return evaluate_one(ref, job)


def slow_echo(i: int, n: int) -> int:
    time.sleep(0.02 * (n - i))  # the last item finishes first
    return i


def serve(n: int) -> None:
    with DaskRunner.open(workers=n) as runner:
        print(runner.client.scheduler.address, flush=True)
        sys.stdin.read()


def kill(drives: str, out: str) -> None:
    refs = find_drives([drives])
    job = EvaluateJob()
    marker = str(Path(out).with_suffix(".marker"))
    with DaskRunner.open(workers=2) as runner:
        pids_before = sorted(runner.client.run(os.getpid).values())
        got = list(runner.map(die_once, refs, job, marker, batch=1))
        # Tasks the scheduler sent to a worker more than once (the log keeps transitions
        # after the tasks are forgotten).
        sched = runner.cluster.scheduler
        starts = Counter(t[0] for t in sched.transition_log if t[2] == "processing")
        lost = [k for k, n in starts.items() if n > 1]
        deadline = time.monotonic() + 30
        while len(runner.client.nthreads()) < 2 and time.monotonic() < deadline:
            time.sleep(0.1)  # the nanny restarts the killed worker
        pids_after = sorted(runner.client.run(os.getpid).values())
    local, skipped = evaluate_refs(refs, job, LocalRunner())
    doc: dict[str, Any] = {
        "fleet": to_json([o.result for o in got if o.skipped is None]),
        "fleet_skipped": [o.skipped for o in got if o.skipped is not None],
        "names": [o.name for o in got],
        "local": to_json(local),
        "local_skipped": skipped,
        "killed": Path(marker).read_text(),
        "tasks_run_twice": len(lost),
        "pids_before": pids_before,
        "pids_after": pids_after,
    }
    Path(out).write_text(json.dumps(doc))


def always(drives: str, out: str) -> None:
    import dask

    refs = find_drives([drives])
    with dask.config.set({"distributed.scheduler.allowed-failures": 1}):
        with DaskRunner.open(workers=2) as runner:
            try:
                list(runner.map(die_always, refs, EvaluateJob(), batch=1))
                message = "no error"
            except FleetError as e:
                message = str(e)
    Path(out).write_text(json.dumps({"error": message}))


def foreign(address: str) -> None:
    import tempfile

    with tempfile.TemporaryDirectory() as d:
        Path(d, "only_here.py").write_text("def double(x):\n    return 2 * x\n")
        sys.path.insert(0, d)
        import only_here

        with DaskRunner.open(scheduler=address) as runner:
            try:
                list(runner.map(only_here.double, [1, 2, 3], batch=1))
                print("no error")
            except FleetError as e:
                print(e)


def certs(out: str) -> None:
    import datetime

    from cryptography import x509
    from cryptography.hazmat.primitives import hashes, serialization
    from cryptography.hazmat.primitives.asymmetric import ec
    from cryptography.x509.oid import NameOID

    now = datetime.datetime.now(datetime.timezone.utc)

    def name(cn: str) -> x509.Name:
        return x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, cn)])

    def cert(
        cn: str, key: ec.EllipticCurvePrivateKey, issuer: str, signer: ec.EllipticCurvePrivateKey
    ) -> bytes:
        b = (
            x509.CertificateBuilder()
            .subject_name(name(cn))
            .issuer_name(name(issuer))
            .public_key(key.public_key())
            .serial_number(x509.random_serial_number())
            .not_valid_before(now - datetime.timedelta(minutes=5))
            .not_valid_after(now + datetime.timedelta(days=1))
            .add_extension(x509.BasicConstraints(ca=cn == issuer, path_length=None), True)
        )
        return b.sign(signer, hashes.SHA256()).public_bytes(serialization.Encoding.PEM)

    d = Path(out)
    d.mkdir(parents=True, exist_ok=True)
    ca_key, node_key, other_key = (ec.generate_private_key(ec.SECP256R1()) for _ in range(3))
    (d / "ca.pem").write_bytes(cert("hdrd test CA", ca_key, "hdrd test CA", ca_key))
    (d / "node.pem").write_bytes(cert("hdrd test node", node_key, "hdrd test CA", ca_key))
    (d / "stranger.pem").write_bytes(cert("stranger", other_key, "stranger", other_key))
    pem = node_key.private_bytes(
        serialization.Encoding.PEM,
        serialization.PrivateFormat.PKCS8,
        serialization.NoEncryption(),
    )
    (d / "node.key").write_bytes(pem)


def serve_tls(n: int, certdir: str) -> None:
    import distributed

    d = Path(certdir)
    roles = ("client", "scheduler", "worker")
    files = {f"tls_{r}_cert": str(d / "node.pem") for r in roles}
    files |= {f"tls_{r}_key": str(d / "node.key") for r in roles}
    sec = distributed.Security(tls_ca_file=str(d / "ca.pem"), require_encryption=True, **files)
    with distributed.LocalCluster(
        n_workers=n,
        threads_per_worker=1,
        processes=True,
        protocol="tls://",
        security=sec,
        dashboard_address=None,
        scheduler_kwargs={"dashboard_address": "127.0.0.1:0"},  # not 8787: tests run at once
    ) as cluster:
        print(cluster.scheduler_address, flush=True)
        sys.stdin.read()


class Hostile:
    """Unpickled, creates the file ``marker``: any code could run there instead."""

    def __init__(self, marker: str) -> None:
        self.marker = marker

    def __reduce__(self) -> tuple[Any, tuple[Any, ...]]:
        return (Path.touch, (Path(self.marker),))


def fake(mode: str, marker: str) -> None:
    import socket
    import threading

    if mode == "pickle":
        import asyncio

        import distributed.comm.core
        from distributed.protocol import to_serialize

        async def answer(comm: Any) -> None:
            await asyncio.sleep(3600)

        plain = distributed.comm.core.Comm.handshake_info
        distributed.comm.core.Comm.handshake_info = lambda self: {  # type: ignore[method-assign]
            **plain(self),
            "pickle-protocol": to_serialize(Hostile(marker)),
        }

        async def main() -> None:
            listener = await distributed.comm.listen("tcp://127.0.0.1:0", answer)
            print(listener.contact_address, flush=True)
            await asyncio.get_running_loop().run_in_executor(None, sys.stdin.read)
            listener.stop()

        asyncio.run(main())
        return
    srv = socket.create_server(("127.0.0.1", 0))
    held: list[socket.socket] = []

    def accept() -> None:
        while True:
            conn, _ = srv.accept()
            held.append(conn)  # held open
            if mode == "garbage":
                conn.sendall(b"HTTP/1.1 400 Bad Request\r\n\r\n" + os.urandom(4096))

    threading.Thread(target=accept, daemon=True).start()
    print(f"tcp://127.0.0.1:{srv.getsockname()[1]}", flush=True)
    sys.stdin.read()


def pid_of(i: int) -> tuple[int, int]:
    time.sleep(0.02)
    return i, os.getpid()


def hybrid(out: str) -> None:
    with DaskRunner.start(2) as runner:
        got = list(runner.map(pid_of, list(range(120))))
        workers = sorted(runner.client.run(os.getpid).values())
    Path(out).write_text(json.dumps({"got": got, "client": os.getpid(), "workers": workers}))


def order(out: str) -> None:
    n = 12
    doc: dict[str, Any] = {}
    with DaskRunner.open(workers=2) as runner:
        for batch in (1, 5):
            got: list[int] = []
            shown: list[list[int]] = []  # [done, items the caller had] at each progress call

            def progress(done: int, _total: int, got: list[int] = got, shown: list = shown) -> None:
                shown.append([done, len(got)])

            for x in runner.map(slow_echo, list(range(n)), n, batch=batch, progress=progress):
                got.append(x)
            doc[f"batch{batch}"], doc[f"progress{batch}"] = got, shown
    Path(out).write_text(json.dumps(doc))


if __name__ == "__main__":
    cmd = sys.argv[1]
    if cmd == "serve":
        serve(int(sys.argv[2]))
    elif cmd == "kill":
        kill(sys.argv[2], sys.argv[3])
    elif cmd == "order":
        order(sys.argv[2])
    elif cmd == "always":
        always(sys.argv[2], sys.argv[3])
    elif cmd == "foreign":
        foreign(sys.argv[2])
    elif cmd == "certs":
        certs(sys.argv[2])
    elif cmd == "serve-tls":
        serve_tls(int(sys.argv[2]), sys.argv[3])
    elif cmd == "hybrid":
        hybrid(sys.argv[2])
    elif cmd == "fake":
        fake(sys.argv[2], sys.argv[3])
    else:
        raise SystemExit(f"unknown command {cmd!r}")
