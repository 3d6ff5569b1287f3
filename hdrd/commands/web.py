"""``hdrd web``: a live, read-only page of the heading, its mode and health (docs/web.md).

Parses the options, binds the page's TCP address and the UDP address the daemon sends to,
and runs :class:`hdrd.io.web.webserver.WebServer` until SIGTERM or SIGINT (status 0). A bad
address is a usage error (2); one that cannot be bound (in use, not this host's) a failure
(1).
"""

from __future__ import annotations

import argparse
import dataclasses
import socket
import sys

from hdrd import __version__
from hdrd.io.logs import log, setup_logging
from hdrd.io.net.datagrams import DEFAULT_TAIL_LISTEN, udp_listener
from hdrd.io.web.http import is_loopback
from hdrd.io.web.webserver import (
    DEFAULT_MAX_CLIENTS,
    DEFAULT_WEB_LISTEN,
    WebServer,
    WebSettings,
    descriptors,
    run_server,
    tcp_listener,
)

__all__ = ["main"]


def _bind(
    listen: str, udp: str
) -> tuple[tuple[socket.socket, str, bool], tuple[socket.socket, str]] | tuple[int, str]:
    """Both sockets, or (exit status, the line saying why not)."""
    try:
        http = tcp_listener(listen)
    except ValueError as e:
        return 2, f"hdrd web: bad --listen {listen!r}: {e}"
    except OSError as e:
        return 1, f"hdrd web: cannot listen on {listen}: {e.strerror or e}"
    try:
        return http, udp_listener(udp)
    except ValueError as e:
        http[0].close()
        return 2, f"hdrd web: bad --udp {udp!r}: {e}"
    except OSError as e:
        http[0].close()
        return 1, f"hdrd web: cannot listen on {udp} (UDP): {e.strerror or e}"


def _warn_not_local(shown: str, local: bool, udp_shown: str, udp_local: bool) -> None:
    """A warning for each address reachable from elsewhere."""
    if not local:
        log.warning(
            "web_listen_not_local",
            listen=shown,
            reason="anyone who can reach this address can watch the vehicle (read only); "
            "the default, 127.0.0.1, is this computer only",
        )
    if not udp_local:
        log.warning(
            "web_udp_not_local",
            udp=udp_shown,
            reason="anyone who can send to this address can put values on the page; "
            "the default, 127.0.0.1, is this computer only",
        )


def _fit_descriptors(settings: WebSettings) -> WebSettings:
    """``settings`` with as many streams as this process's descriptors allow (a note when
    fewer than asked)."""
    nofile, in_use, fitted = descriptors(settings.max_clients)
    if fitted == settings.max_clients:
        return settings
    log.warning(
        "web_max_clients_clamped",
        asked=settings.max_clients,
        max_clients=fitted,
        nofile=nofile,
        reason=f"{nofile} descriptors (RLIMIT_NOFILE, LimitNOFILE=) serve {fitted} at most; "
        "raise the limit for more",
    )
    return dataclasses.replace(settings, max_clients=fitted)


def main(args: argparse.Namespace) -> int:
    """``hdrd web [--listen HOST:PORT] [--udp HOST:PORT] [--max-clients N]``."""
    listen = getattr(args, "listen", None) or DEFAULT_WEB_LISTEN
    udp = getattr(args, "udp", None) or DEFAULT_TAIL_LISTEN
    try:
        settings = WebSettings(max_clients=getattr(args, "max_clients", DEFAULT_MAX_CLIENTS))
    except ValueError as e:
        print(f"hdrd web: --max-clients: {e}", file=sys.stderr)
        return 2
    bound = _bind(listen, udp)
    if isinstance(bound[0], int):
        print(bound[1], file=sys.stderr)
        return bound[0]
    (http_sock, shown, local), (udp_sock, udp_shown) = bound
    setup_logging()
    _warn_not_local(shown, local, udp_shown, is_loopback(str(udp_sock.getsockname()[0])))
    settings = _fit_descriptors(settings)
    server = WebServer(http_sock, udp_sock, local, udp_shown, settings, __version__)
    log.info("web_start", url=f"http://{shown}/", udp=udp_shown, max_clients=settings.max_clients)
    print(
        f"hdrd web: open http://{shown}/ (data from UDP {udp_shown}: "
        f"hdrd run --udp {udp_shown} sends there)",
        file=sys.stderr,
    )
    try:
        run_server(server)
    finally:
        http_sock.close()
        udp_sock.close()
    return 0
