"""A zenoh client session as a user's own tool opens one (zenoh's public API only, no project code)."""

import json

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
