"""The page's pieces without a browser: the graph's layout (no node on another, up to 64
followers, every generated graph), a run directory as the page's document (frames against the
recorded arrays, the plan's windows, an older run without edge ages), the live feed (frames at
most 20 a second of simulated time, the oldest dropped past its bound) and the server (its
assets, its answers to bad requests, a port in use, the Host names it answers and the page that
may control a run)."""

import http.client
import itertools
import json
import random
import re
import socket
import urllib.error
import urllib.request

import numpy as np
import pytest

from swarm_sitl.bus.codec import Status
from swarm_sitl.config.generator import GRAPH_BUILDERS
from swarm_sitl.config.load import with_faults
from swarm_sitl.rundir.load import RunDirError
from swarm_sitl.rundir.outputs import write_outputs
from swarm_sitl.running.sim import run_sim
from swarm_sitl.view import frames, live
from swarm_sitl.view.layout import MARGIN_PX, NODE_PX, graph_layout, hops_from_leader
from swarm_sitl.view.replay import DOWN, FRAME_HZ, GRAPH_PX, ReplaySource, replay_document
from swarm_sitl.view.server import TOKEN_HEADER, ViewError, ViewServer
from tests.support import config


@pytest.mark.unit
@pytest.mark.parametrize("kind", sorted(GRAPH_BUILDERS))
@pytest.mark.parametrize("seed", [0, 1, 2])
def test_no_node_of_a_generated_graph_covers_another_up_to_64_followers(kind, seed):
    for n in (1, 4, 9, 16, 31, 32, 47, 64):
        edges = GRAPH_BUILDERS[kind](n, np.random.default_rng(seed))
        pos = graph_layout(n, edges, *GRAPH_PX)
        assert sorted(pos) == list(range(n + 1))
        for (a, pa), (b, pb) in itertools.combinations(pos.items(), 2):
            assert max(abs(pa[0] - pb[0]), abs(pa[1] - pb[1])) >= NODE_PX, (kind, n, a, b, pa, pb)
        for x, y in pos.values():
            assert MARGIN_PX - 1e-9 <= x <= GRAPH_PX[0] - MARGIN_PX + 1e-9
            assert MARGIN_PX - 1e-9 <= y <= GRAPH_PX[1] - MARGIN_PX + 1e-9


@pytest.mark.unit
def test_nodes_are_in_columns_by_hops_from_the_leader_when_they_fit():
    edges = [(0, 1), (0, 2), (1, 3), (2, 3), (3, 4)]  # hops 0, 1, 1, 2, 3; 5 (no path) last
    hops = hops_from_leader(5, edges)
    assert hops == {0: 0, 1: 1, 2: 1, 3: 2, 4: 3, 5: None}
    pos = graph_layout(5, edges, *GRAPH_PX)
    xs = [pos[i][0] for i in range(6)]
    assert xs[0] < xs[1] == xs[2] < xs[3] < xs[4] < xs[5]


@pytest.fixture(scope="module")
def cut_run(tmp_path_factory):
    """``sim`` of the paper's swarm, 5 s, edge 1->4 cut from 1 s to 2 s, written as ``run`` does."""
    d = tmp_path_factory.mktemp("run")
    plan = d / "plan.yaml"
    plan.write_text(
        json.dumps({"seed": 1, "plan": [{"edge": [1, 4], "drop": True, "from_s": 1, "until_s": 2}]})
    )
    cfg = with_faults(config("paper").model_copy(update={"duration_s": 5.0}), str(plan))
    rec = run_sim(cfg)
    out = d / "run"
    out.mkdir()
    write_outputs(cfg, rec, out)
    return cfg, rec, out


@pytest.mark.integration
def test_a_run_directory_is_the_pages_document_at_20_frames_a_second(cut_run):
    cfg, rec, out = cut_run
    doc = replay_document(out)
    t = np.array(doc["frames"]["t_s"])
    assert t[0] == 0.0 and t[-1] == pytest.approx(cfg.duration_s)
    assert np.all(np.diff(t) >= 1 / FRAME_HZ - 1e-9) and len(t) == int(cfg.duration_s * FRAME_HZ) + 1
    k = np.rint(t / cfg.control_dt_s).astype(int)
    for i, a in rec.followers.items():
        f = doc["frames"]["followers"][str(i)]
        np.testing.assert_allclose(np.array(f["p"], dtype=float), a["p_W"][k], atol=5e-4)  # (mm)
        np.testing.assert_allclose(f["err"], np.linalg.norm(a["pos_err_m"][k], axis=1), atol=5e-5)
        assert not any(s & DOWN for s in f["state"])
    edge = next(e for e in doc["edges"] if (e["src"], e["dst"]) == (1, 4))
    assert [(w["from_s"], w["until_s"]) for w in edge["faults"]] == [(1.0, 2.0)]
    ages = np.array(doc["frames"]["edge_age_s"]["1->4"], dtype=float)
    cut = (t >= 1.0 + 0.1) & (t < 2.0)  # the newest estimate of 1 it has ages while the edge is cut
    assert np.all(np.diff(ages[cut]) > 0) and np.all(ages[(t > 0.1) & (t < 1.0)] <= 2 * cfg.control_dt_s)
    assert json.loads(ReplaySource(doc).document()) == json.loads(json.dumps(doc))  # (strict JSON: no NaN)
    kinds = [e["kind"] for e in doc["events"]]  # (sim writes no events.jsonl: the plan's windows)
    assert kinds == ["fault_start", "fault_end"] and doc["events"][1]["t_s"] == 2.0


def _shape(doc: object) -> object:
    """A document's keys at every level, with a list standing for its length."""
    if isinstance(doc, dict):
        return {k: _shape(v) for k, v in doc.items()}
    return len(doc) if isinstance(doc, list) else type(doc).__name__


def _append_columns(to: dict, more: dict) -> None:
    """The page's merge of new frames (``view.js``'s ``appendColumns``), by name."""
    for k, v in more.items():
        if isinstance(v, list):
            to.setdefault(k, []).extend(v)
        else:
            _append_columns(to.setdefault(k, {}), v)


@pytest.mark.integration
def test_the_replay_and_the_live_feed_make_frames_of_the_one_declared_schema(cut_run, tmp_path):
    cfg, rec, out = cut_run
    replayed = replay_document(out)["frames"]
    ticks = np.rint(np.array(replayed["t_s"]) / cfg.control_dt_s).astype(int)
    feed = live.LiveFeed(cfg, tmp_path, True)
    grown = frames.no_frames()
    rng = np.random.default_rng(7)
    for k in ticks:  # every follower's status at the replay's frame ticks, read in random chunks
        t = k * cfg.control_dt_s
        st = {i: Status(i, int(k), t, t, a["p_W"][k]) for i, a in rec.followers.items()}
        err = {i: float(np.linalg.norm(a["pos_err_m"][k])) for i, a in rec.followers.items()}
        feed.update(st, err, set())
        if rng.random() < 0.3:
            _append_columns(grown, json.loads(feed.frames_since(len(grown["t_s"]), 0))["frames"])
    _append_columns(grown, json.loads(feed.frames_since(len(grown["t_s"]), 0))["frames"])
    whole = json.loads(feed.document())["frames"]
    assert grown == whole  # the page's merge by name rebuilds the document from its pieces
    assert tuple(whole) == tuple(replayed) == frames.FRAME_COLUMNS
    for doc in (whole, replayed):
        assert all(tuple(f) == frames.FOLLOWER_COLUMNS for f in doc["followers"].values())
    live_shape, replay_shape = _shape(whole), _shape(replayed)
    assert live_shape["followers"] == replay_shape["followers"]  # (edges: live has the followers' only)
    assert whole["t_s"] == replayed["t_s"] and whole["followers"] == {
        i: {**f, "err": whole["followers"][i]["err"]} for i, f in replayed["followers"].items()
    }
    for i, f in replayed["followers"].items():  # (the replay's error is recorded, the feed's given)
        np.testing.assert_allclose(np.array(whole["followers"][i]["err"], float), f["err"], atol=1e-4)


@pytest.mark.unit
def test_the_page_reads_only_the_frame_columns_the_schema_declares():
    from pathlib import Path

    import swarm_sitl.view

    js = (Path(swarm_sitl.view.__file__).parent / "static" / "view.js").read_text()
    read = set(re.findall(r"(?:doc\.frames|\bF)\.(\w+)", js))
    assert read and read <= set(frames.FRAME_COLUMNS), read - set(frames.FRAME_COLUMNS)
    for column in frames.FOLLOWER_COLUMNS:  # each follower column is drawn
        assert re.search(rf"\b\w\.{column}\[", js), column
    with pytest.raises(ValueError, match="a follower's columns are"):
        frames.follower_columns(p=[], err=[], state=[], extra=[])
    with pytest.raises(ValueError, match="frame columns are"):
        frames.frame_columns(t_s=[], leader=[], followers={})


@pytest.mark.integration
def test_a_run_made_before_edge_ages_were_recorded_reads_without_them(cut_run, tmp_path):
    _, _, out = cut_run
    old = tmp_path / "old"
    old.mkdir()
    for p in out.iterdir():
        if p.suffix == ".npz" and p.stem.startswith("follower_"):
            arrays = dict(np.load(p))
            arrays.pop("in_age_s")
            np.savez(old / p.name, **arrays)
        elif p.is_file():
            (old / p.name).write_bytes(p.read_bytes())
    doc = replay_document(old)
    assert doc["frames"]["edge_age_s"] == {} and len(doc["frames"]["t_s"]) > 0


@pytest.mark.unit
def test_a_directory_that_is_not_a_run_is_one_line(tmp_path):
    with pytest.raises(RunDirError, match=r"not a run directory \(no config\.yaml\)"):
        replay_document(tmp_path)
    with pytest.raises(RunDirError, match="no such directory"):
        replay_document(tmp_path / "nothing")


@pytest.mark.unit
def test_the_live_feed_makes_at_most_20_frames_a_simulated_second_and_drops_the_oldest(monkeypatch, tmp_path):
    cfg = config("paper")
    monkeypatch.setattr(live, "MAX_FRAMES", 50)
    feed = live.LiveFeed(cfg, tmp_path, True)
    monkeypatch.setattr(feed, "_frames", live.deque(maxlen=50))
    errors = {f.id: 0.01 * f.id for f in cfg.followers}  # (the monitor's, passed on as they are)
    for k in range(0, 1000, 3):  # statuses every 3 ticks, followers 1..4; 3 down from 8.5 s to 9 s
        t = k * cfg.control_dt_s
        st = {f.id: Status(f.id, k, t, t, np.asarray(f.offset_m, dtype=float)) for f in cfg.followers}
        feed.update(st, errors, down={3} if 850 <= k < 900 else set())
    doc = json.loads(feed.document())
    t = np.array(doc["frames"]["t_s"])
    assert len(t) == 50 and doc["frame0"] > 0  # the oldest dropped
    assert np.all(np.diff(t) >= 1 / FRAME_HZ - 1e-9)
    three, one = doc["frames"]["followers"]["3"], doc["frames"]["followers"]["1"]
    down = (t >= 8.5) & (t < 9.0)
    assert down.any() and (~down).any()
    assert all(
        s & DOWN and e is None for s, e, d in zip(three["state"], three["err"], down, strict=True) if d
    )
    assert all(
        s == 0 and e == 0.03 for s, e, d in zip(three["state"], three["err"], down, strict=True) if not d
    )
    assert set(one["err"]) == {0.01} and set(one["state"]) == {0}
    more = json.loads(feed.frames_since(doc["frame0"] + 45, 0))
    assert more["frames"]["t_s"] == doc["frames"]["t_s"][45:]
    assert doc["events"] == more["events"] == [] and more["done"] is False  # what the page reads of them


@pytest.mark.unit
def test_a_live_feed_hands_pause_and_step_to_a_lockstep_runs_hold_and_a_frame_to_each_step(tmp_path):
    cfg = config("paper")
    dt = cfg.control_dt_s

    def statuses(k: int) -> dict[int, Status]:
        return {f.id: Status(f.id, k, k * dt, k * dt, np.zeros(3)) for f in cfg.followers}

    assert live.LiveFeed(cfg, tmp_path, False).control("toggle", 0) == (
        409,
        "a real-time run flies on the wall clock: pause and step are for a lockstep run",
    )
    feed = live.LiveFeed(cfg, tmp_path, True)
    hold = feed.hold
    assert hold is not None
    assert feed.control("toggle", 0) == (200, "pausing the run")  # (asked before the run acts on it)
    hold.act(statuses(100), set(), 0.0)  # the run's session is not open yet: nothing put
    puts: list[int] = []
    hold.put = puts.append
    feed.update(statuses(100), {}, set())
    for now in (0.0, 0.1, 0.45):  # (every follower there for longer than SETTLE_S; no put again)
        hold.act(statuses(100), set(), now)
    feed.update(statuses(100), {}, set())
    more = json.loads(feed.frames_since(0, 0))
    assert more["paused"] and more["held_s"] == 1.0 and puts == [100]
    for j in (1, 2):  # a step of one tick is a frame of its own (flying: one each 1 / FRAME_HZ)
        assert feed.control(None, 1)[0] == 200
        hold.act(statuses(99 + j), set(), 1.0 + j)
        feed.update(statuses(100 + j), {}, set())
    assert json.loads(feed.frames_since(0, 0))["frames"]["t_s"] == [1.0, 1.01, 1.02] and puts == [
        100,
        101,
        102,
    ]
    feed.finish()
    assert feed.control("toggle", 0) == (409, "the run is over")


@pytest.mark.unit
def test_the_server_serves_the_page_from_the_package_and_answers_bad_requests_in_one_line(cut_run):
    _, _, out = cut_run
    server = ViewServer(ReplaySource(replay_document(out))).start()
    try:
        get = lambda path: urllib.request.urlopen(server.url + path, timeout=5)  # noqa: E731
        assert b"<canvas" in get("").read() and b"function" in get("view.js").read()
        assert json.loads(get("document.json").read())["followers"] == [1, 2, 3, 4]
        for path in ("document.json", "frames.json?from=0&events=0"):  # JSON, never cached, its length
            r = get(path)
            body = r.read()
            assert r.headers["Content-Type"] == "application/json" and json.loads(body) is not None
            assert r.headers["Cache-Control"] == "no-store" and int(r.headers["Content-Length"]) == len(body)
        for path, code in (("nowhere", 404), ("frames.json?from=-1", 400), ("frames.json?from=x", 400)):
            with pytest.raises(urllib.error.HTTPError) as e:
                get(path)
            assert e.value.code == code and len(e.value.read().decode().strip().splitlines()) == 1
        post = lambda q: urllib.request.Request(  # noqa: E731
            server.url + "control?" + q, method="POST", headers={TOKEN_HEADER: server.token}
        )
        with pytest.raises(urllib.error.HTTPError) as e:  # a POST anywhere else: one line naming it
            urllib.request.urlopen(urllib.request.Request(server.url + "elsewhere", method="POST"), timeout=5)
        assert e.value.code == 404 and e.value.read().decode().splitlines() == ["no /elsewhere here"]
        for q, code in (("pause=toggle", 409), ("step=1", 409), ("step=-1", 400), ("nothing=1", 409)):
            with pytest.raises(urllib.error.HTTPError) as e:
                urllib.request.urlopen(post(q), timeout=5)  # a finished run is not paused
            assert e.value.code == code and len(e.value.read().decode().strip().splitlines()) == 1
        with socket.create_connection(server.httpd.server_address[:2], timeout=5) as s:  # garbage
            s.sendall(b"\x00\xffnot http at all\r\n\r\n")
            assert b"Error response" in s.recv(200)  # (the standard library's answer)
        assert get("document.json").status == 200  # still serving
        with pytest.raises(ViewError, match="is in use"):
            ViewServer(ReplaySource({}), port=server.httpd.server_address[1])
    finally:
        server.close()


def _raw(server: ViewServer, method: str, path: str, headers: dict[str, str]) -> tuple[int, bytes]:
    """One request with exactly ``headers`` (``Host`` among them, or none)."""
    conn = http.client.HTTPConnection(*server.httpd.server_address[:2], timeout=5)
    try:
        conn.putrequest(method, path, skip_host=True, skip_accept_encoding=True)
        for k, v in headers.items():
            conn.putheader(k, v)
        conn.endheaders()
        r = conn.getresponse()
        return r.status, r.read()
    finally:
        conn.close()


@pytest.mark.unit
def test_the_server_answers_only_its_own_names_and_takes_control_only_from_its_own_page(cut_run):
    """DNS rebinding and cross-origin requests: a request whose Host is not one of the server's
    names (its address, localhost, 127.0.0.1, [::1], each with its port) is 403 with one line,
    whatever the path or method; a control request is taken only with the page's own Origin or
    the token the page holds (a finished run answers 409 once taken), never with another origin,
    another scheme or port, a wrong token or neither. Random names and origins, seeded."""
    _, _, out = cut_run
    server = ViewServer(ReplaySource(replay_document(out))).start()
    port = server.httpd.server_address[1]
    rng = random.Random(53)
    own = [f"127.0.0.1:{port}", f"localhost:{port}", f"LocalHost:{port}", f"[::1]:{port}"]
    words = ["evil", "attacker", "127.0.0.1", "localhost", "example", "rebind", "0", "com", "nip.io"]
    foreign = [
        f"attacker.example:{port}",
        f"127.0.0.1:{port + 1}",
        "127.0.0.1",
        f"localhost.evil.com:{port}",
        f"127.0.0.1.nip.io:{port}",
        f"[::1]:{port + 1}",
        f"127.0.0.2:{port}",
        "",
    ] + [f"{'.'.join(rng.choices(words, k=rng.randint(2, 4)))}:{port}" for _ in range(20)]
    try:
        page = _raw(server, "GET", "/", {"Host": own[0]})
        assert page[0] == 200
        token = re.search(rb'name="control-token" content="([^"]+)"', page[1])
        assert token is not None and token.group(1).decode() == server.token
        for host in own:
            assert _raw(server, "GET", "/document.json", {"Host": host})[0] == 200
        refused = 0
        for host in foreign:
            for method, path in (("GET", "/"), ("GET", "/document.json"), ("POST", "/control?pause=on")):
                status, body = _raw(server, method, path, {"Host": host} if host else {})
                assert status == 403 and len(body.decode().strip().splitlines()) == 1, (host, path)
                refused += 1
        good_origins = [f"http://{h}" for h in own]
        bad_origins = [
            "http://evil.example",
            f"http://attacker.example:{port}",
            f"https://127.0.0.1:{port}",
            f"http://127.0.0.1:{port + 1}",
            f"http://127.0.0.1:{port}/x",
            "null",
            "",
        ]
        for origin in good_origins:  # taken: a finished run cannot be held (409)
            assert _raw(server, "POST", "/control?pause=on", {"Host": own[0], "Origin": origin})[0] == 409
        assert (
            _raw(server, "POST", "/control?pause=on", {"Host": own[1], TOKEN_HEADER: server.token})[0] == 409
        )
        for origin in bad_origins:
            wrong = server.token[:-1] + ("y" if server.token.endswith("x") else "x")  # (1 in 64 ended in x)
            for extra in ({}, {TOKEN_HEADER: wrong}, {TOKEN_HEADER: ""}):
                headers = {"Host": own[0], **({"Origin": origin} if origin else {}), **extra}
                status, body = _raw(server, "POST", "/control?pause=on", headers)
                assert status == 403 and len(body.decode().strip().splitlines()) == 1, (origin, extra)
                refused += 1
        assert server.refused == refused
    finally:
        server.close()


@pytest.mark.integration
def test_thousands_of_requests_leave_a_live_feed_and_its_server_answering(tmp_path):
    """Eight clients send 1040 requests, good and bad, while the supervisor's side feeds frames:
    every request is answered (200, 400 or 404), every frame the feed was given is there, and the
    server answers after."""
    from concurrent.futures import ThreadPoolExecutor

    cfg = config("paper")
    feed = live.LiveFeed(cfg, tmp_path, True)
    server = ViewServer(feed).start()
    paths = ["document.json", "frames.json?from=0&events=0", "frames.json?from=zz", "x" * 3000, "view.js"]

    def client(c: int) -> list[int]:
        codes = []
        for k in range(130):
            try:
                with urllib.request.urlopen(server.url + paths[(c + k) % len(paths)], timeout=10) as r:
                    r.read()
                    codes.append(r.status)
            except urllib.error.HTTPError as e:
                codes.append(e.code)
        return codes

    try:
        with ThreadPoolExecutor(8) as pool:
            answers = [pool.submit(client, c) for c in range(8)]
            n = 200
            for k in range(n):  # the supervisor's side, meanwhile: a frame per status
                t = k / FRAME_HZ
                feed.update({f.id: Status(f.id, k, t, t, np.zeros(3)) for f in cfg.followers}, {}, set())
            codes = [code for a in answers for code in a.result()]
        assert len(codes) == 1040 and set(codes) <= {200, 400, 404, 414}
        assert len(json.loads(feed.document())["frames"]["t_s"]) == n
        with urllib.request.urlopen(server.url + "document.json", timeout=5) as r:
            assert r.status == 200
    finally:
        server.close()
