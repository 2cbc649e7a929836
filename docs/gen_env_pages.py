"""Write the environment pages of the documentation site, ``docs/envs/*.md``, from the package.

    python docs/gen_env_pages.py            # (re)write docs/envs/
    python docs/gen_env_pages.py --check    # write nothing; exit 1 naming each stale page

One page per scenario family, in the layout of Gymnasium's environment pages: Description,
Action space, Observation space, Rewards, Episode end, Arguments, Gymnasium ids, Version
history. Every number on them (spaces and their bounds, followers, step limits, control
period, reward weights, layout seeds, ids and their step limits) is read from ``platoon_env``
by this script; the prose around the numbers is in :data:`FAMILIES` and the functions below.
``scripts/docs.sh`` runs ``--check`` before it builds the site, so a change of the package
that changes a page fails until the pages are regenerated.
"""

from __future__ import annotations

import argparse
import os
import sys
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
OUT = ROOT / "docs" / "envs"
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))
os.environ.setdefault("PLATOON_ENV_QUIET", "1")

import gymnasium as gym  # noqa: E402
import numpy as np  # noqa: E402

import platoon_env  # noqa: E402
from platoon_env.action_range import ActionRange  # noqa: E402
from platoon_env.config import ScenarioConfig  # noqa: E402
from platoon_env.env import ENV_OPTIONS, PlatoonParallelEnv  # noqa: E402
from platoon_env.gym_env import (  # noqa: E402
    GYM_IDS,
    GYM_OPTIONS,
    GYM_STEP_LIMITS,
    VERSION_HISTORY,
)
from platoon_env.gym_vector import VECTOR_OPTIONS  # noqa: E402
from platoon_env.observation import OBS_NAMES  # noqa: E402
from platoon_env.reward import REWARD_TERMS  # noqa: E402
from platoon_env.scenarios.options import (  # noqa: E402
    _SHORTCUT_FIELDS,
    BLOCK_OPTIONS,
    PROFILE_OPTION,
    SCENARIO_OPTIONS,
)
from platoon_env.scenarios.procedural import seed_range  # noqa: E402
from platoon_env.scenarios.profiles import list_profiles  # noqa: E402
from platoon_env.violations import VIOLATION_CAUSES  # noqa: E402

HEADER = "<!-- Written by `python docs/gen_env_pages.py` from the package: do not edit by hand. -->"


@dataclass(frozen=True)
class Family:
    """One page: a family of shipped scenarios and the prose that introduces it."""

    slug: str
    title: str
    scenarios: tuple[str, ...]
    summary: str
    description: str


FAMILIES: tuple[Family, ...] = (
    Family(
        "study_a",
        "Study A",
        ("study_a",),
        "the paper's study A: a long platoon through two narrow passages with corners inside",
        "The paper's study A (its §4.1) on a map designed for it: a long platoon leaves a start "
        "hall, crosses an L-shaped passage and then a Z-shaped one, each with right-angle "
        "corners inside it, and the rooms between them. The corners come while the platoon is "
        "strung out through a passage only a few robot diameters wide, so a follower must keep "
        "its predecessor in view around a bend while the passage walls crowd both the robot "
        "and its line of sight. The leader follows a polyline by pure pursuit; its speed is "
        "drawn per episode around the nominal value.",
    ),
    Family(
        "study_b",
        "Study B",
        ("study_b",),
        "the paper's study B: a furnished flat, a planned leader trajectory, inflated obstacles",
        "The paper's study B (its §4.2): two followers behind a leader that replays a timed "
        "trajectory planned through a furnished flat (rooms, a corridor and doors), stopping "
        "and turning in place at its sharp turns. As in the paper the obstacles are inflated "
        "by a safety margin (`safety.inflation`: the collision rule, the reported clearance "
        "and the proximity readings use the inflated outline) and the proximity sensor covers "
        "a sector about the heading, leaving a blind cone behind each robot. The trajectory "
        "is replayed faster or slower per episode.",
    ),
    Family(
        "study_c",
        "Study C",
        ("study_c",),
        "the paper's study C: a narrow field of view through a meander, rooms and a zig-zag",
        "The paper's study C (its §4.3): two followers with a narrow camera field of view "
        "behind a leader that drives a meandering corridor with sharp corners, rooms with "
        "non-convex obstacles, and a zig-zag corridor. The leader takes every corner tightly "
        "(a short pure-pursuit lookahead), so a follower has to start turning before its "
        "predecessor leaves the field of view. Its robots, sensors and gains are those the "
        "procedural tiers reuse.",
    ),
    Family(
        "procedural_tiers",
        "Procedural tiers: easy, medium, hard",
        tuple(f"procedural_{t}_{s}" for t in ("easy", "medium", "hard") for s in ("train", "test")),
        "generated corridors and rooms in three difficulty tiers, train and test splits",
        "A new workspace and leader path on every reset: a corridor along a random polyline or "
        "a set of rooms joined by doorways, with free-standing obstacles (even odds between "
        "the two). The layout is drawn from the env's own RNG, so `reset(seed=s)` always "
        "gives the same layout. From `easy` to `hard` every range the generator draws from "
        "moves towards the harder end: narrower corridors and doorways, sharper and more "
        "frequent turns, more obstacles closer to the path (the ranges are in "
        "[scenarios.md](../scenarios.md#difficulty-tiers)). The `train` and `test` splits of "
        "a tier draw from disjoint blocks of layout seeds: train on `_train`, report on "
        "`_test`. The robots, sensors and gains are study C's, with two followers by "
        "default (`followers=` changes it; the layouts are sized for the platoon).",
    ),
    Family(
        "procedural_sharp_paper",
        "Procedural tiers with the studies' geometry: sharp, paper",
        tuple(f"procedural_{t}_{s}" for t in ("sharp", "paper") for s in ("train", "test")),
        "generated layouts with the studies' sharp corners and doors followed by a turn",
        "Generated layouts with the geometry that makes the paper's studies hard, which the "
        "other tiers' rounded paths avoid: sharp corners inside passages a few robot diameters "
        "wide, and doors followed at once by a turn. `paper` is the harder of the two "
        "(narrower passages and doors, more corners), and in its rooms the leader drives a "
        "planner's timed trajectory that stops and turns in place, as study B's does. The "
        "leader's speed is drawn per episode. Seeds, splits and defaults work as in the other "
        "tiers ([scenarios.md](../scenarios.md#tiers-with-the-studies-geometry)).",
    ),
    Family(
        "procedural_formations",
        "Procedural formations: a formation drawn per layout",
        tuple(
            f"procedural_formations_{g}{s}"
            for g in ("", "sharp_", "paper_")
            for s in ("train", "test")
        ),
        "generated layouts, each with its own formation (followers, radius, distances, camera)",
        "Each layout also draws its formation: the number of followers, the robot radius, "
        "`d_col`, `d_des`, the camera's range and half-angle and the leader's speed, each from "
        "a range that covers the paper's three studies "
        "([scenarios.md](../scenarios.md#every-formation-generatorformation)). The layouts are "
        "the untiered corridors and rooms, or those of the `sharp` and `paper` tiers. The env "
        "holds one slot per follower of the range's upper end; an episode with fewer followers "
        "leaves the other slots inert (zero observation, reward and cost; their actions are not "
        "read), and `env.agents` lists the live ones. Training on these is how one policy "
        "learns every formation; the task-aware observation option tells it which formation it "
        "is in.",
    ),
    Family(
        "procedural_untiered",
        "Procedural, untiered, and the corridors set",
        ("procedural_train", "procedural_test", "procedural_corridors_train"),
        "the generator before tiers existed, and corridors only (no Gymnasium ids)",
        "The generator's untiered ranges, as shipped before the tiers existed: "
        "`procedural_train` and `procedural_test` draw corridors or rooms with even odds from "
        "disjoint layout seeds; `procedural_corridors_train` draws corridors only, from the "
        "training seeds, with the reward weights stated in its file (the training set of a "
        "legacy shipped model). They have no Gymnasium id; use `platoon_env.make` or "
        "`SingleFollowerEnv(scenario)`.",
    ),
)

#: What each column of the default observation means (``platoon_env.observation.OBS_NAMES``).
OBS_MEANING: dict[str, str] = {
    "visible": "1 when the camera sees the predecessor, else 0",
    "x_rel": "the predecessor ahead, `d cos β` [m] (0 when not visible)",
    "y_rel": "the predecessor to the left, `d sin β` [m] (0 when not visible)",
    "d_W_l": "the follower's clearance to the obstacles on the left [m]",
    "d_W_r": "the follower's clearance on the right [m]",
    "d_l": "the line of sight's clearance on the left [m]",
    "d_r": "the line of sight's clearance on the right [m]",
}

#: How each reward term is computed per follower and step (``platoon_env.reward``).
REWARD_MEANING: dict[str, str] = {
    "distance": "`−w · (e_d / (d_con − d_des))²`, the normalised distance error clipped to ±2",
    "bearing": "`−w · (β / β_con)²`, the normalised bearing clipped to ±2",
    "effort": "`−w · (u² + ω²)` of the applied action",
    "alive": "`+w` in a step without a violation",
    "violation": "`−w` in a step with a violation (any cause)",
    "wall": "`−w · (1 − (c − r) / m)²` while the clearance `c` is within `m = wall_margin` of "
    "a collision (`c − r < m`), else 0",
}

#: When a follower violates each cause (``docs/safety.md``; eqs. 4-5 of the paper).
CAUSE_MEANING: dict[str, str] = {
    "collision_robot": "`d ≤ d_col` to its predecessor, or its disk touches any other robot's",
    "collision_obstacle": "its clearance to the (inflated) obstacles is `≤ r`, or its motion "
    "over a sub-step crossed a wall",
    "occluded": "an obstacle cuts the line of sight to its predecessor",
    "out_of_range": "`d ≥ d_con`",
    "out_of_fov": "`|β| ≥ β_con`",
}


def num(x: Any) -> str:
    """A number as a short string: integers without a point, others to 4 significant digits."""
    x = float(x)
    if x.is_integer() and abs(x) < 1e15:
        return str(int(x))
    return f"{x:.4g}"


def box(space: Any) -> str:
    """A ``Box`` as ``Box(low, high, shape, dtype)``, the bounds written once when uniform."""
    low, high = np.asarray(space.low), np.asarray(space.high)
    lo = num(low.flat[0]) if np.all(low == low.flat[0]) else "[" + ", ".join(map(num, low)) + "]"
    hi = (
        num(high.flat[0]) if np.all(high == high.flat[0]) else "[" + ", ".join(map(num, high)) + "]"
    )
    return f"`Box({lo}, {hi}, {tuple(space.shape)}, {np.dtype(space.dtype).name})`"


def table(head: Sequence[str], rows: Sequence[Sequence[str]]) -> str:
    def cell(text: str) -> str:  # a pipe in a cell, code spans too, is escaped (GFM)
        return text.replace("|", "\\|")

    lines = ["| " + " | ".join(map(cell, head)) + " |", "|" + "---|" * len(head)]
    lines += ["| " + " | ".join(map(cell, row)) + " |" for row in rows]
    return "\n".join(lines)


def code(name: str) -> str:
    return f"`{name}`"


@dataclass
class Facts:
    """What the pages say of one shipped scenario, read from the package."""

    name: str
    config: ScenarioConfig
    env: PlatoonParallelEnv
    gym_ids: list[str]

    @property
    def procedural(self) -> bool:
        return self.config.generator is not None


def facts(name: str) -> Facts:
    env = platoon_env.make(name)
    ids = [i for i, kw in GYM_IDS.items() if kw["scenario"] == name]
    return Facts(name, env.source.config, env, ids)


def per_scenario(fs: Sequence[Facts], rows: Sequence[tuple[str, Callable[[Facts], str]]]) -> str:
    """The quantities of ``rows``: one table of those every scenario shares, then one with a
    column per scenario for those that differ."""
    if len(fs) == 1:
        return table(["", code(fs[0].name)], [[label, get(fs[0])] for label, get in rows])
    values = [(label, [get(f) for f in fs]) for label, get in rows]
    shared = [[label, v[0]] for label, v in values if len(set(v)) == 1]
    differ = [[label, *v] for label, v in values if len(set(v)) > 1]
    parts = []
    if shared:
        parts.append(table(["", "every scenario of this page"], shared))
    if differ:
        parts.append(table(["", *(code(f.name) for f in fs)], differ))
    return "\n\n".join(parts)


def _followers(f: Facts) -> str:
    formation = f.config.generator.formation if f.config.generator else None
    if formation is not None and formation.followers is not None:
        lo, hi = formation.followers
        return f"{lo}–{hi} per layout ({hi} slots)"
    return str(f.config.followers)


def _agents(f: Facts) -> str:
    slots = len(f.env.possible_agents)
    sep = ", " if slots == 2 else " … "
    text = f"`follower_1`{sep}`follower_{slots}`" if slots > 1 else "`follower_1`"
    formation = f.config.generator.formation if f.config.generator else None
    if formation is not None and formation.followers is not None:
        lo, hi = formation.followers
        text += f" ({lo}–{hi} live per layout)"
    return text


def _drawn(f: Facts, key: str) -> str | None:
    formation = f.config.generator.formation if f.config.generator else None
    value = getattr(formation, key, None) if formation is not None else None
    if value is None:
        return None
    return f"drawn in [{num(value[0])}, {num(value[1])}]"


def _driven(f: Facts) -> str:
    """The length of path the leader drives: from its start to the path's end [m]."""
    scenario = f.env.scenario
    return num(scenario.path_s[-1] - scenario.initial_progress)


def _leader(f: Facts) -> str:
    lead = f.config.leader
    if f.config.generator is not None:
        pursuit = f"pure pursuit (lookahead {num(lead.lookahead)} m)"
        if f.config.generator.tier == "paper":
            return f"per layout: {pursuit}; in rooms a planner's timed trajectory"
        return f"a path drawn per layout, by {pursuit}"
    if lead.trajectory:
        t_end = lead.trajectory[-1][0]
        return f"timed trajectory, {len(lead.trajectory)} samples, {_driven(f)} m in {num(t_end)} s"
    return f"pure pursuit along {_driven(f)} m of polyline (lookahead {num(lead.lookahead)} m)"


def _step_limit(f: Facts) -> str:
    if f.config.simulation.max_episode_steps is not None or not f.procedural:
        return str(f.env.max_episode_steps)
    if f.name in GYM_STEP_LIMITS:
        return f"per layout, from its path (at most {GYM_STEP_LIMITS[f.name]})"
    return "per layout, from its path"


def _seeds(f: Facts) -> str:
    gen = f.config.generator
    if gen is None:
        return "–"
    seeds = seed_range(gen.split, gen.tier)
    return f"{seeds.start}–{seeds.stop - 1}"


def _proximity(f: Facts) -> str:
    prox = f.config.proximity
    rng = "`d_con`" if prox.range is None else f"{num(prox.range)} m"
    sector = "all around" if prox.half_angle is None else f"±{num(np.degrees(prox.half_angle))}°"
    return f"range {rng}, {sector}"


PARAMETERS: tuple[tuple[str, Callable[[Facts], str]], ...] = (
    ("followers `N`", _followers),
    ("robot radius `r` [m]", lambda f: _drawn(f, "radius") or num(f.config.robot.radius)),
    ("`d_col` [m]", lambda f: _drawn(f, "d_col") or num(f.config.safety.d_col)),
    ("`d_des` [m]", lambda f: _drawn(f, "d_des") or num(f.config.formation.d_des)),
    ("camera range `d_con` [m]", lambda f: _drawn(f, "d_con") or num(f.config.camera.range)),
    (
        "camera half-angle `β_con` [rad]",
        lambda f: _drawn(f, "beta_con") or num(f.config.camera.half_angle),
    ),
    ("proximity sensor", _proximity),
    ("obstacle inflation [m]", lambda f: num(f.config.safety.inflation)),
    ("leader", _leader),
    (
        "leader speed [m/s]",
        lambda f: _drawn(f, "leader_speed") or num(f.config.leader.speed),
    ),
    ("speed factor per episode", lambda f: _speed_factor(f)),
    ("workspace", lambda f: _workspace(f)),
    ("layout seeds", _seeds),
)


def _speed_factor(f: Facts) -> str:
    v = f.config.leader.speed_variation
    return "1 (fixed)" if v == 0 else f"drawn in [{num(1 - v)}, {num(1 + v)}]"


def _workspace(f: Facts) -> str:
    gen = f.config.generator
    if gen is None:
        edges = len(f.env.scenario.workspace.edges)
        return f"fixed map, {edges} boundary edges"
    tier = "untiered" if gen.tier is None else f"tier `{gen.tier}`"
    return f"`{gen.kind}`, {tier}, split `{gen.split}`"


def section_glance(fam: Family, fs: Sequence[Facts]) -> str:
    """Gymnasium's summary table: one value where the family agrees, else one per scenario."""

    def spaces(f: Facts, which: str) -> str:
        agent = f.env.possible_agents[0]
        return box(getattr(f.env, which)(agent))

    rows: tuple[tuple[str, Callable[[Facts], str]], ...] = (
        ("Agents", _agents),
        ("Action space", lambda f: spaces(f, "action_space")),
        ("Observation space", lambda f: spaces(f, "observation_space")),
        ("Control period", lambda f: f"{num(f.config.simulation.control_period)} s"),
        ("Step limit", _step_limit),
    )
    body: list[list[str]] = []
    for label, get in rows:
        values = [get(f) for f in fs]
        if len(set(values)) == 1:
            body.append([label, values[0]])
        else:
            each = zip(fs, values, strict=True)
            body.append([label, "; ".join(f"{code(f.name)}: {v}" for f, v in each)])
    n_ids = sum(len(f.gym_ids) for f in fs)
    body.append(["Gymnasium ids", f"{n_ids} (below)" if n_ids else "none"])
    body.append(["Import", f'`platoon_env.make("{fs[0].name}")`'])
    usage = (
        "```python\n"
        "import platoon_env\n\n"
        f'env = platoon_env.make("{fs[0].name}")  # the PettingZoo ParallelEnv\n'
        "observations, infos = env.reset(seed=0)\n"
        "```"
    )
    head = ["Scenarios" if len(fs) > 1 else "Scenario", ", ".join(code(f.name) for f in fs)]
    return table(head, body) + "\n\n" + usage


def section_description(fam: Family, fs: Sequence[Facts]) -> str:
    own = "\n".join(f"- {code(f.name)}: {f.config.description}" for f in fs)
    sim = fs[0].config.simulation
    return (
        f"{fam.description}\n\n"
        "Each follower `follower_i` tracks robot `i − 1` (robot 0 is the scripted leader, not "
        "an agent) with two sensors only: a forward camera that sees its predecessor and a "
        "proximity sensor that measures clearances to the obstacles "
        "([sensing.md](../sensing.md)). The scenario files say:\n\n"
        f"{own}\n\n"
        "Parameters (from the scenario files; [scenarios.md](../scenarios.md) defines each "
        "key):\n\n"
        f"{per_scenario(fs, PARAMETERS)}\n\n"
        f"One `step()` is one control period of {num(sim.control_period)} s "
        f"({sim.physics_substeps} physics sub-steps, each an exact unicycle arc, each followed "
        "by the safety checks)."
    )


def section_action(fam: Family, fs: Sequence[Facts]) -> str:
    f = fs[0]
    rng = ActionRange()
    normalised = gym.make(f.gym_ids[0], normalize_actions=True) if f.gym_ids else None
    text = (
        "Each follower sends `[u, ω]`: forward speed [m/s] and turn rate [rad/s] (the "
        "unicycle of the paper's eq. 1), in "
        f"{box(f.env.action_space(f.env.possible_agents[0]))}, that is ±`robot.u_max` and "
        f"±`robot.omega_max` ({num(f.config.robot.u_max)} m/s and "
        f"{num(f.config.robot.omega_max)} rad/s here, far above what the PPC law commands). "
        "Values outside the box are clipped; NaN, infinite values or a wrong shape raise "
        "before anything changes. `u_max=` and `omega_max=` change the bounds."
    )
    if normalised is not None:
        text += (
            "\n\nThe Gymnasium ids take `normalize_actions=True`: the action space is then "
            f"{box(normalised.action_space)}, mapped to `u` in [{num(rng.u_low)}, "
            f"{num(rng.u_high)}] m/s and `ω` in ±{num(rng.omega_high)} rad/s by the default "
            "`platoon_env.action_range.ActionRange` (`action_range=` sets another)."
        )
        normalised.close()
    return text


def section_observation(fam: Family, fs: Sequence[Facts]) -> str:
    spaces = {f.name: f.env.observation_space(f.env.possible_agents[0]) for f in fs}
    first = spaces[fs[0].name]
    same = all(
        np.array_equal(s.low, first.low) and np.array_equal(s.high, first.high)
        for s in spaces.values()
    )
    shown = [fs[0]] if same else list(fs)
    head = ["index", "name", "meaning"]
    for f in shown:
        suffix = "" if same else f" ({f.name})"
        head += [f"low{suffix}", f"high{suffix}"]
    rows = []
    for k, name in enumerate(OBS_NAMES):
        row = [str(k), code(name), OBS_MEANING[name]]
        for f in shown:
            s = spaces[f.name]
            row += [num(s.low[k]), num(s.high[k])]
        rows.append(row)
    name = fs[0].name
    task = platoon_env.make(name, observation={"task_aware": True})
    free = platoon_env.make(name, observation={"task_aware": True, "scale_free": True})
    agent = task.possible_agents[0]
    n_task = task.observation_space(agent).shape[0]
    n_free = free.observation_space(agent).shape[0]
    task.close()
    free.close()
    state = fs[0].env.state_space
    return (
        "Each follower observes only what its own sensors measure, in its body frame: no "
        "global position, no heading, no leader speed, no communication. The default "
        f"observation is a `float32` `Box` of {first.shape[0]}:\n\n"
        f"{table(head, rows)}\n\n"
        "The clearances are capped at the proximity range (a side with nothing sensed reads "
        'the cap). With `observation={"task_aware": True}` the box has '
        f"{n_task} values (these, the formation's parameters over fixed scales and the time "
        'since the predecessor was last seen); adding `"scale_free": True` gives '
        f"{n_free} values in the task's own units ([api.md](../api.md#observation-options), "
        "[sensing.md](../sensing.md#observation-vector)).\n\n"
        f"For centralised critics `env.state()` is a {box(state)} "
        f"(`{fs[0].name}`): poses, applied velocities, leader progress and time. Ground truth "
        "for analysis (never a policy input) is in `info[agent]` and `env.poses`, "
        "`env.sensed`, `env.violation_masks`."
    )


def section_rewards(fam: Family, fs: Sequence[Facts]) -> str:
    def weight(term: str) -> Callable[[Facts], str]:
        return lambda f: num(getattr(f.config.reward, term))

    rows = [(f"`{t}`: {REWARD_MEANING[t]}", weight(t)) for t in REWARD_TERMS]
    rows.append(("`wall_margin` `m` [m]", lambda f: num(f.config.reward.wall_margin)))
    return (
        "The reward is per follower and step, a sum of named, weighted terms "
        '(`platoon_env.reward`; each step\'s terms are in `info[agent]["reward_terms"]`). '
        "`e_d = d − d_des` and `β` are the errors of the paper's eq. 7. The weights `w` are "
        "the scenario's `reward` block (`reward={...}` overrides them):\n\n"
        f"{per_scenario(fs, rows)}\n\n"
        "The reward is a training signal only. The cost of constrained RL is separate: "
        '`info[agent]["cost"]` is 1 in a step with a violation of any cause, else 0. The '
        "benchmark's metrics are computed from ground truth ([metrics.md](../metrics.md))."
    )


def section_episode_end(fam: Family, fs: Sequence[Facts]) -> str:
    terminate = [set(f.config.safety.terminate_on) for f in fs]
    rows = [
        [
            str(k + 1),
            code(cause),
            CAUSE_MEANING[cause],
            "yes" if all(cause in t for t in terminate) else "no",
        ]
        for k, cause in enumerate(VIOLATION_CAUSES)
    ]
    settle = sorted({num(f.config.leader.settle_time) for f in fs})
    limits = ", ".join(f"{code(f.name)} {_step_limit(f)}" for f in fs)
    return (
        "Every follower is checked against five causes after every physics sub-step "
        "([safety.md](../safety.md)):\n\n"
        f"{table(['#', 'cause', 'a follower violates it when', 'terminates here'], rows)}\n\n"
        "**Termination.** The episode terminates for all agents when any follower has a "
        "violation whose cause is in `terminate_on` (by default all five; "
        '`terminate_on=("collision_robot", "collision_obstacle")` keeps going after a lost '
        "predecessor, `terminate_on=()` only reports). The step stops at the sub-step of the "
        'violation. `info[agent]["violation"]` names the first cause in the order above, '
        '`info[agent]["violations"]` all of them.\n\n'
        "**Truncation.** Otherwise the episode is truncated for all agents when the leader "
        f"has reached the end of its path and {' or '.join(settle)} s (`leader.settle_time`) "
        "have passed, or at the step limit (`max_episode_steps`; by default twice the slowest "
        "drawn leader's driving time plus the settle time and 10 s, in steps): "
        f"{limits}. Terminated and truncated are never both true; after either, "
        "`env.agents` is empty until `reset()`."
    )


def section_arguments(fam: Family, fs: Sequence[Facts]) -> str:
    def field(f: Facts, option: str) -> str:
        block, key = _SHORTCUT_FIELDS[option]
        holder = f.config if block is None else getattr(f.config, block)
        value = getattr(holder, key)
        if option == "followers":
            return _followers(f)
        if option == "max_episode_steps" and value is None:
            return "null: " + _step_limit(f)
        if isinstance(value, tuple):
            return "all five" if set(value) == set(VIOLATION_CAUSES) else ", ".join(value)
        if isinstance(value, bool):
            return str(value)
        return num(value)

    def value(option: str) -> Callable[[Facts], str]:
        return lambda f: field(f, option)

    rows = [
        (f"`{o}` (sets `{'.'.join(p for p in _SHORTCUT_FIELDS[o] if p)}`)", value(o))
        for o in SCENARIO_OPTIONS
    ]
    blocks = ", ".join(code(b) for b in BLOCK_OPTIONS)
    profiles = ", ".join(code(p) for p in list_profiles())
    gym_only = [o for o in GYM_OPTIONS if o not in ENV_OPTIONS]
    vec_only = [o for o in VECTOR_OPTIONS if o not in GYM_OPTIONS]
    return (
        f'`platoon_env.make("{fs[0].name}", **overrides)` (also `parallel_env`, `env`, '
        "`BatchedPlatoon`, `gymnasium.make` and `gymnasium.make_vec` on the ids) takes "
        "overrides checked by the scenario schema's own rules: a bad value is a "
        "`ScenarioError` (a `ValueError`) naming the option, an unknown name a `TypeError`. "
        "The shortcuts, with this page's values:\n\n"
        f"{per_scenario(fs, rows)}\n\n"
        f"- **Blocks**: {blocks}. A mapping merges into that block of the scenario, e.g. "
        '`camera={"half_angle": 0.5}`, `formation={"d_des": 1.5}`, '
        '`reward={"wall": 0.0}` ([scenarios.md](../scenarios.md#overrides-from-make)).\n'
        f"- **`{PROFILE_OPTION}`**: a shipped sensor profile ({profiles}) or a YAML file, "
        "merged before the blocks ([realism.md](../realism.md#the-aruco-profile)).\n"
        f"- **Env options**: {', '.join(code(o) for o in ENV_OPTIONS)} "
        "(`diagnostics=False` keeps only the violation entries and the cost in `info`; "
        '`info_view="numeric"` gives fixed keys of numpy scalars, '
        "[api.md](../api.md#the-info-views)).\n"
        f"- **Gymnasium ids only**: {', '.join(code(o) for o in gym_only)}; "
        f"`gymnasium.make_vec` also {', '.join(code(o) for o in vec_only)} "
        "([api.md](../api.md#gymnasium-vector-api))."
    )


def section_gym_ids(fam: Family, fs: Sequence[Facts]) -> str:
    ids = [(f, i) for f in fs for i in f.gym_ids]
    if not ids:
        return (
            "None: these scenarios have no registered id. "
            "`platoon_env.gym_env.SingleFollowerEnv(scenario)` gives the same single-follower "
            "view of any scenario."
        )
    rows = []
    for f, i in ids:
        spec = gym.spec(i)
        profile = GYM_IDS[i].get("sensor_profile")
        sensors = "ideal" if profile is None else f"profile {code(profile)}"
        rows.append([code(i), code(f.name), sensors, str(spec.max_episode_steps)])
    probe = gym.make_vec(ids[0][1], num_envs=2)
    autoreset = getattr(probe, "autoreset_mode", probe.metadata.get("autoreset_mode"))
    vec_class = type(probe).__name__
    probe.close()
    first = ids[0][1]
    return (
        "One follower behind the scripted leader, registered on `import platoon_env` "
        "(`platoon_env.gym_env.SingleFollowerEnv`: the observation, action and reward of the "
        "parallel env's one follower; a scenario that draws its number of followers draws "
        "one). The `-Aruco` ids use the `aruco` sensor profile "
        "([realism.md](../realism.md#the-aruco-profile)). `max_episode_steps` is the "
        "`TimeLimit` that `gymnasium.make` adds; it ends no episode before the env's own "
        "limit does.\n\n"
        f"{table(['id', 'scenario', 'sensors', 'max_episode_steps'], rows)}\n\n"
        "```python\n"
        "import gymnasium as gym\n"
        "import platoon_env  # registers the ids\n\n"
        f'env = gym.make("{first}", normalize_actions=True)\n'
        "# eight copies in one batched core, stepped by one compiled call\n"
        f'envs = gym.make_vec("{first}", num_envs=8)\n'
        "```\n\n"
        f"`gymnasium.make_vec` builds a `{vec_class}` (autoreset mode "
        f"`{getattr(autoreset, 'name', autoreset)}` by default)."
    )


def _changelog_sections() -> list[str]:
    """The ``## `` headings of the repository's CHANGELOG.md, newest first."""
    path = ROOT / "CHANGELOG.md"
    if not path.is_file():
        return []
    lines = path.read_text(encoding="utf-8").splitlines()
    return [line[3:].strip() for line in lines if line.startswith("## ")]


def section_version(fam: Family, fs: Sequence[Facts]) -> str:
    versions = sorted({i.rsplit("-", 1)[1] for f in fs for i in f.gym_ids})
    ids = (
        f"every id of this page ends in {', '.join(code('-' + v) for v in versions)}"
        if versions
        else "these scenarios have no Gymnasium id"
    )
    sections = _changelog_sections()
    listed = f" (its sections: {', '.join(f'*{name}*' for name in sections)})" if sections else ""
    history = "\n".join(
        f"- **{version}** (platoon_env {package}): {what}."
        for version, package, what in VERSION_HISTORY
    )
    return (
        f"{history}\n\nplatoon_env is at version {platoon_env.__version__}, and {ids} "
        f'(`PlatoonParallelEnv.metadata["name"]` is '
        f"`{PlatoonParallelEnv.metadata['name']}`). An older id is refused by "
        "`gymnasium.make` with Gymnasium's `DeprecatedEnv`, which names the current one; the "
        "policy is in [versioning](../versioning.md). Every change of the package is listed in "
        f"the repository's [CHANGELOG.md](../../CHANGELOG.md){listed}. A scenario's content "
        "fingerprint (`platoon_env.scenarios.fingerprint`) names exactly what an episode ran on."
    )


SECTIONS: tuple[tuple[str, Callable[[Family, Sequence[Facts]], str]], ...] = (
    ("Description", section_description),
    ("Action space", section_action),
    ("Observation space", section_observation),
    ("Rewards", section_rewards),
    ("Episode end", section_episode_end),
    ("Arguments", section_arguments),
    ("Gymnasium ids", section_gym_ids),
    ("Version history", section_version),
)


def render(fam: Family) -> str:
    fs = [facts(name) for name in fam.scenarios]
    parts = [f"# {fam.title}", HEADER, section_glance(fam, fs)]
    parts += [f"## {title}\n\n{make(fam, fs)}" for title, make in SECTIONS]
    for f in fs:
        f.env.close()
    return "\n\n".join(parts) + "\n"


def render_index() -> str:
    shipped = set(platoon_env.list_scenarios())
    covered = {n for fam in FAMILIES for n in fam.scenarios}
    if shipped != covered:  # a new shipped scenario needs a family (and prose) here
        raise SystemExit(
            "gen_env_pages.py: FAMILIES must cover platoon_env.list_scenarios() exactly; "
            f"missing {sorted(shipped - covered)}, unknown {sorted(covered - shipped)}"
        )
    rows = [
        [
            f"[{fam.title}]({fam.slug}.md)",
            ", ".join(code(n) for n in fam.scenarios),
            fam.summary,
            str(sum(1 for kw in GYM_IDS.values() if kw["scenario"] in fam.scenarios)),
        ]
        for fam in FAMILIES
    ]
    toc = "\n".join(fam.slug for fam in FAMILIES)
    return (
        "# Environments\n\n"
        f"{HEADER}\n\n"
        f"Every shipped scenario ({len(shipped)}, `platoon_env.list_scenarios()`), by family. "
        "Each is a PettingZoo `ParallelEnv` (`platoon_env.make(name)`); the paper's studies "
        f"and the tiers also have Gymnasium ids for one follower ({len(GYM_IDS)} in all, "
        "`platoon_env.GYM_IDS`). A page per family, in the layout of Gymnasium's environment "
        "pages.\n\n"
        f"{table(['family', 'scenarios', 'what it is', 'Gymnasium ids'], rows)}\n\n"
        "```{toctree}\n:hidden:\n\n"
        f"{toc}\n"
        "```\n"
    )


def pages() -> dict[Path, str]:
    out = {OUT / "index.md": render_index()}
    for fam in FAMILIES:
        out[OUT / f"{fam.slug}.md"] = render(fam)
    return out


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument(
        "--check", action="store_true", help="write nothing; exit 1 if a page is out of date"
    )
    args = parser.parse_args(argv)
    written = pages()
    stale = sorted(
        str(path.relative_to(ROOT))
        for path, text in written.items()
        if not path.is_file() or path.read_text(encoding="utf-8") != text
    )
    extra = sorted(str(p.relative_to(ROOT)) for p in OUT.glob("*.md") if p not in written)
    if args.check:
        for name in stale:
            print(f"{name}: out of date; run python docs/gen_env_pages.py", file=sys.stderr)
        for name in extra:
            print(f"{name}: not written by docs/gen_env_pages.py; remove it", file=sys.stderr)
        return 1 if stale or extra else 0
    OUT.mkdir(parents=True, exist_ok=True)
    for path, text in written.items():
        path.write_text(text, encoding="utf-8")
    for name in extra:
        print(f"{name}: not written by docs/gen_env_pages.py; left as is", file=sys.stderr)
    print(f"wrote {len(written)} pages to {OUT.relative_to(ROOT)}/ ({len(stale)} changed)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
