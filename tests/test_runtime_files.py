"""What a vehicle or node process leaves behind it and reads at its edges
(``sim_vehicles/runtime``), over random contents:

- a row log reads back every row appended, bit for bit, once closed; while open, the rows of
  every whole block flushed; cut at any byte (a process killed mid-write), its complete rows and
  no partial one; a file that is not one, or a row of the wrong width, is one line naming it;
- a counter file and a file of named counts read back, at every step and from another reader
  while the writer still holds them, what was counted; anything else reads as no counts;
- an event log is one JSON line per event, with its time, kind, source and fields, flushed as
  it comes; without a path it counts and writes nothing;
- a secret file is its owner's alone, from its creation;
- a datagram on loopback is stamped by the kernel between its sending and its reading, a socket
  says whether one waits, and a read that blocks waits its timeout and no longer than it may.
"""

import json
import os
import socket
import stat
import struct
import time

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from sim_vehicles.runtime import udp_arrival
from sim_vehicles.runtime.counter_file import CounterFile, NamedCounts, read_counter, read_named_counts
from sim_vehicles.runtime.event_log import EventLog
from sim_vehicles.runtime.row_log import MAGIC, RowLog, RowLogError, read_rows
from sim_vehicles.runtime.secret_file import write_secret

pytestmark = pytest.mark.unit

_cell = st.floats(allow_nan=True, allow_infinity=True, width=64)
_names = st.lists(st.text(min_size=1, max_size=6), min_size=1, max_size=5, unique=True)


@settings(max_examples=60, deadline=None)
@given(
    width=st.integers(1, 5),
    n=st.integers(0, 12),
    flush_rows=st.integers(1, 5),
    data=st.data(),
)
def test_a_row_log_reads_back_its_rows_whole_blocks_while_open_and_complete_rows_when_cut(
    width, n, flush_rows, data, tmp_path_factory
):
    path = tmp_path_factory.mktemp("rows") / "log.rows"
    columns = [f"c{k}" for k in range(width)]
    rows = np.array([data.draw(st.lists(_cell, min_size=width, max_size=width)) for _ in range(n)]).reshape(
        n, width
    )
    log = RowLog(path, columns, flush_rows=flush_rows)
    for k, row in enumerate(rows):
        split = data.draw(st.integers(0, width))  # a row given in two parts, a tuple and an array
        log.append(tuple(row[:split]), row[split:])
        cols, got = read_rows(path)
        flushed = (k + 1) // flush_rows * flush_rows
        assert cols == columns and got.shape == (flushed, width)
        np.testing.assert_array_equal(got, rows[:flushed])
    log.close()
    log.close()  # (a second close is nothing)
    _, got = read_rows(path)
    assert got.tobytes() == rows.astype("<f8").tobytes()
    whole = path.read_bytes()
    cut = data.draw(st.integers(whole.index(b"\n") + 1, len(whole)))
    path.write_bytes(whole[:cut])
    _, got = read_rows(path)
    complete = (cut - whole.index(b"\n") - 1) // (8 * width)
    assert got.tobytes() == rows[:complete].astype("<f8").tobytes()


def test_a_row_log_of_no_columns_reads_as_no_rows(tmp_path):
    log = RowLog(tmp_path / "none.rows", [])
    log.close()
    columns, rows = read_rows(tmp_path / "none.rows")
    assert columns == [] and rows.shape == (0, 0)


def test_a_row_of_the_wrong_width_and_a_file_that_is_no_row_log_are_one_line(tmp_path):
    log = RowLog(tmp_path / "truth.rows", ["a", "b", "c"])
    with pytest.raises(ValueError, match=r"^truth\.rows: row has 4 values, expected 3$"):
        log.append((1.0, 2.0), np.array([3.0, 4.0]))
    log.close()
    for name, content, says in (
        ("empty", b"", "not a row log"),
        ("other", b"PK\x03\x04 a zip\n", "not a row log"),
        ("headless", MAGIC + b'{"columns": [1, 2]', "not a row log"),  # no end to its header
        ("bad", MAGIC + b"{columns}\n", "row log header is unreadable"),
        ("nokey", MAGIC + b'{"cols": ["a"]}\n', "row log header is unreadable"),
    ):
        (tmp_path / name).write_bytes(content)
        with pytest.raises(RowLogError) as e:
            read_rows(tmp_path / name)
        assert str(e.value) == f"{tmp_path / name}: {says}"


@settings(max_examples=40, deadline=None)
@given(steps=st.lists(st.tuples(st.booleans(), st.integers(-(2**40), 2**40)), max_size=10))
def test_a_counter_file_holds_what_was_counted_at_every_step(steps, tmp_path_factory):
    path = tmp_path_factory.mktemp("count") / "sent.count"
    path.write_bytes(b"an old file, longer than a count")
    c = CounterFile(path)
    want = 0
    assert read_counter(path) == 0
    for is_set, n in steps:
        if is_set:
            c.set(n)
            want = n
        else:
            c.add(n)
            want += n
        assert c.value == want and read_counter(path) == want  # read beside the writer
    c.add()
    assert read_counter(path) == want + 1
    c.close()
    assert read_counter(path) == want + 1
    assert read_counter(path.with_name("none")) is None
    path.write_bytes(b"\x00" * 7)
    assert read_counter(path) is None


def test_count_files_are_plain_files_others_may_read_and_a_count_may_hold_any_byte(tmp_path):
    """Created as 0644 under the umask (the supervisor, or another user's tool, reads them; none
    is executable), even over an old file; a count whose bytes hold a line feed (10) reads back."""
    umask = os.umask(0o022)
    os.umask(umask)
    (tmp_path / "old.count").write_bytes(b"x")
    os.chmod(tmp_path / "old.count", 0o700)
    CounterFile(tmp_path / "one.count").close()
    counts = NamedCounts(tmp_path / "named.counts", ["a", "b"])
    counts.values[:] = [10, 0x0A0A]
    for name in ("one.count", "named.counts"):
        assert stat.S_IMODE((tmp_path / name).stat().st_mode) == 0o644 & ~umask
    assert read_named_counts(tmp_path / "named.counts") == {"a": 10, "b": 0x0A0A}


@settings(max_examples=40, deadline=None)
@given(names=_names, data=st.data())
def test_named_counts_read_back_by_name_and_a_view_writes_through(names, data, tmp_path_factory):
    path = tmp_path_factory.mktemp("counts") / "edges.counts"
    counts = NamedCounts(path, names)
    assert read_named_counts(path) == dict.fromkeys(names, 0)
    want = dict.fromkeys(names, 0)
    for name in names:
        v = data.draw(st.integers(-(2**62), 2**62))
        counts.values[counts.index[name]] += v
        want[name] += v
    a = data.draw(st.integers(0, len(names) - 1))
    b = data.draw(st.integers(a + 1, len(names)))
    view = counts.view(names[a:b])
    view += 1
    for name in names[a:b]:
        want[name] += 1
    assert read_named_counts(path) == want
    head = path.read_bytes().split(b"\n")[0] + b"\n"
    assert len(head) % 8 == 0 and json.loads(head[len(b"COUNTS1 ") :]) == names
    counts.close()
    with pytest.raises(AssertionError):
        counts.view([names[0], names[0]] if len(names) == 1 else [names[-1], names[0]])


@pytest.mark.parametrize(
    "content",
    [
        b"",
        b'COUNTS1 ["a"]  \n',  # a header of 16 bytes and no count
        b'COUNTS1 ["a"]\n' + bytes(8),  # a header not padded to 8 bytes
        b'COUNTS1 {"a": 1}\n' + bytes(8),  # names not a list
        b"COUNTS1 [a]    \n" + bytes(8),  # not JSON
        b'ROWLOG1 ["a"]  \n' + bytes(8),
        b'COUNTS1 ["a"]  ' + bytes(8),  # no end to its header
    ],
)
def test_a_file_that_is_not_named_counts_reads_as_none(tmp_path, content):
    (tmp_path / "x").write_bytes(content)
    assert read_named_counts(tmp_path / "x") is None
    assert read_named_counts(tmp_path / "missing") is None


def test_an_event_log_is_one_flushed_json_line_per_event_and_without_a_path_only_counts(tmp_path):
    log = EventLog(tmp_path / "events.jsonl", "vehicle_2")
    log.add(1.0000000004, "mode", mode="HOLD", reason="setpoint lost")
    assert json.loads((tmp_path / "events.jsonl").read_text()) == {  # flushed: readable at once
        "t_s": 1.0,
        "kind": "mode",
        "source": "vehicle_2",
        "mode": "HOLD",
        "reason": "setpoint lost",
    }
    log.add(2.5, "armed")
    log.add(3.1234567891, "disarmed")  # (times to the nanosecond)
    log.close()
    log.close()
    lines = [json.loads(x) for x in (tmp_path / "events.jsonl").read_text().splitlines()]
    assert [(x["kind"], x["t_s"]) for x in lines] == [
        ("mode", 1.0),
        ("armed", 2.5),
        ("disarmed", 3.123456789),
    ]
    assert log.count == 3
    nowhere = EventLog(None, "controller_1")
    nowhere.add(0.0, "start")
    nowhere.close()
    assert nowhere.count == 1 and sorted(p.name for p in tmp_path.iterdir()) == ["events.jsonl"]


def test_a_secret_file_is_its_owners_alone_and_replaces_an_old_one(tmp_path):
    write_secret(tmp_path / "first.key", "new")  # (none there before)
    assert (tmp_path / "first.key").read_text() == "new"
    path = tmp_path / "signing.key"
    path.write_text("old")
    os.chmod(path, 0o644)
    write_secret(path, "passphrase")
    assert path.read_text() == "passphrase"
    assert stat.S_IMODE(path.stat().st_mode) == 0o600 and path.stat().st_uid == os.getuid()


@pytest.fixture
def udp_pair():
    rx = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    rx.bind(("127.0.0.1", 0))
    tx = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    tx.bind(("127.0.0.1", 0))
    yield rx, tx
    rx.close()
    tx.close()


def test_a_datagram_is_stamped_between_its_sending_and_its_reading(udp_pair):
    rx, tx = udp_pair
    assert udp_arrival.enable(rx)
    waiting = udp_arrival.Waiting(rx)
    udp_arrival.block_reads(rx, 0)
    assert not waiting()
    with pytest.raises(BlockingIOError):
        udp_arrival.recv(rx, udp_arrival.wall_to_monotonic_s())
    for k in range(3):
        before = time.monotonic()
        tx.sendto(b"datagram %d" % k, rx.getsockname())
        time.sleep(0.2)
        assert waiting()
        read_at = time.monotonic()
        data, addr, arrived = udp_arrival.recv(rx, udp_arrival.wall_to_monotonic_s())
        assert data == b"datagram %d" % k and addr == tx.getsockname()
        # stamped when it came, not when it was read 200 ms later. On loopback it comes as it is
        # sent, or, on a loaded machine, when the kernel's deferred receive work runs (seen 25 ms
        # late on a 2-core CI machine): the upper bound leaves it 100 ms, and a stamp taken at the
        # read still fails it by 100 ms. The kernel's stamp is on the realtime clock, moved to the
        # monotonic one by two readings that a busy machine may take apart by a few milliseconds.
        assert before - 0.005 <= arrived <= read_at - 0.1
        assert not waiting()


def test_where_poll_is_missing_a_socket_still_says_whether_a_datagram_waits(udp_pair, monkeypatch):
    """(Not Linux: ``select`` without ``poll``.) The same answers, asked of ``select.select``."""
    import select
    import types

    monkeypatch.setattr(udp_arrival, "select", types.SimpleNamespace(select=select.select))
    rx, tx = udp_pair
    waiting = udp_arrival.Waiting(rx)
    assert not waiting()
    tx.sendto(b"x", rx.getsockname())
    time.sleep(0.02)
    assert waiting() and waiting()  # (asking reads nothing)
    rx.recv(16)
    assert not waiting()


def test_a_socket_without_stamps_dates_its_datagrams_when_read(udp_pair):
    rx, tx = udp_pair
    tx.sendto(b"x", rx.getsockname())
    time.sleep(0.02)
    before = time.monotonic()
    _, _, arrived = udp_arrival.recv(rx, udp_arrival.wall_to_monotonic_s())
    assert before <= arrived <= time.monotonic()
    tcp = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
    assert not udp_arrival.enable(tcp)
    tcp.close()


@pytest.mark.parametrize("timeout_s", [0.05, 1.25])
def test_a_blocking_read_is_given_its_timeout_and_a_non_blocking_one_none(udp_pair, timeout_s):
    rx, _ = udp_pair
    udp_arrival.block_reads(rx, timeout_s)
    sec, usec = struct.unpack("@ll", rx.getsockopt(socket.SOL_SOCKET, socket.SO_RCVTIMEO, 16))
    # the kernel keeps the timeout in its own ticks, rounded up: at most one tick (1/HZ, HZ >= 100) more
    assert timeout_s - 1e-6 <= sec + usec * 1e-6 <= timeout_s + 0.01 and rx.getblocking()
    udp_arrival.block_reads(rx, 0)
    assert struct.unpack("@ll", rx.getsockopt(socket.SOL_SOCKET, socket.SO_RCVTIMEO, 16)) == (0, 0)
    assert not rx.getblocking()
