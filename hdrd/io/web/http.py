"""HTTP for ``hdrd web``, pure: a request's head parsed, whom a connection counts against,
which ``Host`` a loopback server serves, and the responses with their security headers (a
content security policy that lets the page run only its own script and connect only to its own
server). :mod:`hdrd.io.web.webserver` serves with them.
"""

from __future__ import annotations

import ipaddress
from collections.abc import Sequence
from dataclasses import dataclass

__all__ = [
    "STREAM_HEAD",
    "Request",
    "host_allowed",
    "http_response",
    "is_loopback",
    "parse_request",
    "peer_key",
]

_CSP = (
    "default-src 'none'; script-src 'self'; style-src 'self'; img-src 'self'; "
    "connect-src 'self'; base-uri 'none'; form-action 'none'; frame-ancestors 'none'"
)
_HEADERS = (
    f"Content-Security-Policy: {_CSP}",
    "X-Content-Type-Options: nosniff",
    "X-Frame-Options: DENY",
    "Referrer-Policy: no-referrer",
)
_REASONS = {
    200: "OK",
    400: "Bad Request",
    403: "Forbidden",
    404: "Not Found",
    405: "Method Not Allowed",
    408: "Request Timeout",
    431: "Request Header Fields Too Large",
    503: "Service Unavailable",
}


@dataclass(frozen=True, slots=True)
class Request:
    """A request's method, path (no query) and ``Host`` header (None: not sent)."""

    method: str
    path: str
    host: str | None


def parse_request(head: bytes) -> Request | None:
    """A request line and its headers (without the blank line), or None when malformed:
    not ``METHOD /target HTTP/1.x``, a header line without a colon or with space before it,
    two ``Host`` headers."""
    lines = head.decode("latin-1").split("\r\n")
    parts = lines[0].split(" ")
    if len(parts) != 3 or parts[2] not in ("HTTP/1.0", "HTTP/1.1"):
        return None
    method, target, _ = parts
    if not (method.isascii() and method.isalpha() and method.isupper()):
        return None
    if not target.startswith("/"):
        return None
    host: str | None = None
    for line in lines[1:]:
        name, sep, value = line.partition(":")
        if not sep or not name or name != name.strip():
            return None
        if name.lower() == "host":
            if host is not None:
                return None
            host = value.strip()
    return Request(method, target.split("?", 1)[0].split("#", 1)[0], host)


def peer_key(address: str) -> str:
    """Whom the per-peer bound counts a connection against: its IPv4 address, or its IPv6
    address's /64 (one host may hold a whole /64); the address as given if it is none."""
    try:
        ip = ipaddress.ip_address(address.split("%", 1)[0])
    except ValueError:
        return address
    if isinstance(ip, ipaddress.IPv6Address):
        if ip.ipv4_mapped is not None:
            return str(ip.ipv4_mapped)
        return str(ipaddress.ip_network(f"{ip}/64", strict=False))
    return str(ip)


def is_loopback(address: str) -> bool:
    """Whether an IP address (an IPv6 one may carry ``%zone``) is a loopback address."""
    try:
        return ipaddress.ip_address(address.split("%", 1)[0]).is_loopback
    except ValueError:
        return False


def host_allowed(host: str | None, local: bool) -> bool:
    """Whether a request's ``Host`` may be served: always unless the server listens on a
    loopback address, then only ``localhost`` (and its subdomains) or a loopback address (no
    ``Host``, as HTTP/1.0 may send, is taken)."""
    if not local or host is None:
        return True
    if host.startswith("["):
        name = host[1 : host.find("]")] if "]" in host else ""
    else:
        name = host.rsplit(":", 1)[0] if host.count(":") == 1 else host
    name = name.lower().rstrip(".")
    return name == "localhost" or name.endswith(".localhost") or is_loopback(name)


def http_response(
    status: int,
    body: bytes = b"",
    content_type: str = "text/plain; charset=utf-8",
    headers: Sequence[str] = (),
) -> bytes:
    """A whole response that closes the connection: status line, the security headers,
    ``headers``, the body."""
    lines = [
        f"HTTP/1.1 {status} {_REASONS.get(status, 'Error')}",
        f"Content-Type: {content_type}",
        f"Content-Length: {len(body)}",
        "Cache-Control: no-cache",
        "Connection: close",
        *_HEADERS,
        *headers,
    ]
    return ("\r\n".join(lines) + "\r\n\r\n").encode("latin-1") + body


STREAM_HEAD = (
    "\r\n".join(
        [
            "HTTP/1.1 200 OK",
            "Content-Type: text/event-stream",
            "Cache-Control: no-store",
            "Connection: keep-alive",
            *_HEADERS,
        ]
    )
    + "\r\n\r\nretry: 2000\n\n"
).encode("latin-1")
"""The head of a stream response, and the browser's reconnection delay (2 s)."""
