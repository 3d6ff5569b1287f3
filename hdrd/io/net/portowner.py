"""Who holds a UDP port on this machine, for a message when a command cannot bind it (``hdrd
tail`` on the port an ``hdrd web`` started earlier holds): ``/proc/net/udp`` and
``/proc/net/udp6`` name each bound socket's inode, and a process's ``/proc/PID/fd`` links name
the sockets it holds. Linux; best effort: another user's processes are not visible without
privilege, and a machine without /proc gives nothing.
"""

from __future__ import annotations

import os
from pathlib import Path

from hdrd.errors import clipped
from hdrd.io.files.access import printable

__all__ = ["udp_port_holders"]

UDP_TABLES = ("/proc/net/udp", "/proc/net/udp6")


def _inodes(port: int, tables: tuple[str, ...]) -> set[str]:
    """The inodes of the UDP sockets bound to ``port`` (any address), from the kernel's
    tables: ``sl local_address rem_address st ... uid timeout inode``, the address's port in
    hex after its last colon."""
    found: set[str] = set()
    for table in tables:
        try:
            lines = Path(table).read_text().splitlines()[1:]
        except OSError:
            continue
        for line in lines:
            fields = line.split()
            if len(fields) < 10:
                continue
            try:
                bound = int(fields[1].rpartition(":")[2], 16)
            except ValueError:
                continue
            if bound == port and fields[9] != "0":
                found.add(fields[9])
    return found


def _command(proc: Path) -> str:
    """A process's command line as a user would type it (``python -m hdrd web ...`` and
    ``python /usr/bin/hdrd web ...`` both ``hdrd web ...``), printable, at most 80 chars."""
    try:
        raw = (proc / "cmdline").read_bytes()
    except OSError:
        return "?"
    argv = [a.decode("utf-8", "replace") for a in raw.split(b"\0") if a]
    if not argv:
        return "?"
    if len(argv) >= 3 and argv[1] == "-m":  # python -m MODULE ...
        argv = argv[2:]
    elif len(argv) >= 2 and os.path.basename(argv[0]).startswith("python"):
        argv = argv[1:]  # python SCRIPT ...
    return clipped(printable(" ".join([os.path.basename(argv[0]), *argv[1:]])), 80)


def udp_port_holders(
    port: int, proc: str | os.PathLike[str] = "/proc", tables: tuple[str, ...] = UDP_TABLES
) -> list[tuple[int, str]]:
    """(pid, command line) of each process this user can see holding a UDP socket bound to
    ``port``, by pid; empty when none is visible."""
    wanted = {f"socket:[{inode}]" for inode in _inodes(port, tables)}
    if not wanted:
        return []
    found: list[tuple[int, str]] = []
    for entry in Path(proc).iterdir():
        if not entry.name.isdigit():
            continue
        try:
            fds = os.listdir(entry / "fd")
        except OSError:  # gone, or another user's
            continue
        for fd in fds:
            try:
                link = os.readlink(entry / "fd" / fd)
            except OSError:
                continue
            if link in wanted:
                found.append((int(entry.name), _command(entry)))
                break
    return sorted(found)
