"""The tests' one toolbox: where things are, the one way to run ``swarm-sitl`` as a user does, the
configs, free ports, processes, the guides' files, and the closed forms more than one test holds
code to. In-process fakes of the bench's interfaces are ``tests.fakes``. A test module imports
from here (and ``tests.fakes``, ``tests.strategies``), never from another test module
(``tests/test_suite_rules.py``)."""

import functools
import math
import re
import socket
import subprocess
import time
from pathlib import Path
from typing import Any

import numpy as np

from tests import cli_host

ROOT = Path(__file__).resolve().parents[1]
CONFIGS = ROOT / "configs"
#: ``swarm-sitl`` as this interpreter runs it
CLI = cli_host.CLI


# -- the command line --------------------------------------------------------------------------------
def cli(
    *args: object,
    timeout: float = 300,
    cwd: Any = None,
    env: dict[str, str] | None = None,
    fresh: bool = False,
) -> "subprocess.CompletedProcess[str]":
    """``swarm-sitl ARGS`` run to its end, its output captured, in working directory ``cwd`` with
    environment ``env`` (default: this process's). Forked from the worker's warm interpreter
    (``tests/cli_host.py``: the same process a new interpreter would be, without its second of
    imports); ``fresh``: a new interpreter, for what its start is part of."""
    argv = [str(a) for a in args]
    if fresh or not cli_host.forkable(env):
        return subprocess.run(
            [*CLI, *argv], capture_output=True, text=True, timeout=timeout, cwd=cwd, env=env
        )
    return cli_host.run(argv, timeout, cwd=cwd, env=env)


def cli_ok(*args: object, **kw: Any) -> "subprocess.CompletedProcess[str]":
    """``cli``, held to exit 0 with no traceback."""
    r = cli(*args, **kw)
    assert r.returncode == 0, (r.stderr + r.stdout)[-3000:]
    assert "Traceback" not in r.stderr, r.stderr[-3000:]
    return r


def start_cli(
    *args: object,
    cwd: Any = None,
    env: dict[str, str] | None = None,
    start_new_session: bool = True,
    **streams: Any,
) -> Any:
    """``swarm-sitl ARGS`` started, by default in its own session (a signal to the group reaches
    all of it), its output piped (``streams``: ``Popen``'s ``stdout`` and ``stderr`` in place of
    the pipes). Forked as ``cli`` is: what it returns has ``Popen``'s ``args``, ``pid``,
    ``stdout``, ``stderr``, ``poll``, ``wait``, ``communicate``, ``send_signal``, ``terminate``
    and ``kill``."""
    streams = {"stdout": subprocess.PIPE, "stderr": subprocess.PIPE, **streams}
    argv = [str(a) for a in args]
    how = {"text": True, "start_new_session": start_new_session, "cwd": cwd, "env": env, **streams}
    if not cli_host.forkable(env):
        return subprocess.Popen([*CLI, *argv], **how)
    return cli_host.ForkedCli(argv, **how)


# -- the configs ---------------------------------------------------------------------------------------
@functools.cache
def config(name: str) -> Any:
    """``configs/NAME.yaml`` as the bench loads it (a frozen ``SwarmConfig``: ``model_copy`` to vary it)."""
    from swarm_sitl.config.load import load_config

    return load_config(CONFIGS / f"{name}.yaml")


def config_data(name: str) -> dict:
    """``configs/NAME.yaml`` as a fresh mapping, to change and write out."""
    import yaml

    return yaml.safe_load((CONFIGS / f"{name}.yaml").read_text())


#: a user's law and vehicle model as files of their own folder: their entries, relative to it
USERS_LAW, USERS_VEHICLE = "my_law.py:ConsensusPD", "my_vehicle.py:LaggyVtol"


def users_plugins(folder: Path) -> None:
    """``USERS_LAW`` and ``USERS_VEHICLE``'s files in ``folder``: the example law and the vehicle
    model template, copied as a user's own."""
    import shutil

    shutil.copy(ROOT / "examples" / "laws" / "consensus_pd.py", folder / "my_law.py")
    shutil.copy(ROOT / "sim_vehicles" / "models" / "template.py", folder / "my_vehicle.py")


#: a user's link model in a file (the link-model contract: ``faults.link_model``), with one parameter:
#: messages lost while ``m.t_s`` is within the first ``dark`` of each second
BLACKOUT_MODEL = """
from pydantic import BaseModel, Field

from swarm_sitl.faults.link_model import Effect


class Blackout:
    class Params(BaseModel):
        dark: float = Field(ge=0, le=1)

    def fate(self, p, m):
        return Effect(lost=True) if (m.t_s % 1.0) < p.dark else None
"""


# -- ports and processes -------------------------------------------------------------------------------
def free_udp_port() -> int:
    """A loopback UDP port free now."""
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def udp_port_free(port: int) -> bool:
    """Whether loopback UDP ``port`` can be bound."""
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        try:
            s.bind(("127.0.0.1", port))
        except OSError:
            return False
    return True


def vehicle_ports(run_dir: Path) -> list[int]:
    """The ports a run's vehicles said they listen on, from their logs."""
    ports = []
    for log in sorted((run_dir / "logs").glob("vehicle_*.log")):
        m = re.search(r"listening on udp:[0-9.]+:(\d+)", log.read_text())
        if m:
            ports.append(int(m.group(1)))
    return ports


def wait_running(out: Path, followers: int = 4, timeout: float = 120.0) -> None:
    """Until every controller of the run writing ``out`` has recorded ticks."""
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        rows = [out / "procs" / f"controller_{i}.rows" for i in range(1, followers + 1)]
        if all(p.is_file() and p.stat().st_size > 20_000 for p in rows):
            return
        time.sleep(0.1)
    raise AssertionError("the run did not get going")


def vehicle(*args: object, timeout: float = 120) -> "subprocess.CompletedProcess[str]":
    """``python -m sim_vehicles ARGS`` run to its end, its output captured; forked as ``cli`` is."""
    return cli_host.run([str(a) for a in args], timeout, module="sim_vehicles")


def start_vehicle(*args: object, **streams: Any) -> Any:
    """``python -m sim_vehicles ARGS`` started, its standard output piped (``streams``: ``Popen``'s
    ``stdout`` and ``stderr`` otherwise); forked as ``cli`` is."""
    streams = {"stdout": subprocess.PIPE, **streams}
    return cli_host.ForkedCli([str(a) for a in args], text=True, module="sim_vehicles", **streams)


def spawn_vehicle(system_id: int, port: int, *extra: str) -> Any:
    """``python -m sim_vehicles`` at 20 m up on ``port``, once it says it listens."""
    proc = start_vehicle("--id", system_id, "--port", port, "--position", "0", "0", "20", *extra)
    assert proc.stdout is not None and "listening" in proc.stdout.readline()
    return proc


def cmdline(pid: int) -> str:
    """Process ``pid``'s command line ("" once it is gone)."""
    try:
        return Path(f"/proc/{pid}/cmdline").read_bytes().replace(b"\0", b" ").decode()
    except OSError:
        return ""


def ppid_and_sid(pid: int) -> tuple[int, int]:
    """Process ``pid``'s parent and session (``/proc/<pid>/stat``, after the command's brackets)."""
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return int(fields[1]), int(fields[3])


def processes_mentioning(text: str) -> list[int]:
    """Live processes whose command line contains ``text`` (a run directory): what a run left."""
    found = []
    for d in Path("/proc").iterdir():
        if not d.name.isdigit():
            continue
        try:
            cmd = (d / "cmdline").read_bytes().replace(b"\0", b" ").decode(errors="replace")
            state = (d / "stat").read_text().rsplit(")", 1)[1].split()[0]
        except OSError:
            continue
        if text in cmd and state != "Z":
            found.append(int(d.name))
    return found


# -- the guides -------------------------------------------------------------------------------------------
def page_files(text: str) -> dict[str, str]:
    """The files a guide in ``docs/`` gives: each ``<!-- file: NAME -->`` and the Python or YAML
    block after it."""
    return dict(re.findall(r"<!-- file: (\S+) -->\n```(?:python|yaml)\n(.*?)```", text, re.S))


def page_command(cmd: str, cwd: Path) -> "subprocess.CompletedProcess[str]":
    """A guide's ``swarm-sitl ...`` command line, run in ``cwd`` as ``cli`` runs one."""
    return cli(*cmd.split()[1:], cwd=cwd)


# -- PX4 SIH's quadrotor, and closed forms more than one test holds code to ----------------------------
def sih_quad() -> Any:
    """PX4 SIH's quadrotor as ``VehicleParams``: 1 kg, inertia 0.025, 0.025, 0.03 kg m^2, 4 x 5 N."""
    from sim_vehicles.plant.params import VehicleParams

    return VehicleParams(1.0, (0.025, 0.025, 0.03), 20.0)


def sih_roll_step(t: np.ndarray, rate_p: float, rate_d: float = 0.0) -> np.ndarray:
    """``roll_cascade_step`` on PX4 SIH's quadrotor with PX4's torque scale (the roll torque a
    normalised 1 asks: the effectiveness' pseudo-inverse, as PX4 normalises it)."""
    j = sih_quad().inertia_kgm2[0]
    return roll_cascade_step(t, sih_roll_torque_per_unit_Nm(), j, rate_p, rate_d=rate_d)


def sih_roll_torque_per_unit_Nm() -> float:
    """The roll torque a normalised 1 asks of PX4 SIH's quadrotor (PX4's torque scale)."""
    from sim_vehicles.plant.px4_allocation import normalized_mix, torque_per_unit_Nm
    from sim_vehicles.plant.rotors import effectiveness

    scale = normalized_mix(effectiveness(5.0, 0.1, 0.2, 0.2))[1]
    return float(torque_per_unit_Nm(scale)[0])


def roll_cascade_step(
    t: np.ndarray,
    torque_per_unit_Nm: float,
    inertia_kgm2: float,
    rate_p: float,
    att_p: float = 6.5,
    rate_d: float = 0.0,
) -> np.ndarray:
    """The unit step response from rest of PX4's roll cascade, linearised, P and D: ``J x'' = U
    (P_r (P_a (1 - x) - x') - D_r x'')``, i.e. ``x'' + 2 zeta wn x' + wn^2 x = wn^2`` with ``wn^2 = U
    P_r P_a / J'`` and ``2 zeta wn = U P_r / J'`` (``U``: the roll torque a normalised 1 asks; the D
    term adds ``U D_r`` to the inertia: ``J' = J + U D_r``), under- or overdamped."""
    inertia_kgm2 = inertia_kgm2 + torque_per_unit_Nm * rate_d
    a = torque_per_unit_Nm * rate_p / inertia_kgm2
    b = a * att_p  # x'' + a x' + b x = b
    disc = a * a / 4 - b
    if disc < 0:
        wd = math.sqrt(-disc)
        return 1 - np.exp(-a / 2 * t) * (np.cos(wd * t) + a / 2 / wd * np.sin(wd * t))
    r1, r2 = -a / 2 + math.sqrt(disc), -a / 2 - math.sqrt(disc)
    return 1 - (r2 * np.exp(r1 * t) - r1 * np.exp(r2 * t)) / (r2 - r1)


def start_paper_run(out: Path, *extra: object) -> "subprocess.Popen[str]":
    """``swarm-sitl run configs/paper.yaml --out OUT --quiet EXTRA``, started (``start_cli``)."""
    return start_cli("run", CONFIGS / "paper.yaml", "--out", out, "--quiet", *extra)


def cli_in_process(*args: object, stdout: Any = None) -> tuple[int, str, str]:
    """``swarm-sitl ARGS`` run in this process (``cli.main``): its exit code, standard output and
    error. For what fails before anything starts (a bad argument, config or space), where a new
    interpreter would only add its start-up; the signal handlers ``main`` installs are put back.
    ``stdout``: a stream of the caller's for its standard output (then given back as "")."""
    import contextlib
    import io
    import signal

    from swarm_sitl.cli import main

    saved = {s: signal.getsignal(s) for s in (signal.SIGTERM, signal.SIGHUP)}
    out, err = io.StringIO(), io.StringIO()
    try:
        with contextlib.redirect_stdout(out if stdout is None else stdout), contextlib.redirect_stderr(err):
            try:
                code = main([str(a) for a in args])
            except SystemExit as e:  # (argparse's own refusals)
                code = e.code if isinstance(e.code, int) else 2
    finally:
        for s, h in saved.items():
            signal.signal(s, h)
    return code, out.getvalue(), err.getvalue()


# -- falsify ----------------------------------------------------------------------------------------
class FixedTrial:
    """A sampler for ``falsify.space.plan_of`` that answers each suggestion from a table, by its
    full name or its last part (the low end where it has none), held within the bounds asked;
    every item on (the last choice)."""

    def __init__(self, values: dict[str, float]):
        self.values = values

    def suggest_float(self, name: str, low: float, high: float) -> float:
        v = self.values.get(name, self.values.get(name.rsplit(".", 1)[-1], low))
        assert low <= v <= high, (name, v)
        return v

    def suggest_categorical(self, name: str, choices: Any) -> Any:
        return list(choices)[-1]


# -- ROS 2 ------------------------------------------------------------------------------------------
def msg_files(ros_type: str) -> dict[str, str]:
    """The ``.msg`` text of ``ros_type`` and of each type it uses, by type name, split out of the
    definition rosbag2 stores (``MSG: pkg/Name`` sections; ROS 2's own files, as rosbags ships them)."""
    import re

    from swarm_sitl.ros2 import types

    parts = re.split(r"\n=+\n", types.message_definition(ros_type))
    files = {ros_type: parts[0]}
    for part in parts[1:]:
        head, _, body = part.partition("\n")
        pkg, name = head.removeprefix("MSG: ").strip().split("/")
        files[f"{pkg}/msg/{name}"] = body
    return files


def msg_dir(root: Path, ros_types: list[str]) -> Path:
    """``root`` holding the ``.msg`` files of ``ros_types`` as a ROS 2 package tree
    (``<pkg>/msg/<Name>.msg``: where zenoh-ros2-sdk's registry looks, instead of fetching them)."""
    for ros_type in ros_types:
        for t, body in msg_files(ros_type).items():
            pkg, _, name = t.split("/")
            (root / pkg / "msg").mkdir(parents=True, exist_ok=True)
            (root / pkg / "msg" / f"{name}.msg").write_text(body)
    return root


def ros2_user_session(run_dir: Path, timeout: float = 60.0) -> Any:
    """A raw zenoh session that joins a running run's router as its ROS 2 user (``ros2``), from
    its ``ros2_join.json`` (waited for up to ``timeout``)."""
    import json

    import zenoh

    join_file = run_dir / "ros2_join.json"
    end = time.monotonic() + timeout
    while not join_file.is_file() and time.monotonic() < end:
        time.sleep(0.01)
    join = json.loads(join_file.read_text())
    conf = zenoh.Config()
    password = Path(join["password_file"]).read_text().strip()
    for key, value in (
        ("mode", "client"),
        ("connect/endpoints", [join["endpoint"]]),
        ("scouting/multicast/enabled", False),
        ("transport/auth/usrpwd/user", join["user"]),
        ("transport/auth/usrpwd/password", password),
    ):
        conf.insert_json5(key, json.dumps(value))
    return zenoh.open(conf)


def fresh_ros2_client(monkeypatch: Any) -> None:
    """``zenoh-ros2-sdk`` as a new process has it: its session and its message registry are
    process-wide singletons (the registry keeps the first folder of ``.msg`` files it is given),
    so each test that uses it starts them again."""
    from zenoh_ros2_sdk import message_registry
    from zenoh_ros2_sdk.session import ZenohSession

    monkeypatch.setattr(ZenohSession, "_instance", None)
    monkeypatch.setattr(message_registry, "_registry", None)


def raw_frame(
    cls: Any, payload: bytes, crc_extra: int | None = None, sysid: int = 1, compid: int = 1
) -> bytes:
    """A plain MAVLink 2 frame of message class ``cls`` carrying ``payload`` (its trailing zeros
    dropped, as MAVLink 2 sends it), its CRC by pymavlink's own X.25 over ``crc_extra`` (default:
    the message's): a frame any payload makes, good or, with another CRC extra, bad."""
    from pymavlink.generator.mavcrc import x25crc

    while len(payload) > 1 and payload[-1] == 0:
        payload = payload[:-1]
    msg_id = cls.id
    ids = [msg_id & 0xFF, (msg_id >> 8) & 0xFF, msg_id >> 16]
    header = bytes([0xFD, len(payload), 0, 0, 0, sysid, compid, *ids])
    crc = x25crc(header[1:] + payload)
    crc.accumulate(bytes([cls.crc_extra if crc_extra is None else crc_extra]))
    return header + payload + crc.crc.to_bytes(2, "little")
