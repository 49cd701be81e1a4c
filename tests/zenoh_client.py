"""A zenoh client session as a user's own tool opens one (zenoh's public API only, no project code)."""

import json
import time

import zenoh


def client_session(endpoint: str, creds: tuple[str, str] | None) -> zenoh.Session:
    """A client of the router at ``endpoint``, authenticating with ``creds`` (user, password) if given."""
    c = zenoh.Config()
    c.insert_json5("mode", '"client"')
    c.insert_json5("connect/endpoints", json.dumps([endpoint]))
    c.insert_json5("scouting/multicast/enabled", "false")
    if creds is not None:
        c.insert_json5("transport/auth/usrpwd", json.dumps({"user": creds[0], "password": creds[1]}))
    return zenoh.open(c)


def client_session_once_up(endpoint: str, creds: tuple[str, str], within_s: float) -> zenoh.Session:
    """``client_session`` of a router that is starting: a client opened before the router listens is
    refused as one with wrong credentials is, so it tries again until ``within_s`` has passed (then
    raises zenoh's last error)."""
    end = time.monotonic() + within_s
    while True:
        try:
            return client_session(endpoint, creds)
        except zenoh.ZError:
            if time.monotonic() > end:
                raise
            time.sleep(0.1)
