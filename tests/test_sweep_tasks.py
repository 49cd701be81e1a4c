"""What a campaign hands its runs and what it draws (``campaigns.sweep``), its runs stood in for:
each task carries its own point's config (the file ``points/NAME.yaml`` holds), the plug-in files,
the wall budget and, asked, its kept run directory; a row names its point's file; the runs go to
this machine's pool with the jobs asked, or to a cluster's client, closed at the end; the
figures are the heat map for two varied keys and an error chart per varied key."""

import json
import re
from pathlib import Path

import pytest
import yaml

import swarm_sitl.campaigns.sweep as sweep_mod
from swarm_sitl.campaigns.point import METRICS
from tests.support import BLACKOUT_MODEL, config_data, users_plugins

pytestmark = pytest.mark.integration

MODEL_KEY = "link.blackout.py:Blackout.dark"  # (a user's model: a key with capitals and a colon)


def _metrics(task) -> dict:
    loss = yaml.safe_load(task.config_yaml)["seed"] / 10
    return {m: ("" if m == "failure" else loss) for m in METRICS} | {"passed": 1}


def _setup(tmp_path, monkeypatch) -> Path:
    """A config of the paper's with a user's law (``my_law.py``) beside it, and a user's link
    model (``blackout.py``) in the working directory."""
    monkeypatch.chdir(tmp_path)
    users_plugins(tmp_path)
    (tmp_path / "blackout.py").write_text(BLACKOUT_MODEL)
    data = config_data("paper")
    data["law"] = {"entry": "my_law.py:ConsensusPD", "params": {}}
    data["duration_s"] = 30.0
    (tmp_path / "c.yaml").write_text(yaml.safe_dump(data))
    return tmp_path / "c.yaml"


def _expected_name(point: dict, seed: int) -> str:
    """A point's file name, made here: its values and seed, every character a file name may not
    hold on any system made ``_``."""
    text = "_".join([f"{k}-{v:.12g}" for k, v in point.items()] + [f"seed-{seed}"])
    return "".join(c if c.isascii() and (c.isalnum() or c in "._-") else "_" for c in text)


def test_each_task_carries_its_points_config_files_budget_and_kept_directory(tmp_path, monkeypatch):
    config = _setup(tmp_path, monkeypatch)
    handed: list = []

    def runs(tasks, jobs):
        handed.append((list(tasks), jobs))
        for t in tasks:
            yield t, _metrics(t)

    monkeypatch.setattr(sweep_mod, "run_local", runs)
    monkeypatch.setattr(sweep_mod, "draw", lambda c: [])
    out = tmp_path / "camp"
    vary = {MODEL_KEY: [0.1, 0.3], "link.delay_s": [0.05]}
    c = sweep_mod.sweep(
        config, vary, out=out, seeds=[0, 2], bound_m=0.5, jobs=3, keep_runs=True, point_timeout_s=33.0
    )
    ((tasks, jobs),) = handed
    assert jobs == 3 and len(tasks) == 4 == len(c.rows)
    law = (tmp_path / "my_law.py").read_bytes()
    model = (tmp_path / "blackout.py").read_bytes()
    for t in tasks:
        data = yaml.safe_load(t.config_yaml)
        point = {MODEL_KEY: t.key[0], "link.delay_s": t.key[1]}
        assert t.name == _expected_name(point, data["seed"]) and re.fullmatch(r"[A-Za-z0-9._-]+", t.name)
        assert (out / "points" / f"{t.name}.yaml").read_text() == t.config_yaml
        assert t.keep_dir == str(out / "runs" / t.name) and t.timeout_s == 33.0
        assert sorted(t.plugins.values()) == sorted([law, model])
        shipped = {"entry": "plugins/blackout.py:Blackout", "params": {"dark": point[MODEL_KEY]}}
        assert shipped in [e["model"] for e in data["faults"]["plan"] if "model" in e]
    assert len({t.name for t in tasks}) == 4 and {t.key[-1] for t in tasks} == {0, 2}
    for row in c.rows:
        (t,) = [t for t in tasks if t.key == (row[MODEL_KEY], row["link.delay_s"], row["seed"])]
        assert row["config"] == f"points/{t.name}.yaml" and row["max_error_m"] == row["seed"] / 10


def test_a_campaign_on_a_cluster_hands_its_tasks_to_the_client_and_closes_it(tmp_path, monkeypatch):
    config = _setup(tmp_path, monkeypatch)

    class Client:
        closed = False

        def close(self):
            self.closed = True

    client = Client()
    given: list = []

    def runs(tasks, c):
        given.append((tasks, c))
        for t in tasks:
            yield t, _metrics(t)

    monkeypatch.setattr(
        sweep_mod, "connect", lambda address, timeout_s: client if address == "tcp://h:8786" else None
    )
    monkeypatch.setattr(sweep_mod, "run_dask", runs)
    monkeypatch.setattr(sweep_mod, "run_local", lambda *a: pytest.fail("ran here"))
    monkeypatch.setattr(sweep_mod, "draw", lambda c: [])
    c = sweep_mod.sweep(
        config, {"link.loss": [0.0, 0.2]}, out=tmp_path / "d", seeds=1, bound_m=0.5, scheduler="tcp://h:8786"
    )
    ((tasks, used),) = given
    assert used is client and client.closed and len(tasks) == 2 == len(c.rows)
    assert all(t.keep_dir is None for t in tasks)  # (a cluster's runs are not kept here)


@pytest.mark.parametrize(
    ("keys", "figures"),
    [
        (["link.loss"], ["error_vs_link.loss.png"]),
        (
            ["link.loss", "link.delay_s"],
            ["heat_map.png", "error_vs_link.loss.png", "error_vs_link.delay_s.png"],
        ),
        (["link.delay_s", "link.loss"], ["error_vs_link.loss.png"]),  # (delay held at one value)
    ],
)
def test_a_campaign_draws_a_heat_map_for_two_varied_keys_and_a_chart_per_varied_key(tmp_path, keys, figures):
    values = {"link.loss": [0.0, 0.1], "link.delay_s": [0.0, 0.2] if len(figures) == 3 else [0.0]}
    rows = [
        {"link.loss": a, "link.delay_s": b, "seed": 0, "passed": int(a == 0.0), "max_error_m": 0.01 + a}
        for a in values["link.loss"]
        for b in values["link.delay_s"]
    ]
    out = tmp_path / "campaign_x"
    out.mkdir()
    drawn = sweep_mod.draw(sweep_mod.Campaign(out, keys, 0.05, rows))
    assert drawn == [out / f for f in figures]
    assert all(p.read_bytes()[:4] == b"\x89PNG" for p in drawn)
    assert sorted(p.name for p in out.iterdir()) == sorted(figures)


def test_a_campaign_widened_again_runs_only_what_it_lacks_and_records_the_union(tmp_path, monkeypatch):
    """The same campaign again with more values and seeds: only the new points run (whatever
    order the done ones come in), ``campaign.json`` holds every value and seed either run asked,
    and each task's wall budget is the default: its start, ten times its duration and a minute."""
    config = _setup(tmp_path, monkeypatch)
    handed: list = []

    def runs(tasks, jobs):
        handed.append(list(tasks))
        for t in tasks:
            yield t, _metrics(t)

    monkeypatch.setattr(sweep_mod, "run_local", runs)
    monkeypatch.setattr(sweep_mod, "draw", lambda c: [])
    out = tmp_path / "w"
    sweep_mod.sweep(config, {"link.loss": [0.1, 0.3]}, out=out, seeds=[0], bound_m=0.5)
    c = sweep_mod.sweep(config, {"link.loss": [0.0, 0.1, 0.2, 0.3]}, out=out, seeds=[0, 1], bound_m=0.5)
    first, second = ([(t.key[0], t.key[1]) for t in ts] for ts in handed)
    assert sorted(first) == [(0.1, 0), (0.3, 0)]  # (then a done seed comes before one to run)
    assert sorted(second) == sorted({(v, s) for v in (0.0, 0.1, 0.2, 0.3) for s in (0, 1)} - set(first))
    assert len(c.rows) == 8
    recorded = json.loads((out / "campaign.json").read_text())
    assert recorded["values"] == {"link.loss": [0.0, 0.1, 0.2, 0.3]} and recorded["seeds"] == [0, 1]
    base = yaml.safe_load((out / "base.yaml").read_text())
    budget = base["run"]["start_timeout_s"] + 10 * base["duration_s"] + 60
    assert {t.timeout_s for ts in handed for t in ts} == {budget}


def test_an_out_that_is_a_file_or_holds_an_unreadable_campaign_is_one_line_naming_it(tmp_path, monkeypatch):
    config = _setup(tmp_path, monkeypatch)
    monkeypatch.setattr(sweep_mod, "run_local", lambda tasks, jobs: pytest.fail("ran"))
    (tmp_path / "file").write_text("x")
    with pytest.raises(
        sweep_mod.SweepSpecError, match=rf"^--out {tmp_path / 'file'}: exists and is not a directory$"
    ):
        sweep_mod.sweep(config, {"link.loss": [0.1]}, out=tmp_path / "file", seeds=1, bound_m=0.5)
    (tmp_path / "bad").mkdir()
    (tmp_path / "bad" / "campaign.json").write_text("{not json")
    with pytest.raises(
        sweep_mod.SweepSpecError, match=rf"^{tmp_path / 'bad' / 'campaign.json'}: cannot read it \("
    ):
        sweep_mod.sweep(config, {"link.loss": [0.1]}, out=tmp_path / "bad", seeds=1, bound_m=0.5)
