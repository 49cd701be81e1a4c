"""The page's HTTP server: the page and its assets from the installed package, and the document.

``ViewServer`` serves, on ``127.0.0.1`` unless told another address (nothing listens elsewhere
by default):

- ``/``, ``/view.js``, ``/view.css``: the page (``static/``, installed with the package: nothing
  comes from the internet);
- ``/document.json``: the whole document so far (``replay``: its layout);
- ``/frames.json?from=F&events=E``: a live run's frames from frame ``F`` and events from ``E`` on,
  whether it is done, its real-time factor and whether it is paused;
- ``POST /control?pause=toggle`` or ``?step=1``: a lockstep run paused, resumed or stepped.

Each request is answered by a thread of its own from what the source holds (``DocumentSource``):
a slow, closed or misbehaving browser never waits on the run, and the run never waits on it. A
request the server does not know is answered 404 or 400 with one line; the standard library's
request parser answers a malformed request line itself.
"""

import errno
import threading
from http import HTTPStatus
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from importlib import resources
from typing import Protocol
from urllib.parse import parse_qs, urlsplit

ASSETS = {
    "/": ("index.html", "text/html; charset=utf-8"),
    "/index.html": ("index.html", "text/html; charset=utf-8"),
    "/view.js": ("view.js", "text/javascript; charset=utf-8"),
    "/view.css": ("view.css", "text/css; charset=utf-8"),
}
REQUEST_TIMEOUT_S = 10.0  #: a client that sends nothing for this long is let go


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


class _Handler(BaseHTTPRequestHandler):
    source: DocumentSource
    served: list[int]  #: requests answered so far (one element: shared by the server's threads)
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

    def do_GET(self) -> None:
        self.served[0] += 1
        url = urlsplit(self.path)
        if url.path in ASSETS:
            name, kind = ASSETS[url.path]
            self._send(HTTPStatus.OK, _asset(name), kind)
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
        url = urlsplit(self.path)
        if url.path != "/control":
            self._send(HTTPStatus.NOT_FOUND, f"no {url.path[:80]} here\n".encode())
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
        self._served = [0]
        handler = type("Handler", (_Handler,), {"source": source, "served": self._served})
        try:
            self.httpd = ThreadingHTTPServer((host, port), handler)
        except OSError as e:
            if e.errno == errno.EADDRINUSE:
                raise ViewError(
                    f"port {port} on {host} is in use: give another (0 picks a free one)"
                ) from None
            raise ViewError(f"cannot serve the page on {host}:{port} ({e.strerror or e})") from None
        self.httpd.daemon_threads = True
        self._thread = threading.Thread(target=self.httpd.serve_forever, name="view", daemon=True)

    @property
    def url(self) -> str:
        host, port = self.httpd.server_address[:2]
        return f"http://{host!s}:{port}/"

    @property
    def requests(self) -> int:
        """The requests answered so far."""
        return self._served[0]

    def start(self) -> "ViewServer":
        self._thread.start()
        return self

    def close(self) -> None:
        if self._thread.is_alive():
            self.httpd.shutdown()
        self.httpd.server_close()
