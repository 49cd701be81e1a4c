"""The names the page's server answers to (``view.server.AllowedHosts``), for any address it is
told and bound to, any port and any way a ``Host`` header may write a name.

The rule, stated here on its own (the module docstring's): a server answers to the name it was
told and the address it is bound to, as a ``Host`` header writes them (lower case, an IPv6 address
in brackets); where either is a loopback name or address, to ``localhost``, ``127.0.0.1`` and
``[::1]`` as well; bound to a wildcard (``0.0.0.0``, ``::``), to this machine's own names and
addresses too; each with its port, which a header may leave out only for port 80. Nothing else:
no other name, no other port, no malformed header. An ``Origin`` is the page's own where it is
``http://`` and such a host, with no path.
"""

import contextlib
import socket

import pytest
from hypothesis import given
from hypothesis import strategies as st

from swarm_sitl.view.server import AllowedHosts
from tests.strategies import FUZZ

pytestmark = pytest.mark.unit

ADDRESSES = ["127.0.0.1", "127.0.0.2", "::1", "[::1]", "localhost", "LocalHost", "0.0.0.0", "::"]
OTHERS = ["10.1.2.3", "192.168.7.9", "fe80::2", "viewer.example", "Viewer.Example"]
LOOPBACK = {"localhost", "127.0.0.1", "[::1]"}
#: which of the names drawn are loopback: 127.0.0.0/8, ::1 (bare or bracketed), localhost in any case
IS_LOOPBACK = {"127.0.0.1", "127.0.0.2", "::1", "[::1]", "localhost", "LocalHost"}


def _written(name: str) -> str:
    name = name.lower()
    return f"[{name}]" if ":" in name and not name.startswith("[") else name


def _this_machine() -> set[str]:
    names = {_written(socket.gethostname()), _written(socket.getfqdn())}
    with contextlib.suppress(OSError):  # (a host name that does not resolve: its names only)
        names |= {_written(str(a[4][0])) for a in socket.getaddrinfo(socket.gethostname(), None)}
    return names


def _expected(host: str, bound: str) -> set[str]:
    names = {_written(host), _written(bound)}
    if host in IS_LOOPBACK or bound in IS_LOOPBACK:
        names |= LOOPBACK
    if bound in ("0.0.0.0", "::"):
        names |= _this_machine()
    return names - {""}


def _header(name: str, port: int, case: str) -> str:
    text = name if port == 80 and case == "no port" else f"{name}:{port}"
    return text.upper() if case == "upper" else f" {text} " if case == "spaced" else text


@FUZZ
@given(
    host=st.sampled_from(ADDRESSES + OTHERS),
    bound=st.sampled_from(ADDRESSES + OTHERS[:3]),
    port=st.sampled_from([80, 8080, 43117]),
    case=st.sampled_from(["as is", "upper", "spaced", "no port"]),
)
def test_a_server_answers_to_exactly_its_names_with_its_port(host, bound, port, case):
    allowed = AllowedHosts.of(host, bound, port)
    names = _expected(host, bound)
    candidates = (
        names | LOOPBACK | {_written(n) for n in ADDRESSES + OTHERS} | _this_machine() | {"evil.example"}
    )
    for name in candidates - {""}:
        ok = name in names
        assert allowed.host_ok(_header(name, port, case)) == ok, (name, case)
        assert not allowed.host_ok(f"{name}:{port + 1}")  # another port
        assert allowed.origin_ok(f"http://{name}:{port}") == ok
        assert not allowed.origin_ok(f"https://{name}:{port}") and not allowed.origin_ok(
            f"http://{name}:{port}/x"
        )
    if port != 80:
        assert not any(allowed.host_ok(n) for n in names)  # its port, written
    for bad in ("", ":80", "[::1", "[::1]x", "[::1]:", "[::1]]:80", f"localhost:{port}x", None):
        assert not allowed.host_ok(bad) and not allowed.origin_ok(bad and f"http://{bad}")
