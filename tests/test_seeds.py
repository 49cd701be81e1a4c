"""One seed for a run (``config.seeds``): every random stream takes the run's ``seed`` unless its
section pins its own; a campaign's seeds, ``--seed`` and ``Swarm(seed=)`` move every stream that is
not pinned, and the same seed flies the same."""

import numpy as np
import pytest
import yaml

from swarm_sitl.campaigns.grid import point_data
from swarm_sitl.config.load import parse_config, with_seed
from swarm_sitl.config.seeds import STREAMS, seed_lines
from tests.support import CONFIGS


def _paper() -> dict:
    return yaml.safe_load((CONFIGS / "paper.yaml").read_text())


@pytest.mark.unit
@pytest.mark.parametrize("run_seed", [0, 3, 2**40 + 7])
def test_every_stream_takes_the_run_seed_unless_its_section_pins_one(run_seed):
    data = {**_paper(), "seed": run_seed}
    cfg = parse_config(data, "paper")
    assert cfg.seed_streams() == {name: (run_seed, False) for name in STREAMS}
    assert (cfg.faults.seed, cfg.law.seed, cfg.wind.seed, cfg.vehicle.sensors.seed) == (run_seed,) * 4
    data["wind"] = {"seed": 11}
    pinned = parse_config(data, "paper")
    assert pinned.seed_streams()["wind"] == (11, True)
    assert {n: s for n, (s, p) in pinned.seed_streams().items() if not p} == dict.fromkeys(
        ("faults", "law", "sensors"), run_seed
    )
    assert "wind 11 (pinned by its section)" in seed_lines(pinned)[0]
    streams = ", ".join(f"{n} {run_seed}" for n in STREAMS)
    assert seed_lines(cfg) == [f"seeds: run {run_seed}; streams: {streams}"]  # none pinned: nothing more


@pytest.mark.unit
def test_a_written_config_keeps_following_its_run_seed_and_keeps_what_it_pins():
    data = _paper()
    data["vehicle"]["sensors"] = {"seed": 4}
    cfg = parse_config({**data, "seed": 9}, "paper")
    again = parse_config(yaml.safe_load(yaml.safe_dump(cfg.data())), "config.yaml")
    assert again == cfg and again.seed_streams() == cfg.seed_streams()
    moved = with_seed(again, 21)
    assert moved.seed_streams() == {
        "faults": (21, False),
        "law": (21, False),
        "wind": (21, False),
        "sensors": (4, True),
    }


@pytest.mark.unit
def test_a_campaign_point_moves_every_stream_its_base_does_not_pin():
    base = parse_config(_paper(), "paper").data()
    for s in (0, 1, 5):
        cfg = parse_config(point_data(base, {}, s), "sweep")
        assert {n: v for n, (v, _) in cfg.seed_streams().items()} == dict.fromkeys(STREAMS, s)


@pytest.mark.integration
def test_three_seeds_fly_three_gust_and_noise_series_and_a_seed_twice_flies_the_same():
    """In gusts and noisy reports, each seed of a campaign flies its own air and noise (every
    follower's path differs from the other seeds' by more than rounding) and seed 1 again flies
    what seed 1 flew, bit for bit; with gusts alone, and noise alone, the seeds differ as well."""
    from swarm_sitl.running.sim import run_sim

    def flown(air: bool, noise: bool, seed: int) -> dict[int, np.ndarray]:
        data = {**_paper(), "duration_s": 1.0}
        if air:
            data["wind"] = {"gust_mps": 1.0, "gust_time_s": 0.3}
            data["vehicle"] = {**data["vehicle"], "drag_Ns2pm2": 0.05}
        if noise:
            data["vehicle"] = {**data["vehicle"], "sensors": {"position_noise_m": 0.02}}
        cfg = parse_config(point_data(parse_config(data, "paper").data(), {}, seed), "sweep")
        rec = run_sim(cfg)
        return {i: a["p_W"] for i, a in rec.followers.items()}

    for air, noise in ((True, True), (True, False), (False, True)):
        runs = [flown(air, noise, s) for s in (0, 1, 2)]
        for a, b in ((0, 1), (0, 2), (1, 2)):
            for i in runs[a]:
                assert np.abs(runs[a][i] - runs[b][i]).max() > 1e-6, (air, noise, a, b, i)
        again = flown(air, noise, 1)
        assert all(np.array_equal(again[i], runs[1][i]) for i in again)


@pytest.mark.unit
def test_a_config_without_a_seed_flies_every_stream_at_0_as_before_the_run_seed():
    """The committed campaigns and configs name no run seed: each stream keeps its old default."""
    data = _paper()
    assert "seed" not in data
    cfg = parse_config(data, "paper")
    assert cfg.seed == 0 and cfg.seed_streams() == {name: (0, False) for name in STREAMS}
