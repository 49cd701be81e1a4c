"""The page's HTTP server: the page and its assets from the installed package, and the document.

``ViewServer`` serves, on ``127.0.0.1`` unless told another address (nothing listens elsewhere
by default):

- ``/``, ``/view.js``, ``/view.css``: the page (``static/``, installed with the package: nothing
  comes from the internet);
- ``/document.json``: the whole document so far (``replay``: its layout);
- ``/frames.json?from=F&events=E``: a live run's frames from frame ``F`` and events from ``E`` on,
  whether it is done, its real-time factor and whether it is paused;
- ``POST /control?pause=toggle`` or ``?step=1``: a lockstep run paused, resumed or stepped.

**Other web pages.** Listening on loopback keeps other machines out, not other pages open in the
user's browser: any page may send a request to ``127.0.0.1``, and a DNS-rebinding page (its own
name re-pointed at ``127.0.0.1``) may read the answers. So, as Jupyter and Bokeh do:

- every request must name the server in its ``Host`` header: the address it was told to serve on
  (``--view-host``/``--host``), the address it is bound to, and for a loopback bind ``localhost``,
  ``127.0.0.1`` and ``[::1]``; with the port it listens on (``AllowedHosts``). Any other name is
  answered 403 with one line: a rebinding page reads nothing;
- ``POST /control``, the one request that changes anything, must come from the page's own origin
  (its ``Origin`` header, which a browser sets on every POST, is ``http://`` + an allowed host) or
  carry the server's token (``X-Swarm-Sitl-Token``; a random one per server, in the page it
  serves, so only a client that can read the page has it: a script may GET ``/`` and take it from
  the ``control-token`` meta tag). Otherwise 403 with one line: a cross-origin ``fetch`` (a
  "simple" request, sent without asking first) pauses nothing.

Each request is answered by a thread of its own from what the source holds (``DocumentSource``):
a slow, closed or misbehaving browser never waits on the run, and the run never waits on it. A
request the server does not know is answered 404 or 400 with one line; the standard library's
request parser answers a malformed request line itself.
"""

import contextlib
import errno
import ipaddress
import secrets
import socket
import threading
from dataclasses import dataclass
from http import HTTPStatus
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from importlib import resources
from typing import Any, Protocol
from urllib.parse import parse_qs, urlsplit

ASSETS = {
    "/": ("index.html", "text/html; charset=utf-8"),
    "/index.html": ("index.html", "text/html; charset=utf-8"),
    "/view.js": ("view.js", "text/javascript; charset=utf-8"),
    "/view.css": ("view.css", "text/css; charset=utf-8"),
}
REQUEST_TIMEOUT_S = 10.0  #: a client that sends nothing for this long is let go
TOKEN_HEADER = "X-Swarm-Sitl-Token"  #: the header a control request without the page's origin carries
_TOKEN_MARK = b"@CONTROL_TOKEN@"  #: where ``index.html`` holds the token


class ViewError(RuntimeError):
    """The page cannot be served (a port in use, an address that is not ours); one line."""


class DocumentSource(Protocol):
    """What the server reads (``replay.ReplaySource``, ``live.LiveFeed``)."""

    def document(self) -> bytes: ...
    def frames_since(self, frame: int, event: int) -> bytes: ...
    def control(self, pause: str | None, step: int) -> tuple[int, str]:
        """A page's pause or step: an HTTP status and one line."""
        ...


def _asset(name: str) -> bytes:
    return resources.files("swarm_sitl.view").joinpath("static", name).read_bytes()


def _is_loopback(host: str) -> bool:
    if host.lower() == "localhost":
        return True
    try:
        return ipaddress.ip_address(host.strip("[]")).is_loopback
    except ValueError:
        return False


def _name(host: str) -> str:
    """A host as the ``Host`` header writes it: lower case, an IPv6 address in brackets."""
    host = host.lower()
    return f"[{host}]" if ":" in host and not host.startswith("[") else host


def _host_and_port(header: str) -> tuple[str, str] | None:
    """``(name, port)`` of a ``Host`` header (``name``, ``name:port``, ``[v6]:port``); the port
    is 80 where it is not written. None: not a host."""
    h = header.strip().lower()
    if h.startswith("["):
        name, sep, rest = h.partition("]")
        name += sep
        if not sep or (rest and not rest.startswith(":")):
            return None
        port = rest[1:] if rest else "80"
    else:
        name, sep, port = h.partition(":")
        port = port if sep else "80"
    return (name, port) if name and port.isdigit() else None


@dataclass(frozen=True)
class AllowedHosts:
    """The names a request's ``Host`` (and a control request's ``Origin``) may give for a server
    on ``port`` (module docstring)."""

    names: frozenset[str]
    port: int

    @classmethod
    def of(cls, host: str, bound: str, port: int) -> "AllowedHosts":
        """For a server told ``host`` (``--view-host``), bound to address ``bound``. A wildcard
        bind (``0.0.0.0``, ``::``) also answers to this machine's own names."""
        names = {_name(host), _name(bound)}
        if _is_loopback(host) or _is_loopback(bound):
            names |= {"localhost", "127.0.0.1", "[::1]"}
        if bound in ("0.0.0.0", "::"):
            names |= {_name(socket.gethostname()), _name(socket.getfqdn())}
            with contextlib.suppress(OSError):  # (a host name that does not resolve: its names only)
                names |= {_name(str(a[4][0])) for a in socket.getaddrinfo(socket.gethostname(), None)}
        names.discard("")
        return cls(frozenset(names), port)

    def host_ok(self, header: str | None) -> bool:
        """Whether a ``Host`` header names this server (its port included, but for port 80)."""
        split = _host_and_port(header or "")
        return split is not None and split[0] in self.names and split[1] == str(self.port)

    def origin_ok(self, header: str | None) -> bool:
        """Whether an ``Origin`` header is this server's own page."""
        scheme, sep, rest = (header or "").partition("://")
        return bool(sep) and scheme.lower() == "http" and "/" not in rest and self.host_ok(rest)


class _Handler(BaseHTTPRequestHandler):
    source: DocumentSource
    served: list[int]  #: requests answered so far (one element: shared by the server's threads)
    refused: list[int]  #: requests answered 403 (as ``served``)
    allowed: AllowedHosts
    token: str
    timeout = REQUEST_TIMEOUT_S
    server_version = "swarm-sitl-view"

    def log_message(self, format: str, *args: object) -> None:  # (quiet: the run's terminal is the user's)
        pass

    def _send(self, status: int, body: bytes, kind: str = "text/plain; charset=utf-8") -> None:
        try:
            self.send_response(status)
            self.send_header("Content-Type", kind)
            self.send_header("Content-Length", str(len(body)))
            self.send_header("Cache-Control", "no-store")
            self.end_headers()
            self.wfile.write(body)
        except OSError:  # the browser went away mid-answer: nothing to tell it
            pass

    def _query_int(self, query: dict[str, list[str]], name: str) -> int:
        raw = query.get(name, ["0"])[0]
        if not raw.isdigit() or len(raw) > 12:
            raise ValueError(f"{name} must be a count, not {raw[:40]!r}")
        return int(raw)

    def _refuse(self, line: str) -> None:
        self.refused[0] += 1
        self._send(HTTPStatus.FORBIDDEN, f"{line}\n".encode())

    def _host_refused(self) -> bool:
        """Refuse (403) a request that does not name this server in its ``Host``."""
        host = self.headers.get("Host")
        if self.allowed.host_ok(host):
            return False
        self._refuse(
            f"this page is served as {', '.join(sorted(self.allowed.names))} port {self.allowed.port}, "
            f"not to Host {(host or 'none')[:80]!r}"
        )
        return True

    def do_GET(self) -> None:
        self.served[0] += 1
        if self._host_refused():
            return
        url = urlsplit(self.path)
        if url.path in ASSETS:
            name, kind = ASSETS[url.path]
            body = _asset(name)
            if name == "index.html":
                body = body.replace(_TOKEN_MARK, self.token.encode())
            self._send(HTTPStatus.OK, body, kind)
        elif url.path == "/document.json":
            self._send(HTTPStatus.OK, self.source.document(), "application/json")
        elif url.path == "/frames.json":
            query = parse_qs(url.query)
            try:
                frame, event = self._query_int(query, "from"), self._query_int(query, "events")
            except ValueError as e:
                self._send(HTTPStatus.BAD_REQUEST, f"{e}\n".encode())
                return
            self._send(HTTPStatus.OK, self.source.frames_since(frame, event), "application/json")
        else:
            self._send(HTTPStatus.NOT_FOUND, f"no {url.path[:80]} here\n".encode())

    def do_POST(self) -> None:
        self.served[0] += 1
        if self._host_refused():
            return
        url = urlsplit(self.path)
        if url.path != "/control":
            self._send(HTTPStatus.NOT_FOUND, f"no {url.path[:80]} here\n".encode())
            return
        origin, token = self.headers.get("Origin"), self.headers.get(TOKEN_HEADER)
        if not (
            self.allowed.origin_ok(origin)
            or (token is not None and secrets.compare_digest(token.encode(), self.token.encode()))
        ):
            self._refuse(
                "a control request comes from the page itself "
                + (f"(not from {origin[:80]!r})" if origin else f"or carries its {TOKEN_HEADER}")
            )
            return
        query = parse_qs(url.query)
        try:
            step = self._query_int(query, "step")
        except ValueError as e:
            self._send(HTTPStatus.BAD_REQUEST, f"{e}\n".encode())
            return
        pause = query.get("pause", [None])[0]
        status, line = self.source.control(pause, step)
        self._send(status, (line + "\n").encode())


class ViewServer:
    """The page of ``source`` on ``host:port`` (0: a free port), served from a thread of its own."""

    def __init__(self, source: DocumentSource, host: str = "127.0.0.1", port: int = 0):
        self._served, self._refused = [0], [0]
        self.token = secrets.token_urlsafe(24)  #: what a control request without the page's origin carries
        handler: Any = type(
            "Handler",
            (_Handler,),
            {"source": source, "served": self._served, "refused": self._refused, "token": self.token},
        )
        try:
            self.httpd = ThreadingHTTPServer((host, port), handler)
        except OSError as e:
            if e.errno == errno.EADDRINUSE:
                raise ViewError(
                    f"port {port} on {host} is in use: give another (0 picks a free one)"
                ) from None
            raise ViewError(f"cannot serve the page on {host}:{port} ({e.strerror or e})") from None
        self.httpd.daemon_threads = True
        bound, bound_port = self.httpd.server_address[:2]
        handler.allowed = AllowedHosts.of(host, str(bound), int(bound_port))
        self._thread = threading.Thread(target=self.httpd.serve_forever, name="view", daemon=True)

    @property
    def url(self) -> str:
        host, port = self.httpd.server_address[:2]
        return f"http://{host!s}:{port}/"

    @property
    def requests(self) -> int:
        """The requests answered so far."""
        return self._served[0]

    @property
    def refused(self) -> int:
        """The requests refused (403: another Host, or a control request from another page)."""
        return self._refused[0]

    def start(self) -> "ViewServer":
        self._thread.start()
        return self

    def close(self) -> None:
        if self._thread.is_alive():
            self.httpd.shutdown()
        self.httpd.server_close()
