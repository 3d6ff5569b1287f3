"""Whom a fleet command trusts (docs/fleet.md, "Trust"): a real TLS scheduler reached with
certificates from the command line or the Dask configuration; a scheduler that cannot show a
certificate of the cluster's authority refused; a listener that accepts and says nothing, one
that answers garbage and one that answers with a pickled object, each a one-line error; every
scheme hdrd does not speak refused in one line; plain TCP to another machine warned about.

Every cluster and fake scheduler runs in a child process (tests/fleet_cluster.py), and so does
every hdrd command.
"""

from __future__ import annotations

import os
import subprocess
import sys
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import pytest

from hdrd.analysis.cluster import scheduler_warning
from hdrd.io.files.drivelog import write_drive
from hdrd.sim.drive import simulate_drive

ROOT = Path(__file__).resolve().parents[1]
ENV = {**os.environ, "PYTHONPATH": str(ROOT)}
HELPER = str(ROOT / "tests" / "fleet_cluster.py")
QUICK = {**ENV, "DASK_DISTRIBUTED__COMM__TIMEOUTS__CONNECT": "3s"}


@pytest.fixture(scope="module")
def drives(tmp_path_factory: pytest.TempPathFactory) -> Path:
    root = tmp_path_factory.mktemp("drives")
    for i, kind in enumerate(("city", "rural", "highway")):
        write_drive(root / f"{kind}.csv", simulate_drive(kind, 1.5, 20 + i))
    return root


@pytest.fixture(scope="module")
def certs(tmp_path_factory: pytest.TempPathFactory) -> Path:
    d = tmp_path_factory.mktemp("certs")
    subprocess.run([sys.executable, HELPER, "certs", str(d)], env=ENV, check=True, timeout=60)
    return d


def hdrd(*args: str, env: dict[str, str] = ENV) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "hdrd", *args],
        capture_output=True,
        text=True,
        env=env,
        cwd=ROOT,
        timeout=300,
        stdin=subprocess.DEVNULL,
    )


@contextmanager
def serving(*argv: str) -> Iterator[str]:
    """tests/fleet_cluster.py ARGV in a child process; the address it prints, while it serves."""
    p = subprocess.Popen(
        [sys.executable, HELPER, *argv],
        stdin=subprocess.PIPE,
        stdout=subprocess.PIPE,
        stderr=subprocess.DEVNULL,
        text=True,
        env=ENV,
    )
    assert p.stdin is not None and p.stdout is not None
    try:
        yield p.stdout.readline().strip()
    finally:
        p.stdin.close()
        try:
            p.wait(timeout=60)
        finally:
            p.stdout.close()
            if p.poll() is None:
                p.kill()
                p.wait()


def one_error(p: subprocess.CompletedProcess[str], *, warned: bool = False) -> str:
    """The one line a failed command printed (after its warning, if ``warned``)."""
    assert p.returncode == 1, p.stderr
    lines = p.stderr.splitlines()
    assert "Traceback" not in p.stderr and len(lines) == 1 + warned, p.stderr
    assert lines[-1].startswith("hdrd evaluate: error: "), lines
    return lines[-1]


@pytest.mark.slow
def test_a_real_tls_scheduler_with_certificates_from_options_or_dask_config(
    drives: Path, certs: Path, tmp_path: Path
) -> None:
    one = hdrd("evaluate", str(drives), "--json", str(tmp_path / "one.json"))
    assert one.returncode == 0, one.stderr
    files = {
        "--tls-ca-file": certs / "ca.pem",
        "--tls-cert": certs / "node.pem",
        "--tls-key": certs / "node.key",
    }
    with serving("serve-tls", "2", str(certs)) as address:
        assert address.startswith("tls://"), address
        opts = [x for flag, f in files.items() for x in (flag, str(f))]
        out = tmp_path / "tls.json"
        two = hdrd("evaluate", str(drives), "--scheduler", address, "--json", str(out), *opts)
        assert two.returncode == 0, two.stderr
        assert two.stdout == one.stdout
        assert out.read_bytes() == (tmp_path / "one.json").read_bytes()
        # the same files from the Dask configuration (here its environment variables)
        conf = {
            **ENV,
            "DASK_DISTRIBUTED__COMM__TLS__CA_FILE": str(files["--tls-ca-file"]),
            "DASK_DISTRIBUTED__COMM__TLS__CLIENT__CERT": str(files["--tls-cert"]),
            "DASK_DISTRIBUTED__COMM__TLS__CLIENT__KEY": str(files["--tls-key"]),
        }
        three = hdrd("evaluate", str(drives), "--scheduler", address, env=conf)
        assert three.returncode == 0, three.stderr
        assert three.stdout == one.stdout
        # a scheduler whose certificate the authority given did not sign: refused
        other = [*opts[:1], str(certs / "stranger.pem"), *opts[2:]]
        line = one_error(hdrd("evaluate", str(drives), "--scheduler", address, *other))
        assert f"cannot reach the Dask scheduler at {address}: TLS certificate" in line
        # the TLS scheduler by plain TCP, and by TLS without certificates: one line each
        plain = address.replace("tls://", "tcp://")
        line = one_error(hdrd("evaluate", str(drives), "--scheduler", plain, env=QUICK))
        assert line.startswith(f"hdrd evaluate: error: cannot reach the Dask scheduler at {plain}")
        line = one_error(hdrd("evaluate", str(drives), "--scheduler", address))
        assert "TLS needs the cluster's CA certificate and a client certificate" in line
        assert "--tls-ca-file" in line and "distributed.comm.tls.ca-file" in line


@pytest.mark.slow
def test_listeners_that_are_not_a_scheduler_are_one_line_errors(
    drives: Path, certs: Path, tmp_path: Path
) -> None:
    with serving("fake", "silent", "-") as address:
        line = one_error(hdrd("evaluate", str(drives), "--scheduler", address, env=QUICK))
        assert line == (
            f"hdrd evaluate: error: cannot reach the Dask scheduler at {address}: no answer "
            "within 3 s (distributed.comm.timeouts.connect)"
        )
    with serving("fake", "garbage", "-") as address:
        line = one_error(hdrd("evaluate", str(drives), "--scheduler", address, env=QUICK))
        assert address in line
    marker = tmp_path / "unpickled"
    with serving("fake", "pickle", str(marker)) as address:
        tls = address.replace("tcp://", "tls://")
        opts = ["--tls-ca-file", str(certs / "ca.pem"), "--tls-cert", str(certs / "node.pem")]
        opts += ["--tls-key", str(certs / "node.key")]
        # by TLS, it cannot show a certificate of the cluster's authority: nothing unpickled
        line = one_error(hdrd("evaluate", str(drives), "--scheduler", tls, *opts, env=QUICK))
        assert not marker.exists()
        # by plain TCP, the client unpickles what it sends: code of the listener's choosing
        # ran in the client (the trust model says so); the command still ends in one line
        line = one_error(hdrd("evaluate", str(drives), "--scheduler", address, env=QUICK))
        assert marker.exists()
        assert address in line


@pytest.mark.slow
def test_every_scheme_but_tcp_and_tls_is_one_line(drives: Path) -> None:
    for address in ("ucx://127.0.0.1:8786", "inproc://x", "ws://127.0.0.1:1", "foo://h:1"):
        line = one_error(hdrd("evaluate", str(drives), "--scheduler", address))
        scheme = address.split(":")[0]
        assert f"the {scheme}:// scheme is not supported" in line
    line = one_error(hdrd("evaluate", str(drives), "--scheduler", "tcp://[::1"))
    assert "not an address" in line
    line = one_error(hdrd("evaluate", str(drives), "--tls-cert", "x.pem"))
    assert line.endswith("the --tls-* options are for a tls:// --scheduler")
    p = hdrd("evaluate", str(drives), "--scheduler", "tcp://127.0.0.1:9", "--tls-cert", "x.pem")
    assert one_error(p).endswith("--tls-* options need a tls:// scheduler address, not "
                                 "tcp://127.0.0.1:9")  # fmt: skip
    p = hdrd("evaluate", str(drives), "--scheduler", "tls://127.0.0.1:9",
             "--tls-ca-file", "missing-ca.pem", "--tls-cert", "missing.pem")  # fmt: skip
    line = one_error(p)
    assert "cannot load the TLS files (CA missing-ca.pem, certificate missing.pem" in line


def test_plain_tcp_to_another_machine_is_warned_about() -> None:
    for address in ("tcp://10.0.0.5:8786", "10.0.0.5:8786", "tcp://sched.example:8786"):
        w = scheduler_warning(address)
        assert w is not None and w.startswith(f"{address} is plain TCP to another machine")
    for address in ("tcp://127.0.0.1:8786", "tcp://localhost:8786", "tcp://[::1]:8786"):
        assert scheduler_warning(address) is None
    assert scheduler_warning("tls://10.0.0.5:8786") is None


@pytest.mark.slow
def test_the_warning_comes_before_the_attempt(drives: Path) -> None:
    p = hdrd("evaluate", str(drives), "--scheduler", "tcp://192.0.2.1:8786", env=QUICK)
    line = one_error(p, warned=True)
    assert "192.0.2.1:8786" in line
    assert p.stderr.startswith(
        "hdrd evaluate: warning: tcp://192.0.2.1:8786 is plain TCP to another machine"
    )
