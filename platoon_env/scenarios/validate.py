"""The range checks of a parsed scenario (:func:`check_ranges`) and the bounds they enforce.

:func:`platoon_env.scenarios.schema.parse_scenario` runs :func:`check_ranges` on every config it
builds, so a scenario file, a mapping and a keyword override are held to the same rules. Each
rule names the field and the offending value. Geometric validation (polygons, leader-path
clearance, feasibility of the initial configuration) happens in
:func:`platoon_env.scenarios.scenario.build_scenario`, once the workspace geometry is built.
"""

from __future__ import annotations

import math
from dataclasses import asdict

import numpy as np

from platoon_env.config import (
    FORMATION_GAP,
    GENERATOR_KINDS,
    GENERATOR_SPLITS,
    GENERATOR_TIERS,
    MAX_DRAWN_FOLLOWERS,
    FormationRanges,
    Point,
    ScenarioConfig,
    field_error,
    require,
    shown,
)
from platoon_env.realism import check_realism_ranges
from platoon_env.scenarios.trajectory import (
    check_leader_drive,
    check_trajectory_motion,
    check_trajectory_times,
    polyline_length,
    trajectory_length,
    trajectory_mean_speed,
)
from platoon_env.violations import VIOLATION_CAUSES

#: [m/s or rad/s] Range of ``robot.u_max`` and ``robot.omega_max``. They are the bounds of the
#: float32 action Box: far inside float32's range (no overflow to inf, no underflow to 0, no
#: bound so small that ``low == high``) and far beyond any physical unicycle. The leader's
#: ``leader.speed`` and ``leader.max_turn_rate`` lie in the same range (a slower leader makes
#: the default step limit, which divides the path length by the speed, overflow).
ACTION_BOUND_RANGE: tuple[float, float] = (1e-6, 1e6)
#: [s] Upper bound on ``simulation.control_period``. One action is held this long; beyond a
#: second a follower crosses its whole sensing range between two decisions, and much larger
#: (finite) values overflow the pose integration.
MAX_CONTROL_PERIOD: float = 1.0
#: [s] Lower bound on ``simulation.control_period``: 10 us, a 100 kHz control loop, far
#: faster than any camera. Below it the step counts derived from a time (the default step
#: limit, the latency in periods, the frame hold) grow without bound.
MIN_CONTROL_PERIOD: float = 1e-5
#: Upper bound on ``simulation.physics_substeps``. A step integrates every robot once per
#: sub-step, so its cost is linear in it; 1000 sub-steps of the largest control period are
#: 1 ms arcs, far finer than the exact arc integration needs (the shipped scenarios use 2).
MAX_PHYSICS_SUBSTEPS: int = 1000
#: Upper bound on ``followers``: the per-robot arrays (poses, observations, frame history)
#: are allocated for this many robots.
MAX_FOLLOWERS: int = 1000
#: Upper bound on ``simulation.max_episode_steps`` and on the default step limit derived from
#: the path (:func:`default_max_steps`): 10**9 steps, about a day of compute at the fastest step
#: rate, far within the int64 the core stores it in.
MAX_EPISODE_STEPS: int = 10**9
#: [s] Upper bound on ``leader.settle_time`` (about 11.6 days of simulated time).
MAX_SETTLE_TIME: float = 1e6
#: [m] Bound on the absolute value of every coordinate (workspace bounds, polygons, leader
#: path): 1000 km, beyond any room or corridor, and far from where lengths and areas overflow.
MAX_COORDINATE: float = 1e6
#: Longest camera latency, in control periods (the core keeps a frame history this long).
MAX_LATENCY_STEPS = 1000
#: Largest ``leader.speed_variation`` (the slowest leader drives at 1 - this of its speed).
MAX_SPEED_VARIATION: float = 0.9


def default_max_steps(cfg: ScenarioConfig, path_length: float) -> int:
    """Steps for twice the slowest leader's driving time (speed ``leader.speed * (1 -
    leader.speed_variation)``; a trajectory: its mean speed), its settle time and 10 s more."""
    slowest = cfg.leader.speed * (1.0 - cfg.leader.speed_variation)
    seconds = 2.0 * path_length / slowest + cfg.leader.settle_time + 10.0
    return math.ceil(seconds / cfg.simulation.control_period)


def check_ranges(cfg: ScenarioConfig, path: str = "scenario") -> None:
    """Check every scalar parameter against the ranges the model needs.

    Every message names the field and the offending value. Beyond the model's own ranges
    (``docs/safety.md``: ``d_col >= 2r``, ``d_col < d_des < d_con``, ``0 < beta_con < pi/2``)
    this bounds what would overflow or allocate without limit: the actuator limits and the
    leader's speed and turn rate to :data:`ACTION_BOUND_RANGE`, the control period to
    ``[MIN_CONTROL_PERIOD, MAX_CONTROL_PERIOD]``, ``followers`` to :data:`MAX_FOLLOWERS`,
    ``physics_substeps`` to :data:`MAX_PHYSICS_SUBSTEPS`, ``max_episode_steps`` (given, or the
    default derived from the leader's path) to :data:`MAX_EPISODE_STEPS`, ``settle_time`` to
    :data:`MAX_SETTLE_TIME` and every coordinate to :data:`MAX_COORDINATE`. A timed trajectory
    must be one the leader can drive
    (:func:`~platoon_env.scenarios.trajectory.check_trajectory_motion`), and with
    ``leader.drive`` set the leader keeps the robots' drive
    (:func:`~platoon_env.scenarios.trajectory.check_leader_drive`).
    """
    _check_platoon(cfg, path)
    _check_leader(cfg, path)
    _check_coordinates(cfg, path)
    _check_leader_motion(cfg, path)
    check_leader_drive(cfg, path)
    if cfg.generator is None:
        _check_leader_route(cfg, path)
    else:
        _check_generator(cfg, path)
    _check_sensing_and_formation(cfg, path)
    _check_safety(cfg, path)
    _check_simulation(cfg, path)
    _check_reward_and_initial(cfg, path)
    _check_ppc(cfg, path)
    _check_realism(cfg, path)
    check_realism_ranges(cfg, path, MAX_LATENCY_STEPS)
    _check_observation(cfg, path)


def _check_platoon(cfg: ScenarioConfig, path: str) -> None:
    """The number of followers, the robots' radius and their action bounds."""
    n = cfg.followers
    require(n >= 1, f"{path}.followers", f"must be >= 1, got {shown(n)}")
    require(
        n <= MAX_FOLLOWERS,
        f"{path}.followers",
        f"must be at most {MAX_FOLLOWERS} (MAX_FOLLOWERS), got {shown(n)}",
    )
    r = cfg.robot.radius
    require(r > 0, f"{path}.robot.radius", f"must be > 0, got {r!r}")
    lo, hi = ACTION_BOUND_RANGE
    for name in ("u_max", "omega_max"):
        bound = getattr(cfg.robot, name)
        require(
            lo <= bound <= hi,
            f"{path}.robot.{name}",
            f"must lie in [{lo:g}, {hi:g}] (a float32 action bound), got {bound!r}",
        )


def _check_leader(cfg: ScenarioConfig, path: str) -> None:
    """The leader's speed (a trajectory's: its mean speed), turn rate, lookahead and settle time."""
    lo, hi = ACTION_BOUND_RANGE
    lead = cfg.leader
    for name, unit in (("speed", "m/s"), ("max_turn_rate", "rad/s")):
        value = getattr(lead, name)
        if name == "speed" and lead.trajectory:
            require(
                lo <= value <= hi,
                f"{path}.leader.trajectory",
                f"its mean speed (length over duration) must lie in [{lo:g}, {hi:g}] {unit} "
                f"(ACTION_BOUND_RANGE), got {value!r}",
            )
            continue
        require(
            lo <= value <= hi,
            f"{path}.leader.{name}",
            f"must lie in [{lo:g}, {hi:g}] {unit} (ACTION_BOUND_RANGE), got {value!r}",
        )
    require(lead.lookahead > 0, f"{path}.leader.lookahead", f"must be > 0, got {lead.lookahead!r}")
    require(
        lead.settle_time >= 0,
        f"{path}.leader.settle_time",
        f"must be >= 0, got {lead.settle_time!r}",
    )
    require(
        lead.settle_time <= MAX_SETTLE_TIME,
        f"{path}.leader.settle_time",
        f"must be at most {MAX_SETTLE_TIME:g} s (MAX_SETTLE_TIME), got {lead.settle_time!r}",
    )


def _check_coordinates(cfg: ScenarioConfig, path: str) -> None:
    """Every coordinate of the workspace and the leader's path within ``MAX_COORDINATE``."""
    ws = cfg.workspace
    groups: list[tuple[str, tuple[Point, ...]]] = [
        ("leader.path", cfg.leader.path),
        ("leader.trajectory", tuple((x, y) for _, x, y, _ in cfg.leader.trajectory)),
    ]
    if ws.bounds is not None:
        x0, y0, x1, y1 = ws.bounds
        groups.append(("workspace.bounds", ((x0, y0), (x1, y1))))
    if ws.free_space is not None:
        groups.append(("workspace.free_space.exterior", ws.free_space.exterior))
        for k, hole in enumerate(ws.free_space.holes):
            groups.append((f"workspace.free_space.holes[{k}]", hole))
    for k, obstacle in enumerate(ws.obstacles):
        groups.append((f"workspace.obstacles[{k}]", obstacle))
    for k, sample in enumerate(cfg.leader.trajectory):
        require(
            abs(sample[3]) <= MAX_COORDINATE,
            f"{path}.leader.trajectory[{k}]",
            f"theta must lie in [-{MAX_COORDINATE:g}, {MAX_COORDINATE:g}] rad, got {sample[3]!r}",
        )
    for where, points in groups:
        # One array test per group (a layout has hundreds of points); the loop names the first.
        if not points or float(np.max(np.abs(np.asarray(points, dtype=np.float64)))) <= (
            MAX_COORDINATE
        ):
            continue
        for k, (x, y) in enumerate(points):
            require(
                abs(x) <= MAX_COORDINATE and abs(y) <= MAX_COORDINATE,
                f"{path}.{where}" if where == "workspace.bounds" else f"{path}.{where}[{k}]",
                f"coordinates must lie in [-{MAX_COORDINATE:g}, {MAX_COORDINATE:g}] m "
                f"(MAX_COORDINATE), got {[x, y]!r}",
            )


def _check_leader_motion(cfg: ScenarioConfig, path: str) -> None:
    """The episode's speed factor range and the fastest leader it gives."""
    lead = cfg.leader
    hi = ACTION_BOUND_RANGE[1]
    variation = lead.speed_variation
    require(
        0.0 <= variation <= MAX_SPEED_VARIATION,
        f"{path}.leader.speed_variation",
        f"must lie in [0, {MAX_SPEED_VARIATION:g}] (MAX_SPEED_VARIATION), got {variation!r}",
    )
    require(
        lead.speed * (1.0 + variation) <= hi,
        f"{path}.leader.speed_variation",
        f"the fastest leader, speed * (1 + speed_variation) = "
        f"{lead.speed * (1.0 + variation):g} m/s, must be at most {hi:g} m/s "
        "(ACTION_BOUND_RANGE)",
    )


def _check_leader_route(cfg: ScenarioConfig, path: str) -> None:
    """A fixed scenario's leader: exactly one of a path (two points or more) and a trajectory
    (its samples, its speed the mean speed, drivable by the leader)."""
    lead = cfg.leader
    require(
        (len(lead.path) > 0) != (len(lead.trajectory) > 0),
        f"{path}.leader",
        "give exactly one of 'path' (pure pursuit at 'speed') and 'trajectory' "
        "([[t, x, y, theta], ...] replayed exactly), got " + ("both" if lead.path else "neither"),
    )
    if not lead.trajectory:
        require(
            len(lead.path) >= 2,
            f"{path}.leader.path",
            f"needs at least two points, got {len(lead.path)}",
        )
        return
    check_trajectory_times(lead.trajectory, f"{path}.leader.trajectory")
    mean = trajectory_mean_speed(lead.trajectory)
    require(
        abs(lead.speed - mean) <= 1e-9 * mean,
        f"{path}.leader.speed",
        f"with a trajectory the leader's speed is the trajectory's mean speed (its length over "
        f"its duration), {mean!r} m/s: leave it out, got {lead.speed!r}",
    )
    check_trajectory_motion(cfg, path)


def _check_generator(cfg: ScenarioConfig, path: str) -> None:
    """A procedural scenario: no trajectory (each layout draws its path) and a known kind,
    split and tier."""
    gen = cfg.generator
    assert gen is not None
    require(
        not cfg.leader.trajectory,
        f"{path}.leader.trajectory",
        "a procedural scenario (with a 'generator' block) draws each layout's leader "
        "path; it takes no trajectory",
    )
    require(
        gen.kind in GENERATOR_KINDS,
        f"{path}.generator.kind",
        f"expected one of {', '.join(GENERATOR_KINDS)}, got {gen.kind!r}",
    )
    require(
        gen.split in GENERATOR_SPLITS,
        f"{path}.generator.split",
        f"expected one of {', '.join(GENERATOR_SPLITS)}, got {gen.split!r}",
    )
    require(
        gen.tier is None or gen.tier in GENERATOR_TIERS,
        f"{path}.generator.tier",
        f"expected one of {', '.join(GENERATOR_TIERS)} (or no tier), got {gen.tier!r}",
    )
    if gen.formation is not None:
        formation_limits(cfg, path)


#: The distances of a drawn formation, in the order they are drawn, by their
#: :class:`~platoon_env.config.FormationRanges` field.
FORMATION_DISTANCES: tuple[str, ...] = ("radius", "d_col", "d_des", "d_con")


def formation_gap(cfg: ScenarioConfig) -> float:
    """[m] The least gap of a drawn formation between ``d_col`` and ``d_des`` and between
    ``d_des`` and ``d_con``: :data:`~platoon_env.config.FORMATION_GAP`, plus ``2 rho_d_inf``
    with a ``ppc`` block (so that its funnels fit inside the constraints, as
    :func:`check_ranges` requires)."""
    return FORMATION_GAP + (2.0 * cfg.ppc.rho_d_inf if cfg.ppc is not None else 0.0)


def formation_limits(cfg: ScenarioConfig, path: str = "scenario") -> dict[str, tuple[float, float]]:
    """The ranges a procedural template's ``generator.formation`` draws from, tightened so that
    every sequential draw is consistent (:func:`platoon_env.scenarios.procedural.draw_formation`):
    ``{field: (lo, hi)}`` for every :class:`~platoon_env.config.FormationRanges` field, a
    field left out taking the template's value.

    The distances are drawn in :data:`FORMATION_DISTANCES` order, each from ``[max(lo,
    floor(previous)), hi']``: ``d_col >= 2 r``, ``d_des >= d_col + g``, ``d_con >= d_des + g``
    (``g`` = :func:`formation_gap`), where ``hi'`` is the range's upper end lowered until the
    later ones can still be drawn. The lower ends returned are the least values (the chain of
    lower ends), the upper ends ``hi'``. Raises ``ScenarioError`` naming the field for an
    empty range (``lo > hi``), a value out of the model's range, or ranges that admit no
    consistent formation.
    """
    gen = cfg.generator
    assert gen is not None and gen.formation is not None
    ranges: FormationRanges = gen.formation
    where = f"{path}.generator.formation"
    template = {
        "followers": (cfg.followers, cfg.followers),
        "radius": (cfg.robot.radius, cfg.robot.radius),
        "d_col": (cfg.safety.d_col, cfg.safety.d_col),
        "d_des": (cfg.formation.d_des, cfg.formation.d_des),
        "d_con": (cfg.camera.range, cfg.camera.range),
        "beta_con": (cfg.camera.half_angle, cfg.camera.half_angle),
        "leader_speed": (cfg.leader.speed, cfg.leader.speed),
    }
    raw: dict[str, tuple[float, float]] = {}
    for name, default in template.items():
        given = getattr(ranges, name)
        lo, hi = default if given is None else given
        require(lo <= hi, f"{where}.{name}", f"empty range: lo must be <= hi, got [{lo}, {hi}]")
        raw[name] = (lo, hi)
    n_lo, n_hi = raw["followers"]
    require(
        1 <= n_lo and n_hi <= MAX_DRAWN_FOLLOWERS,
        f"{where}.followers",
        f"must lie in [1, {MAX_DRAWN_FOLLOWERS}] (MAX_DRAWN_FOLLOWERS), got [{n_lo}, {n_hi}]",
    )
    r_lo = raw["radius"][0]
    require(r_lo > 0, f"{where}.radius", f"must be > 0, got [{r_lo}, {raw['radius'][1]}]")
    b_lo, b_hi = raw["beta_con"]
    floor = 2.0 * cfg.ppc.rho_beta_inf if cfg.ppc is not None else 0.0
    require(
        floor < b_lo and b_hi < math.pi / 2,
        f"{where}.beta_con",
        f"must lie in ({floor:g}, pi/2) (0 < beta_con < pi/2, and 2 * ppc.rho_beta_inf < "
        f"beta_con), got [{b_lo}, {b_hi}]",
    )
    v_lo, v_hi = raw["leader_speed"]
    a_lo, a_hi = ACTION_BOUND_RANGE
    require(
        a_lo <= v_lo and v_hi <= a_hi,
        f"{where}.leader_speed",
        f"must lie in [{a_lo:g}, {a_hi:g}], got [{v_lo}, {v_hi}]",
    )
    gap = formation_gap(cfg)
    names = FORMATION_DISTANCES
    floors = (0.0, 0.0, gap, gap)  # what the previous distance adds: r; 2 r; + g; + g
    factor = (1.0, 2.0, 1.0, 1.0)
    # the chain of lower ends (each raised by the previous one) and of upper ends (each
    # lowered by the next one), and which field's own range set each end
    lows, low_from = [raw[names[0]][0]], [0]
    for k in range(1, 4):
        chained = factor[k] * lows[k - 1] + floors[k]
        own = raw[names[k]][0]
        lows.append(max(own, chained))
        low_from.append(k if own >= chained else low_from[k - 1])
    highs, high_from = [0.0, 0.0, 0.0, raw[names[3]][1]], [0, 0, 0, 3]
    for k in range(2, -1, -1):
        chained = (highs[k + 1] - floors[k + 1]) / factor[k + 1]
        own = raw[names[k]][1]
        highs[k] = min(own, chained)
        high_from[k] = k if own <= chained else high_from[k + 1]
    for k, name in enumerate(names):
        if lows[k] > highs[k]:
            # name a range the user gave that is in the conflict (the one that emptied it)
            blame = names[high_from[k]] if high_from[k] != k else names[low_from[k]]
            if getattr(ranges, blame) is None:
                blame = name
            lo_name, hi_name = names[low_from[k]], names[high_from[k]]
            raise field_error(
                f"{where}.{blame}",
                f"no consistent formation: {name} must be >= {lows[k]:g} (from {lo_name}'s "
                f"range) and <= {highs[k]:g} (from {hi_name}'s range) under the chain 2 r <= "
                f"d_col, d_col + g <= d_des, d_des + g <= d_con (g = {gap:g} m: FORMATION_GAP, "
                "plus 2 ppc.rho_d_inf with a ppc block); ranges: "
                + ", ".join(f"{n} [{raw[n][0]:g}, {raw[n][1]:g}]" for n in names),
            )
    out = dict(raw)
    for k, name in enumerate(FORMATION_DISTANCES):
        out[name] = (lows[k], highs[k])
    return out


def _check_observation(cfg: ScenarioConfig, path: str) -> None:
    """``observation.scale_free`` needs ``observation.task_aware`` (its layout holds the task
    inputs)."""
    obs = cfg.observation
    require(
        obs.task_aware or not obs.scale_free,
        f"{path}.observation.scale_free",
        "needs observation.task_aware: true (the scale-free layout expresses the task-aware "
        "observation in the task's units; pass observation={'task_aware': True, "
        "'scale_free': True})",
    )


def _check_sensing_and_formation(cfg: ScenarioConfig, path: str) -> None:
    """The camera's field of view (eq. 5) and ``2r <= d_col < d_des < d_con`` (eq. 4,
    Problem 1)."""
    r = cfg.robot.radius
    bc, dcon = cfg.camera.half_angle, cfg.camera.range
    require(
        0 < bc < math.pi / 2,
        f"{path}.camera.half_angle",
        f"beta_con must satisfy 0 < beta_con < pi/2, got {bc!r}",
    )
    require(dcon > 0, f"{path}.camera.range", f"d_con must be > 0, got {dcon!r}")
    require(
        dcon <= MAX_COORDINATE,
        f"{path}.camera.range",
        f"d_con must be <= {MAX_COORDINATE:g} m (the observation space's bound, float32), "
        f"got {dcon!r}",
    )
    dcol, ddes = cfg.safety.d_col, cfg.formation.d_des
    require(
        dcol >= 2 * r - 1e-12,
        f"{path}.safety.d_col",
        f"d_col must be >= r_i + r_(i-1) = {2 * r:g}, got {dcol:g}",
    )
    require(
        dcol < ddes < dcon,
        f"{path}.formation.d_des",
        f"d_des must lie in (d_col, d_con) = ({dcol:g}, {dcon:g}), got {ddes:g}",
    )


def _check_safety(cfg: ScenarioConfig, path: str) -> None:
    """The obstacles' inflation, the causes that end an episode and the proximity sensor."""
    inflation = cfg.safety.inflation
    prox = cfg.proximity_range
    require(
        inflation >= 0.0,
        f"{path}.safety.inflation",
        f"must be >= 0 (the obstacles' margin), got {inflation!r}",
    )
    require(
        inflation < prox,
        f"{path}.safety.inflation",
        f"must be below the proximity range {prox:g} m (a sensor that sees no "
        f"farther than the margin reads 0 everywhere), got {inflation!r}",
    )
    for cause in cfg.safety.terminate_on:
        require(
            cause in VIOLATION_CAUSES,
            f"{path}.safety.terminate_on",
            f"unknown cause {cause!r} (expected some of {', '.join(VIOLATION_CAUSES)})",
        )
    r = cfg.robot.radius
    require(
        prox > r, f"{path}.proximity.range", f"must exceed the robot radius {r:g}, got {prox!r}"
    )
    require(
        prox <= MAX_COORDINATE,
        f"{path}.proximity.range",
        f"must be <= {MAX_COORDINATE:g} m (the observation space's bound, float32), got {prox!r}",
    )
    sector = cfg.proximity.half_angle
    require(
        sector is None or 0 < sector <= math.pi,
        f"{path}.proximity.half_angle",
        f"must satisfy 0 < half_angle <= pi, got {sector!r}",
    )


def _check_simulation(cfg: ScenarioConfig, path: str) -> None:
    """The time discretisation and the step limit, given or derived (all bounded)."""
    sim = cfg.simulation
    dt = sim.control_period
    require(
        0 < dt <= MAX_CONTROL_PERIOD,
        f"{path}.simulation.control_period",
        f"must lie in (0, {MAX_CONTROL_PERIOD:g}] s, got {dt!r}",
    )
    require(
        dt >= MIN_CONTROL_PERIOD,
        f"{path}.simulation.control_period",
        f"must be at least {MIN_CONTROL_PERIOD:g} s (MIN_CONTROL_PERIOD), got {dt!r}",
    )
    substeps = sim.physics_substeps
    require(
        substeps >= 1,
        f"{path}.simulation.physics_substeps",
        f"must be >= 1, got {shown(substeps)}",
    )
    require(
        substeps <= MAX_PHYSICS_SUBSTEPS,
        f"{path}.simulation.physics_substeps",
        f"must be at most {MAX_PHYSICS_SUBSTEPS} (MAX_PHYSICS_SUBSTEPS), got {shown(substeps)}",
    )
    steps = sim.max_episode_steps
    where = f"{path}.simulation.max_episode_steps"
    if steps is not None:
        require(steps >= 1, where, f"must be >= 1, got {shown(steps)}")
        require(
            steps <= MAX_EPISODE_STEPS,
            where,
            f"must be at most {MAX_EPISODE_STEPS} (MAX_EPISODE_STEPS), got {shown(steps)}",
        )
    elif cfg.generator is None and (len(cfg.leader.path) >= 2 or cfg.leader.trajectory):
        # The default limit follows the path (a procedural template has none yet; each layout
        # is checked when it is built). The bounds above keep it finite; bound it as a given one.
        if cfg.leader.trajectory:
            length = trajectory_length(cfg.leader.trajectory)
        else:
            length = polyline_length(np.asarray(cfg.leader.path, dtype=np.float64))
        default = default_max_steps(cfg, length)
        require(
            default <= MAX_EPISODE_STEPS,
            where,
            f"not given, and the default (2 * path length / (leader.speed * (1 - "
            f"speed_variation)) + settle_time + 10 s in control periods) would be {default} "
            f"steps, more than {MAX_EPISODE_STEPS} (MAX_EPISODE_STEPS): set it, or a faster "
            "leader.speed or a longer control_period",
        )


def _check_reward_and_initial(cfg: ScenarioConfig, path: str) -> None:
    """Finite reward weights, a positive wall margin and non-negative start perturbations."""
    for name, value in asdict(cfg.reward).items():
        require(math.isfinite(value), f"{path}.reward.{name}", f"must be finite, got {value!r}")
    margin = cfg.reward.wall_margin
    require(margin > 0, f"{path}.reward.wall_margin", f"must be > 0, got {margin!r}")
    for name in ("position_noise", "heading_noise"):
        noise = getattr(cfg.initial, name)
        require(noise >= 0, f"{path}.initial.{name}", f"must be >= 0, got {noise!r}")


def _check_ppc(cfg: ScenarioConfig, path: str) -> None:
    """The PPC law's parameters (eqs. 12-14) and its funnels inside the constraints."""
    p = cfg.ppc
    if p is None:
        return
    dcol, ddes, dcon = cfg.safety.d_col, cfg.formation.d_des, cfg.camera.range
    bc = cfg.camera.half_angle
    for name in ("lambda_", "rho_d_inf", "rho_beta_inf", "k_d", "k_beta", "delta"):
        key = "lambda" if name == "lambda_" else name
        value = getattr(p, name)
        require(value > 0, f"{path}.ppc.{key}", f"must be > 0, got {value!r}")
    require(0 < p.epsilon < 1, f"{path}.ppc.epsilon", f"must lie in (0, 1), got {p.epsilon!r}")
    require(
        2 * p.rho_d_inf < min(ddes - dcol, dcon - ddes),
        f"{path}.ppc.rho_d_inf",
        "2 * rho_d_inf must be smaller than both d_des - d_col and d_con - d_des "
        f"= {min(ddes - dcol, dcon - ddes):g}, got rho_d_inf = {p.rho_d_inf!r}",
    )
    require(
        2 * p.rho_beta_inf < bc,
        f"{path}.ppc.rho_beta_inf",
        f"2 * rho_beta_inf must be < beta_con = {bc:g}, got rho_beta_inf = {p.rho_beta_inf!r}",
    )


def _check_realism(cfg: ScenarioConfig, path: str) -> None:
    """Ranges of the sensing and actuation realism (``docs/realism.md``)."""
    cam, noise = cfg.camera, cfg.camera.noise
    for name in ("position", "position_per_m", "bearing"):
        value = getattr(noise, name)
        require(value >= 0, f"{path}.camera.noise.{name}", f"must be >= 0, got {value!r}")
    require(
        0 <= cam.detection <= 1,
        f"{path}.camera.detection",
        f"must be a probability in [0, 1], got {cam.detection!r}",
    )
    require(
        0 <= cam.detection_edge <= 1,
        f"{path}.camera.detection_edge",
        f"must lie in [0, 1], got {cam.detection_edge!r}",
    )
    dt = cfg.simulation.control_period
    if cam.frame_rate is not None:
        require(
            0 < cam.frame_rate <= 1.0 / dt + 1e-9,
            f"{path}.camera.frame_rate",
            f"must lie in (0, 1 / control_period = {1.0 / dt:g}] Hz, got {cam.frame_rate!r}",
        )
    steps = cam.latency / dt
    require(
        cam.latency >= 0 and abs(steps - round(steps)) <= 1e-6 * max(1.0, steps),
        f"{path}.camera.latency",
        f"must be >= 0 and a whole number of control periods ({dt:g} s), got {cam.latency!r}",
    )
    require(
        steps <= MAX_LATENCY_STEPS,
        f"{path}.camera.latency",
        f"must be at most {MAX_LATENCY_STEPS} control periods, got {cam.latency!r}",
    )
    prox = cfg.proximity.noise
    require(prox >= 0, f"{path}.proximity.noise", f"must be >= 0, got {prox!r}")
    rob = cfg.robot
    for name in ("accel_max", "alpha_max"):
        value = getattr(rob, name)
        require(
            value is None or value > 0,
            f"{path}.robot.{name}",
            f"must be > 0 or null (no bound), got {value!r}",
        )
    require(rob.lag >= 0, f"{path}.robot.lag", f"must be >= 0, got {rob.lag!r}")
