"""Fig. 15 with one follower: ``python -m experiments.studies.comparison --fig15`` (study C,
``followers=1``, PPC and the last-seen controller of ref. [32]), its first-loss measure and its
tables."""

from __future__ import annotations

import re
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
from PIL import Image

import platoon_env
from experiments.grid import resolve_cells
from experiments.store import Store
from experiments.studies.comparison import (
    FIG15_FILE,
    FIG15_MEASURE,
    FIG15_POLICIES,
    FIG15_STUDY,
    fig15_cells,
    first_loss,
    first_loss_table,
    leader_corners,
    main,
    plot_last_seen_trace,
)
from platoon_env.geometry.sensing import SENSE_VISIBLE
from platoon_env.rollout import Episode
from platoon_env.safety import causes_to_mask


def _episode(visible: list[int], arrived: list[int] | None = None) -> Episode:
    """A one-follower episode of ``len(visible)`` samples, 0.1 s apart: the leader at
    ``(t, 1)``, the follower at ``(t, 0)``; ``visible[k]`` the camera flag at sample ``k``,
    the step into a sample without sight marked ``out_of_fov``; ``arrived`` the policy's
    signal at samples ``0 .. T - 1``."""
    n = len(visible)
    times = 0.1 * np.arange(n)
    poses = np.zeros((n, 2, 3))
    poses[:, 0, 0] = poses[:, 1, 0] = times
    poses[:, 0, 1] = 1.0
    sensed = np.zeros((n, 1, 9), dtype=np.float32)
    sensed[:, 0, SENSE_VISIBLE] = visible
    violations = np.zeros((n - 1, 1), dtype=np.int64)
    violations[np.asarray(visible[1:]) == 0, 0] = causes_to_mask(["out_of_fov"])
    signals = {} if arrived is None else {"arrived": np.asarray(arrived, bool)[:, None]}
    return Episode(
        scenario="study_c", seed=0, control_period=0.1, d_des=1.0, times=times, poses=poses,
        sensed=sensed, actions=np.zeros((n - 1, 1, 2)), violations=violations,
        terminated=False, truncated=True, leader_arrived=True, first_violation=None,
        signals=signals,
    )  # fmt: skip


def test_fig15_cells_are_study_c_with_one_follower_per_seed_and_policy() -> None:
    cells = fig15_cells(3)
    assert [(c.policy.name, c.seed) for c in cells] == [
        (p, s) for s in range(3) for p in FIG15_POLICIES
    ]
    assert {c.scenario for c in cells} == {FIG15_STUDY}
    assert all(c.measure == FIG15_MEASURE and c.record_signals for c in cells)
    resolved = resolve_cells(cells)
    assert len(resolved) == 6  # no two cells share a key
    for rc in resolved:
        assert rc.config["followers"] == 1
        terminate_on = rc.config["safety"]["terminate_on"]
        assert sorted(terminate_on) == ["collision_obstacle", "collision_robot"]
    with pytest.raises(ValueError, match="seeds must be >= 1"):
        fig15_cells(0)


def test_first_loss_when_where_regained_and_reached_blind() -> None:
    # sight lost at samples 3-5 (back at 6; arrived at the last-seen point at 5), then at 8-9
    ep = _episode([1, 1, 1, 0, 0, 0, 1, 1, 0, 0], arrived=[0, 0, 0, 0, 0, 1, 0, 0, 0])
    m = first_loss(ep)
    assert m["first_loss"] and m["first_loss_follower"] == 1 and m["first_loss_step"] == 3
    assert m["first_loss_time"] == pytest.approx(0.3)
    assert m["first_loss_position"] == pytest.approx([0.3, 0.0])  # the follower at sample 3
    assert m["first_loss_last_seen"] == pytest.approx([0.2, 1.0])  # the leader at sample 2
    assert m["first_loss_causes"] == ["out_of_fov"]
    assert m["first_loss_duration"] == pytest.approx(0.3)
    assert m["first_loss_regained"] is True and m["first_loss_reached_blind"] is True
    # the second interval is open at the end (its last sample has no signal)
    assert m["ends_blind"] is True and m["reached_blind_intervals"] == 1
    np.testing.assert_allclose(m["loss_positions"], [[0.3, 0.0], [0.8, 0.0]])


def test_first_loss_never_regained_without_signals_and_without_a_loss() -> None:
    m = first_loss(_episode([1, 1, 0, 0, 0]))
    assert m["first_loss_regained"] is False and m["ends_blind"] is True
    assert m["first_loss_reached_blind"] is None and m["reached_blind_intervals"] is None
    none = first_loss(_episode([1, 1, 1], arrived=[0, 0]))
    assert none["first_loss"] is False and none["ends_blind"] is False
    assert none["reached_blind_intervals"] == 0 and none["loss_positions"] == []
    assert all(v is None for k, v in none.items() if k.startswith("first_loss_"))


def test_leader_corners_of_study_c_and_a_clear_error_without_a_path() -> None:
    corners = leader_corners(platoon_env.make(FIG15_STUDY, followers=1).scenario.config)
    assert corners[0] == (4.0, 1.2) and len(corners) == 12  # the first sharp corner first
    bare = SimpleNamespace(name="x", leader=SimpleNamespace(path=None))
    with pytest.raises(ValueError, match="no path with a corner"):
        leader_corners(bare)


def test_first_loss_table_counts_the_corners_of_the_losses() -> None:
    corners = [(0.0, 0.0), (1.0, 0.0)]
    # lost at (0.3, 0): corner 1, then at (0.9, 0): corner 2
    lost = first_loss(_episode([1, 1, 1, 0, 1, 1, 1, 1, 1, 0, 1], arrived=[0] * 10))
    kept = first_loss(_episode([1] * 11, arrived=[0] * 10))
    groups = {("s", "p"): [{**m, "followers": 1} for m in (lost, lost, kept)]}
    (row,) = [ln for ln in first_loss_table(groups, corners).splitlines() if ln.startswith("| s ")]
    cells = [c.strip() for c in row.strip("|").split("|")]
    assert cells[2:5] == ["1", "3", "2"]  # followers, episodes, episodes with a loss
    assert cells[6] == "1 (0, 0): 2" and cells[9] == "1 (0, 0): 2, 2 (1, 0): 2"
    assert cells[10] == "2/2" and cells[12] == "0/2"  # regained, reached blind


def test_plot_last_seen_trace_refuses_another_team() -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    two = platoon_env.make(FIG15_STUDY).scenario  # the study's own team: 2 followers
    fig, ax = plt.subplots()
    with pytest.raises(ValueError, match="2 follower"):
        plot_last_seen_trace(ax, two, _episode([1, 1, 0]))
    plt.close(fig)


def _tables(text: str) -> list[list[list[str]]]:
    """The markdown tables of ``text``: rows (header and separator dropped) of cells."""
    tables: list[list[list[str]]] = []
    current: list[list[str]] | None = None
    for line in text.splitlines():
        if line.startswith("|"):
            if current is None:
                current = []
                tables.append(current)
            current.append([c.strip() for c in line.strip("|").split("|")])
        else:
            current = None
    return [t[2:] for t in tables]


def test_fig15_command_writes_one_follower_tables_that_add_up(tmp_path: Path) -> None:
    store, out = tmp_path / "s.sqlite", tmp_path / "out"
    text = main(["--fig15", "--seeds", "2", "--workers", "1", "--store", str(store),
                 "--out", str(out)])  # fmt: skip
    assert (out / FIG15_FILE).read_text() == text
    assert not (out / "comparison.md").exists()  # the default run's table is not touched
    summary, losses, episodes = _tables(text)
    assert [r[1] for r in summary] == list(FIG15_POLICIES) == [r[1] for r in losses]
    assert all(r[3] == "2" for r in summary + losses)  # episodes per policy
    assert all(r[2] == "1" for r in losses)  # followers
    assert sorted((r[0], r[1]) for r in episodes) == sorted(
        (p, str(s)) for p in FIG15_POLICIES for s in range(2)
    )
    for s_row, l_row in zip(summary, losses, strict=True):
        rows = [r for r in episodes if r[0] == l_row[1]]
        n_lost = sum(r[2] != "–" for r in rows)
        assert int(s_row[4]) == int(l_row[4]) == n_lost  # episodes with a break = with a loss
        assert int(s_row[5].split()[0]) == sum(int(r[10]) for r in rows)  # intervals
        if n_lost:
            corners = [int(k) for k in re.findall(r": (\d+)", l_row[6])]
            assert sum(corners) == n_lost
            every = [int(k) for k in re.findall(r": (\d+)", l_row[9])]
            assert sum(every) == int(s_row[5].split()[0])  # every interval at some corner
            assert l_row[10].endswith(f"/{n_lost}")  # regained, of the episodes with a loss
    with Store(store) as st:
        metrics = [r.metrics for r in st.episodes().values()]
    assert len(metrics) == 4 and all(m["followers"] == 1 for m in metrics)
    png = out / f"{FIG15_STUDY}_last_seen_trace_one_follower.png"
    assert "--fig15" in Image.open(png).info["Description"]
