"""The leaderboard's arrangement and statistics, on hand-made boards, and one tiny real run."""

from __future__ import annotations

import shutil
from pathlib import Path
from typing import Any

import pytest

pytest.importorskip("rliable")

from experiments.board import episode_seeds, span
from experiments.policies import PolicySpec
from experiments.significance import mcnemar_exact
from experiments.stats import bootstrap_episodes
from experiments.studies import leaderboard as lb
from experiments.suites import ARUCO, IDEAL, suite

REPO = Path(__file__).resolve().parent.parent


def _ep(success: bool, violation: str = "", sim_time: float = 10.0, rms: float = 0.1) -> dict:
    return {
        "success": success,
        "violation": violation,
        "sim_time": sim_time,
        "rms_e_d": rms,
        "rms_e_beta": 0.05,
        "control_effort": 2.0,
    }


def _tasks(seeds: int = 4) -> list[lb.Task]:
    return [
        lb.Task(suite, scenario, c.label, seeds, c)
        for suite, scenarios in (("paper", ("study_a", "study_b")), ("heldout", ("t_easy",)))
        for scenario in scenarios
        for c in (IDEAL, ARUCO)
    ]


def _board(
    per_entry: dict[str, list[dict[lb.Task, list[dict[str, Any]]]]], seeds: int = 4
) -> lb.Board:
    entries = []
    for name, runs in per_entry.items():
        learned = name.startswith("m")
        specs = tuple(PolicySpec.of("ppc", f"{name}_s{i}") for i in range(len(runs)))
        entries.append(lb.Entry(name, specs, learned))
    return lb.Board(entries, _tasks(seeds), per_entry)


def test_entries_group_seed_folders_into_configurations(tmp_path: Path) -> None:
    src = next(REPO.glob("models/**/ppo_corridors_s0/model.zip")).parent
    for name in ("cfg_a_s0", "cfg_a_s1", "cfg_b_s3", "solo"):
        shutil.copytree(src, tmp_path / name)
    entries = lb.entries(tmp_path)
    assert [e.name for e in entries] == [*lb.ANALYTIC, "cfg_a", "cfg_b", "solo"]
    by = {e.name: e for e in entries}
    assert [s.name for s in by["cfg_a"].runs] == ["cfg_a_s0", "cfg_a_s1"]
    assert by["cfg_a"].learned and not by["ppc"].learned
    assert len(by["solo"].runs) == 1


def test_tasks_cover_both_suites_with_their_seeds() -> None:
    tasks = lb.tasks()
    # 3 studies and every procedural tier's test split, each ideal and aruco
    n = 2 * (3 + len(suite("heldout").scenarios))
    assert len(tasks) == n and len(set(tasks)) == n
    assert {t.seeds for t in tasks if t.suite == "paper"} == {20}
    assert {t.seeds for t in tasks if t.suite == "heldout"} == {200}
    assert {t.condition_label for t in tasks} == {"ideal", "aruco"}
    small = lb.tasks(3, 5)
    assert {(t.suite, t.seeds) for t in small} == {("paper", 3), ("heldout", 5)}
    with pytest.raises(ValueError):
        lb.tasks(0, 5)


def test_a_model_the_sensors_refuse_is_refused_not_run(tmp_path: Path) -> None:
    src = next(REPO.glob("models/**/ppo_corridors_s0/model.zip")).parent
    shutil.copytree(src, tmp_path / "old_s0")  # 0.05 s: aruco's 30 Hz camera refuses it
    entries = [e for e in lb.entries(tmp_path) if e.learned]
    cells, refused = lb.cells(entries, lb.tasks(1, 1))
    assert {t.condition_label for (_, t) in refused} == {"aruco"}
    n = len(lb.tasks(1, 1)) // 2  # tasks per condition
    assert len(refused) == n and all("frame_rate" in why for why in refused.values())
    assert len(cells) == n  # the ideal tasks, one seed each


def test_suite_row_counts_violations_per_1000_steps_of_10_ms() -> None:
    t = _tasks()
    runs = [{task: [_ep(True), _ep(False, "occluded"), _ep(True), _ep(True)] for task in t}]
    board = _board({"ppc": runs})
    row = lb.suite_row(board, board.entries[0], "paper")
    # 4 paper tasks x 4 episodes x 10 s = 160 s = 16,000 steps of 10 ms; 4 occlusions
    assert row["episodes"] == 16
    assert row["violations_per_1k"]["occluded"] == pytest.approx(1000 * 4 / 16000)
    assert row["violations_per_1k"]["collision_robot"] == 0
    assert lb._violations(row["violations_per_1k"]) == "occluded 0.250"
    assert lb._violations({"occluded": 0.0001, "out_of_fov": 0.0}) == "occluded <0.001"
    assert row["rms_e_d"] == pytest.approx(0.1)


def test_success_of_a_deterministic_law_is_the_plain_mean_over_tasks() -> None:
    t = _tasks()
    rates = {t[0]: 4, t[1]: 3, t[2]: 2, t[3]: 0}
    runs = [{task: [_ep(i < rates.get(task, 4)) for i in range(4)] for task in t}]
    board = _board({"ppc": runs})
    agg = lb.success_aggregate(board, board.entries[0], board.suite_tasks("paper"))
    assert agg is not None
    # task means 1, .75, .5, 0: the mean keeps every task (an IQM would give .625)
    assert agg.value == pytest.approx(0.5625)
    assert agg.low < agg.value < agg.high
    # 4 scores of one run: too few for an IQM
    assert lb.success_iqm(board, board.entries[0], board.suite_tasks("paper")) is None


def test_a_floor_or_ceiling_law_gets_an_interval_of_width() -> None:
    """0/4 and 4/4 on every task: the interval is not a point (the episode bootstrap's was)."""
    t = _tasks()
    runs = [{task: [_ep(task.condition_label == "ideal")] * 4 for task in t}]
    board = _board({"ppc": runs})
    agg = lb.success_aggregate(board, board.entries[0], board.suite_tasks("paper"))
    assert agg is not None and agg.value == 0.5 and agg.high - agg.low > 0.05
    same = bootstrap_episodes(board.episode_matrix("ppc", board.suite_tasks("paper")))
    assert same.low == same.high


def test_success_of_a_configuration_is_over_its_seeds() -> None:
    t = _tasks()
    good = {task: [_ep(True)] * 4 for task in t}
    bad = {task: [_ep(False, "collision_obstacle")] * 4 for task in t}
    board = _board({"m": [good, good, bad]})
    m = board.success_matrix("m", board.suite_tasks("paper"))
    assert m.shape == (3, 4) and m[:2].min() == 1 and m[2].max() == 0
    agg = lb.success_aggregate(board, board.entries[0], board.suite_tasks("paper"))
    assert agg is not None
    assert agg.value == pytest.approx(2 / 3)  # two seeds of three succeed everywhere
    assert agg.low < 0.5 and agg.high > 0.85  # the seeds disagree: a wide interval
    iqm = lb.success_iqm(board, board.entries[0], board.suite_tasks("paper"))
    # 12 scores, 8 ones and 4 zeros; IQM trims 3 at each end: 5 ones of 6
    assert iqm is not None and iqm.value == pytest.approx(5 / 6)


def test_a_missing_task_gives_no_aggregate() -> None:
    t = _tasks()
    runs = [{task: [_ep(True)] * 4 for task in t[1:]}]
    board = _board({"m": runs})
    assert lb.success_aggregate(board, board.entries[0], board.suite_tasks("paper")) is None


def test_the_goal_needs_every_seed_ideal_and_a_significant_aruco_win_without_a_loss() -> None:
    t = _tasks(seeds=20)
    aruco_a, aruco_b = (
        next(x for x in t if x.scenario == s and x.condition_label == "aruco")
        for s in ("study_a", "study_b")
    )
    ideal_a = next(x for x in t if x.scenario == "study_a" and x.condition_label == "ideal")

    def run(fails: dict[lb.Task, int]) -> dict[lb.Task, list[dict[str, Any]]]:
        return {x: [_ep(i >= fails.get(x, 0)) for i in range(20)] for x in t}

    law = [run({aruco_a: 20, aruco_b: 10})]  # the reference: 0/20 on A, 10/20 on B (aruco)
    good = run({aruco_a: 0, aruco_b: 10, ideal_a: 1})  # 19/20 ideal A is >= 95 %
    per_entry = {"filtered_ppc": law, "m": [good, good], "m2": [good, run({ideal_a: 2})]}
    board = _board(per_entry, seeds=20)
    found = lb.comparisons(board)
    g = lb.goal(board, board.entries[1], found)
    assert g["wins"] == ["study_a/aruco"] and g["losses"] == [] and g["met"]
    assert [r["ideal"] for r in g["runs"]] == [True, True]
    g2 = lb.goal(board, board.entries[2], found)
    assert g2["ideal_runs"] == 1 and not g2["met"]  # one seed at 18/20 on ideal A
    # a loss anywhere on the aruco studies, beside the win, fails the goal
    worse = run({aruco_a: 0, aruco_b: 20})
    board = _board({"filtered_ppc": law, "m": [worse, worse]}, seeds=20)
    g3 = lb.goal(board, board.entries[1], lb.comparisons(board))
    assert g3["wins"] == ["study_a/aruco"] and g3["losses"] == ["study_b/aruco"]
    assert not g3["met"]
    assert "| m | 2 of 2 | study_a/aruco | study_b/aruco | no |" in lb.goal_markdown([g3])


def test_tables_and_readme_splice(tmp_path: Path) -> None:
    t = _tasks()
    board = _board({"ppc": [{task: [_ep(True)] * 4 for task in t}]})
    rows = [lb.suite_row(board, e, s) for s in lb.SUITES for e in board.entries]
    table = lb.table_markdown(rows)
    assert table.count("\n") == 4 and "| ppc | paper | all | 1 × 16 | 1.00 [0.7" in table
    tasks_md = lb.task_table_markdown(board)
    assert "study_a/aruco" in tasks_md and "4/4 [0.51, 1.00] ⊤" in tasks_md
    assert set(lb.task_graded_markdown(board).split("\n")[2].split(" | ")[1:-1]) == {"–"}
    readme = tmp_path / "README.md"
    readme.write_text(f"intro\n{lb.MARKERS[0]}\nold\n{lb.MARKERS[1]}\nend\n")
    lb.splice_readme(readme, table)
    body = readme.read_text()
    assert "old" not in body and table in body and body.startswith("intro") and "end" in body
    readme.write_text("no markers")
    with pytest.raises(ValueError, match="markers"):
        lb.splice_readme(readme, table)


def test_the_graded_table_shows_progress_on_an_unsolved_task() -> None:
    """Two entries that both fail every episode tie on success; the graded table tells the
    one that gets further (mean path done, median smallest margin) from the other."""
    t = _tasks()

    def graded(path: float, margin: float) -> dict:
        return {
            **_ep(False, "out_of_fov"),
            "path_fraction": path,
            "min_margin_distance": margin + 0.5,
            "min_margin_bearing": margin,
        }

    far = [graded(0.9, -0.01), graded(0.7, -0.03), graded(0.8, -0.02)]
    near = [graded(0.1, -0.2)] * 3
    board = _board({"a": [{task: far for task in t}], "b": [{task: near for task in t}]})
    assert lb.task_graded(board, "a", t[0]) == (pytest.approx(0.8), pytest.approx(-0.02))
    assert lb.task_graded(board, "b", t[0]) == (pytest.approx(0.1), pytest.approx(-0.2))
    md = lb.task_graded_markdown(board)
    assert "| a | 0.80 / -0.02 |" in md and "| b | 0.10 / -0.20 |" in md


def test_a_tiny_leaderboard_run_writes_its_outputs(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    models = tmp_path / "models"
    models.mkdir()
    docs = tmp_path / "docs"
    argv = [
        "--models", str(models), "--store", str(tmp_path / "store"), "--paper-seeds", "1",
        "--heldout-seeds", "1", "--docs", str(docs), "--no-readme", "--workers", "1",
        "--no-progress", "--allow-mixed",
    ]  # fmt: skip
    rc = lb.main(argv)
    assert rc == 0
    text = (docs / "leaderboard.md").read_text()
    for name in lb.ANALYTIC:
        for suite_name in ("paper", "heldout"):
            for condition in ("ideal", "aruco"):
                n = len(suite(suite_name).scenarios)
                assert f"| {name} | {suite_name} | {condition} | 1 × {n} |" in text
    assert "## Confirmatory comparisons" in text and "## Exploratory comparisons" in text
    assert "tests in the family" in text
    assert (docs / "figures" / "leaderboard_tasks.png").stat().st_size > 0
    assert (docs / "figures" / "leaderboard_forest.png").stat().st_size > 0
    assert not (docs / "figures" / "leaderboard_separation.png").exists()  # not a screen tall
    assert (docs / "figures" / "leaderboard_profiles.png").stat().st_size > 0
    # a second run finds every episode in the store
    rc = lb.main(argv)
    assert rc == 0
    n_cells = len(lb.ANALYTIC) * len(lb.tasks(1, 1))
    assert f"0 episode(s) run, {n_cells} already in the store" in capsys.readouterr().out


def test_the_pairwise_family_flags_ties_and_names_the_winner() -> None:
    t = _tasks()
    good = {task: [_ep(True)] * 20 for task in t}
    bad = {task: [_ep(task.condition_label == "ideal", "occluded")] * 20 for task in t}
    board = _board({"ppc": [good], "m": [bad]})
    found = lb.comparisons(board)
    by_task = {c.task: c for c in found}
    aruco = next(x for x in t if x.condition_label == "aruco")
    ideal = next(x for x in t if x.condition_label == "ideal")
    assert by_task[aruco.label].verdict == "ppc"
    assert by_task[ideal.label].tie == "ceiling"
    text = lb.comparisons_markdown(found, board.tasks)
    assert "tie at ceiling" in text and "significant after Holm" in text


def test_a_board_from_mixed_code_versions_is_refused(tmp_path: Path) -> None:
    """Rows written at another commit: refused (exit 2) unless --allow-mixed."""
    from experiments.store import Store

    store_dir = tmp_path / "store"
    argv = [
        "--models", str(tmp_path), "--store", str(store_dir), "--paper-seeds", "1",
        "--heldout-seeds", "1", "--docs", str(tmp_path / "docs"), "--no-readme",
        "--workers", "1", "--no-progress", "--no-cards",
    ]  # fmt: skip
    (tmp_path / "m_s0").mkdir()  # no model: the board holds the analytic laws only
    assert lb.main([*argv, "--allow-mixed"]) == 0
    with Store(store_dir / "results.sqlite") as store, store.transaction() as db:
        db.execute("UPDATE runs SET stamp = ?", ('{"commit": "0000000other"}',))
    (tmp_path / "docs" / "leaderboard.md").unlink()
    assert lb.main(argv) == 2
    assert not (tmp_path / "docs" / "leaderboard.md").exists()  # refused before writing
    assert lb.main([*argv, "--allow-mixed"]) == 0
    assert "Mixed code versions" in (tmp_path / "docs" / "leaderboard.md").read_text()


def test_paper_runs_split_the_seeds_and_a_law_plays_them_all(tmp_path: Path) -> None:
    """On a paper study a configuration's runs play disjoint seeds and an analytic law all of
    them (as many episodes, the same seeds, none twice); on a held-out tier a configuration's
    runs share out the layouts an analytic law plays."""
    law = lb.Entry("ppc", (PolicySpec.of("ppc"),), False)
    runs = tuple(PolicySpec.of("ppc", name=f"m_s{k}", k_d=1.0 + k) for k in range(3))
    config = lb.Entry("m", runs, True)
    paper = lb.Task("paper", "study_c", "ideal", 4)
    heldout = lb.Task("heldout", "procedural_easy_test", "ideal", 4)
    assert span([law, config]) == 3
    seeds = [list(episode_seeds(paper, config, k, 3)) for k in range(3)]
    assert seeds == [[0, 1, 2, 3], [4, 5, 6, 7], [8, 9, 10, 11]]
    assert list(episode_seeds(paper, law, 0, 3)) == list(range(12))
    assert list(episode_seeds(heldout, law, 0, 3)) == [0, 1, 2, 3]
    layouts = [list(episode_seeds(heldout, config, k, 3)) for k in range(3)]
    assert layouts == [[0], [1], [2, 3]]  # every layout once, near-equal slices
    # the cells and the board follow the same rule
    for task, law_seeds, run_seeds in (
        (paper, list(range(12)), seeds),
        (heldout, [0, 1, 2, 3], layouts),
    ):
        grid, refused = lb.cells([law, config], [task])
        assert not refused
        by_policy: dict[str, list[int]] = {}
        for rc in grid:
            by_policy.setdefault(rc.cell.policy.name, []).append(rc.cell.seed)
        assert sorted(by_policy["ppc"]) == law_seeds
        assert {k: sorted(v) for k, v in by_policy.items() if k != "ppc"} == {
            f"m_s{k}": run_seeds[k] for k in range(3)
        }
    # fewer layouts than runs: a run would play none
    with pytest.raises(ValueError, match="fewer than the 3 runs"):
        lb.cells([law, config], [lb.Task("heldout", "procedural_easy_test", "ideal", 2)])


def test_a_readme_that_cannot_be_spliced_is_refused_before_any_episode(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """``--readme`` is checked first (exit 2, no store made): not after hours of board."""
    page = tmp_path / "page.md"
    page.write_text("no markers here\n")
    store = tmp_path / "store"
    code = lb.main(["--store", str(store), "--readme", str(page), "--docs", str(tmp_path)])
    assert code == 2
    assert "has no" in capsys.readouterr().err and not store.exists()
    assert lb.readme_problem(tmp_path / "missing.md") is not None
    page.write_text(f"a\n{lb.MARKERS[0]}\nold\n{lb.MARKERS[1]}\nb\n")
    assert lb.readme_problem(page) is None
    shipped = Path(__file__).resolve().parents[1] / "docs" / "benchmark.md"
    assert lb.readme_problem(shipped) is None  # the default page holds the markers


def test_comparisons_pair_episodes_by_seed_across_a_configuration_s_runs() -> None:
    """A configuration's runs play disjoint seed blocks; the law plays them all: each seed is
    one pair. The law fails seeds 0-9 and 20-29, the configuration fails 10-19 only: 20 pairs
    where only it succeeds, 10 where only the law does."""
    t = _tasks(seeds=40)
    task = next(x for x in t if x.suite == "paper" and x.condition_label == "aruco")

    def ep(seed: int, ok: bool) -> dict[str, Any]:
        return {**_ep(ok), "seed": seed}

    law = [{task: [ep(s, s // 10 in (1, 3)) for s in range(40)]}]
    config = [{task: [ep(s, s // 10 != 1) for s in block]} for block in (range(20), range(20, 40))]
    board = _board({"filtered_ppc": law, "m": config}, seeds=40)
    pairs = lb.paired_outcomes(board, "m", "filtered_ppc", task)
    assert len(pairs) == 40
    assert sum(1 for a, b in pairs if a and not b) == 20
    assert sum(1 for a, b in pairs if b and not a) == 10
    (c,) = [c for c in lb.comparisons(board) if c.task == task.label]
    assert c.p_value == pytest.approx(mcnemar_exact(20, 10))
    # the confirmatory family: the learned configuration against the law on the goal's tasks
    assert [(x.a, x.b, x.task) for x in lb.confirmatory(board)] == [
        ("m", "filtered_ppc", task.label)
    ]


def test_the_oracle_is_marked_beside_the_entries_and_its_file_is_checked(tmp_path: Path) -> None:
    import json

    from experiments.board import ORACLE_SUMMARY_FORMAT, load_oracle

    t = _tasks()
    board = _board({"ppc": [{task: [_ep(True)] * 4 for task in t}]})
    good = tmp_path / "f.json"
    rows = {t[1].label: {"successes": 9, "episodes": 10, "seeds": list(range(10))}}
    good.write_text(json.dumps({"format": ORACLE_SUMMARY_FORMAT, "tasks": rows}))
    oracle = load_oracle(good)
    assert oracle == {t[1].label: (9, 10)}
    md = lb.task_table_markdown(board, oracle)
    last = md.strip().split("\n")[-1]
    assert last.startswith(f"| *{lb.ORACLE_LABEL}* | – | 9/10 [")
    for text, match in [
        ("{", "cannot read"),
        ('{"format": "x", "tasks": {}}', "not a feasibility summary"),
        (json.dumps({"format": ORACLE_SUMMARY_FORMAT, "tasks": []}), "tasks must be"),
        (
            json.dumps(
                {"format": ORACLE_SUMMARY_FORMAT, "tasks": {"a": {"successes": 3, "episodes": 2}}}
            ),
            "tasks.a",
        ),
        (
            json.dumps(
                {
                    "format": ORACLE_SUMMARY_FORMAT,
                    "tasks": {"a": {"successes": True, "episodes": 2}},
                }
            ),
            "tasks.a",
        ),
    ]:
        bad = tmp_path / "bad.json"
        bad.write_text(text)
        with pytest.raises(ValueError, match=match):
            load_oracle(bad)


def test_the_forest_and_confirmatory_figures_fit_a_screen(tmp_path: Path) -> None:
    """A board of 16 tasks and 14 entries: the forest plot (the oracle marked) and the
    confirmatory grid are written, neither taller than 1,080 pixels."""
    from PIL import Image

    t = [lb.Task("paper", f"study_{i}", c.label, 4, c) for i in range(8) for c in (IDEAL, ARUCO)]
    per_entry = {
        **{f"law{i}": [{task: [_ep(i % 2 == 0)] * 4 for task in t}] for i in range(4)},
        **{f"m{i}": [{task: [_ep(True), _ep(False)] * 2 for task in t}] for i in range(10)},
    }
    entries_ = [
        lb.Entry(name, (PolicySpec.of("ppc", name),), name.startswith("m")) for name in per_entry
    ]
    board = lb.Board(entries_, t, per_entry)
    forest = lb.plot_forest(board, tmp_path / "forest.png", {}, {t[0].label: (3, 4)})
    grid = lb.plot_confirmatory(lb.confirmatory(board), tmp_path / "grid.png", {})
    assert grid is not None and lb.plot_confirmatory([], tmp_path / "none.png", {}) is None
    for path in (forest, grid):
        with Image.open(path) as image:
            assert image.size[1] <= 1080, (path.name, image.size)
