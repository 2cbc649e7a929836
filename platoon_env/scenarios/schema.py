"""Typed, frozen configuration objects for a scenario (``docs/scenarios.md``).

A scenario file is YAML; :func:`platoon_env.scenarios.loader.load_scenario` safe-loads it and
passes the resulting mapping to :func:`parse_scenario`, which builds these dataclasses, rejects
unknown keys (naming their path, e.g. ``scenario.leader.sped``) and checks every numeric field.
:func:`config_to_mapping` is its exact inverse, so keyword overrides
(:mod:`platoon_env.scenarios.options`) are checked by the same rules as a file. Geometric
validation (polygons, leader-path clearance, feasibility of the initial configuration) happens in
:func:`platoon_env.scenarios.scenario.build_scenario`, once the workspace geometry is built.

Units are SI throughout: metres, seconds, radians.
"""

from __future__ import annotations

import math
import numbers
import types
import typing
from collections.abc import Mapping
from dataclasses import MISSING, asdict, dataclass, field, fields, is_dataclass
from typing import Any, TypeVar

import numpy as np

from platoon_env.violations import VIOLATION_CAUSES

Point = tuple[float, float]
Polygon = tuple[Point, ...]
#: One sample of a timed leader trajectory: ``(t [s], x [m], y [m], theta [rad])``.
TrajectorySample = tuple[float, float, float, float]


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
#: the path (:func:`platoon_env.scenarios.scenario.default_max_steps`): 10**9 steps, about a
#: day of compute at the fastest step rate, far within the int64 the core stores it in.
MAX_EPISODE_STEPS: int = 10**9
#: [s] Upper bound on ``leader.settle_time`` (about 11.6 days of simulated time).
MAX_SETTLE_TIME: float = 1e6
#: [m] Bound on the absolute value of every coordinate (workspace bounds, polygons, leader
#: path): 1000 km, beyond any room or corridor, and far from where lengths and areas overflow.
MAX_COORDINATE: float = 1e6


#: Longest camera latency, in control periods (the core keeps a frame history this long).
MAX_LATENCY_STEPS = 1000
#: Most samples of ``leader.trajectory`` (the core keeps them in its map bank, like a path).
MAX_TRAJECTORY_SAMPLES: int = 100_000
#: [s] Shortest interval between two samples of ``leader.trajectory``, and longest trajectory
#: (its last sample's time): together they keep every sample time apart from the next by far
#: more than the replay's clock tolerance
#: (:data:`~platoon_env.dynamics.leader.TRAJECTORY_TIME_TOLERANCE`).
MIN_TRAJECTORY_INTERVAL: float = 1e-6
MAX_TRAJECTORY_DURATION: float = 1e6
#: Relative tolerance of the trajectory's feasibility rule (``|u| <= u_max``, ``|omega| <=
#: max_turn_rate``): a log written with its values rounded passes (a heading rounded to 0.1 mrad
#: at samples 0.1 s apart changes a turn rate by up to 1e-3 rad/s); 1 % beyond a limit fails.
TRAJECTORY_LIMIT_TOLERANCE: float = 1e-2
#: Largest ``leader.speed_variation`` (the slowest leader drives at 1 - this of its speed).
MAX_SPEED_VARIATION: float = 0.9

#: Metadata of a field added after scenario fingerprints were first recorded: left out of
#: :func:`config_to_mapping` at its default, so that a scenario that does not use it keeps its
#: mapping (and its :mod:`~platoon_env.scenarios.fingerprint`).
_OMIT_DEFAULT = {"omit_default": True}


class ScenarioError(ValueError):
    """A scenario is malformed or infeasible. The message names the offending field.

    Attributes:
        path: the dotted location of the offending field (e.g. ``scenario.robot.u_max``), or
            None when the error is not about one field.
        reason: the message without its location (e.g. ``must be > 0, got 0.0``), or None.
    """

    def __init__(self, message: str, *, path: str | None = None, reason: str | None = None):
        super().__init__(message)
        self.path = path
        self.reason = reason


def field_error(path: str, reason: str) -> ScenarioError:
    """A :class:`ScenarioError` ``"{path}: {reason}"`` that keeps ``path`` and ``reason``."""
    return ScenarioError(f"{path}: {reason}", path=path, reason=reason)


@dataclass(frozen=True)
class FreeSpaceConfig:
    """Free space given directly: an outer polygon with optional holes (obstacles)."""

    exterior: Polygon
    holes: tuple[Polygon, ...] = ()


@dataclass(frozen=True)
class WorkspaceConfig:
    """The workspace ``W`` and its static obstacles ``O_j``.

    ``bounds`` (``[xmin, ymin, xmax, ymax]``) and/or ``free_space`` give the outer region;
    ``obstacles`` (possibly non-convex polygons) are subtracted from it.
    """

    bounds: tuple[float, float, float, float] | None = None
    free_space: FreeSpaceConfig | None = None
    obstacles: tuple[Polygon, ...] = ()


@dataclass(frozen=True)
class LeaderConfig:
    """The scripted leader ``R_0`` (:mod:`platoon_env.dynamics.leader`), in one of two modes:

    * ``path``: pure pursuit along a polyline at constant ``speed``;
    * ``trajectory``: ``[[t, x, y, theta], ...]`` replayed exactly (a planner's output, a
      recorded log): at each sample time the leader is at the sample's pose, in between at
      their interpolation (linear in ``x, y``, the shorter way round in ``theta``), after the
      last one it stays there (arrived). ``speed`` is then derived, the trajectory's mean speed
      (its length over its duration): leave it out (given, it must equal that).

    Exactly one of ``path`` and ``trajectory`` is given, except in a procedural scenario (one
    with a ``generator`` block), which has neither: each layout draws its own path.
    ``speed_variation`` ``v``: each episode draws a speed factor ``f`` uniformly in
    ``[1 - v, 1 + v]`` from the env's seeded RNG at reset; the leader drives at ``f * speed``
    (a trajectory: replayed ``f`` times as fast). 0 (default): ``f = 1``, nothing drawn.
    """

    speed: float  # [m/s] (a trajectory's mean speed, derived)
    path: tuple[Point, ...] = ()
    trajectory: tuple[TrajectorySample, ...] = field(default=(), metadata=_OMIT_DEFAULT)
    lookahead: float = 0.5  # [m] pure-pursuit lookahead distance
    max_turn_rate: float = 1.5  # [rad/s] bound on the leader's |omega|
    settle_time: float = 2.0  # [s] after the leader stops, the episode is truncated
    #: relative half-range v of the episode's speed factor f in [1 - v, 1 + v]
    speed_variation: float = field(default=0.0, metadata=_OMIT_DEFAULT)


@dataclass(frozen=True)
class RobotConfig:
    """Disk robots ``R_i`` of radius ``r`` and their actuator limits (the action-space bounds).

    The paper imposes no actuator limits; the defaults are generous (above the peaks the PPC
    law commands on the shipped studies) so that the paper's law runs unclipped.
    """

    radius: float  # [m] r
    u_max: float = 10.0  # [m/s] |u| bound of the action space
    omega_max: float = 10.0  # [rad/s] |omega| bound of the action space
    #: Actuator dynamics (``docs/realism.md``); the defaults apply a command at once.
    accel_max: float | None = None  # [m/s^2] bound on the change of the applied u; None: none
    alpha_max: float | None = None  # [rad/s^2] bound on the change of the applied omega
    lag: float = 0.0  # [s] first-order time constant from command to applied velocity


@dataclass(frozen=True)
class CameraNoiseConfig:
    """Gaussian errors of a reported detection (``docs/realism.md``): each body-frame coordinate
    gets noise of std ``position + position_per_m * d``, then the point is rotated by an angle of
    std ``bearing``."""

    position: float = 0.0  # [m]
    position_per_m: float = 0.0  # [m per m of d]
    bearing: float = 0.0  # [rad]


@dataclass(frozen=True)
class CameraConfig:
    """Forward camera: field of view ``F_i``, a sector of half-angle ``beta_con`` and radius
    ``d_con``, and what it reports (``docs/realism.md``; the defaults are an ideal camera)."""

    half_angle: float  # [rad] beta_con
    range: float  # [m] d_con
    noise: CameraNoiseConfig = CameraNoiseConfig()
    #: Probability that a truly visible predecessor is reported in a frame ...
    detection: float = 1.0
    #: ... lowered towards the edge of the field of view: ``detection * (1 - detection_edge *
    #: (|beta| / beta_con)^2)``.
    detection_edge: float = 0.0
    frame_rate: float | None = None  # [Hz]; None: a frame every control step
    latency: float = 0.0  # [s] a frame reports what was seen this long ago


@dataclass(frozen=True)
class ProximityConfig:
    """Proximity sensor (LiDAR) that measures the four clearances; ``range`` defaults to
    ``d_con`` (the camera range). ``half_angle`` limits it to the sector ``±half_angle`` about
    the robot's heading (boundary points at a bearing outside it are not sensed); None senses
    all around."""

    range: float | None = None  # [m]
    half_angle: float | None = None  # [rad] in (0, pi]; None (default): all around
    noise: float = 0.0  # [m] std of each reported clearance (clipped to [0, range])


@dataclass(frozen=True)
class SafetyConfig:
    """Safety limits (eqs. 4-5) and which violation causes end an episode.

    ``inflation`` ``m`` [m]: the obstacles are inflated by ``m`` for every rule (the paper's
    study B "augmented the obstacles' boundary by 0.1 m", §4.2): a follower collides when its
    centre comes within ``r + m`` of an obstacle, its proximity sensor measures the four
    clearances to the inflated outline, the reported ``clearance`` is to it (true less ``m``),
    and the leader's path and the initial configuration must be feasible with it. 0 (default):
    the true obstacles.
    """

    d_col: float  # [m] minimum inter-robot distance
    terminate_on: tuple[str, ...] = VIOLATION_CAUSES
    inflation: float = field(default=0.0, metadata=_OMIT_DEFAULT)  # [m] m


@dataclass(frozen=True)
class FormationConfig:
    """Desired inter-robot distance ``d_des`` (Problem 1)."""

    d_des: float  # [m]


@dataclass(frozen=True)
class PPCConfig:
    """Parameters of the PPC law (eqs. 12-14); names as in the paper."""

    lambda_: float = field(metadata={"key": "lambda"})  # [1/s] convergence rate
    rho_d_inf: float  # [m] steady-state bound on e_d
    rho_beta_inf: float  # [rad] steady-state bound on e_beta
    k_d: float  # gain of eq. 13
    k_beta: float  # gain of eq. 14
    delta: float  # [m] activation distance of S(.; delta)
    epsilon: float  # projection-operator parameter in (0, 1)


@dataclass(frozen=True)
class SimulationConfig:
    """Time discretisation and episode length."""

    control_period: float = 0.01  # [s] one env step, one action
    physics_substeps: int = 2  # exact unicycle arcs per control period
    #: None: enough for the leader to drive its path twice over, plus its settle time and 10 s
    #: (see :func:`platoon_env.scenarios.scenario.default_max_steps`).
    max_episode_steps: int | None = None


@dataclass(frozen=True)
class RewardConfig:
    """Weights of the named reward terms (see :mod:`platoon_env.reward`)."""

    distance: float = 1.0  # penalty on (e_d / (d_con - d_des))^2
    bearing: float = 1.0  # penalty on (e_beta / beta_con)^2
    effort: float = 0.01  # penalty on u^2 + omega^2
    alive: float = 1.0  # bonus per step without violation
    violation: float = 100.0  # penalty when a violation occurs
    wall: float = 5.0  # penalty on (1 - (clearance - r) / wall_margin)^2 near a wall
    wall_margin: float = 0.4  # [m] clearance beyond r below which the wall term applies


@dataclass(frozen=True)
class InitialConfig:
    """Seeded perturbation of the default initial configuration on ``reset(seed)``."""

    perturb: bool = True
    position_noise: float = 0.05  # [m] uniform in [-a, a] per coordinate
    heading_noise: float = 0.05  # [rad] uniform in [-a, a]


@dataclass(frozen=True)
class ObservationConfig:
    """What each follower's observation holds (:mod:`platoon_env.observation`,
    ``docs/sensing.md``).

    ``task_aware`` False (default): the 7-vector ``[visible, x~, y~, d_W_l, d_W_r, d_l, d_r]``.
    True: those 7, then what a real follower knows of its task and sensors, each over a fixed
    reference scale: ``d_des``, ``d_col``, ``d_con``, ``beta_con``, ``r``, and the time since
    its predecessor was last perceived visible (13 values).
    """

    task_aware: bool = False


#: Kinds of procedural workspace (see :mod:`platoon_env.scenarios.procedural`).
GENERATOR_KINDS: tuple[str, ...] = ("corridor", "rooms", "mixed")
#: Disjoint families of procedural workspaces: train on one, evaluate on the other.
GENERATOR_SPLITS: tuple[str, ...] = ("train", "test")
#: Difficulty tiers of procedural workspaces, easiest first (the parameters of each are
#: :data:`platoon_env.scenarios.procedural.TIERS`).
GENERATOR_TIERS: tuple[str, ...] = ("easy", "medium", "hard")


@dataclass(frozen=True)
class GeneratorConfig:
    """A procedural scenario: a new workspace and leader path is sampled on every reset.

    The ``split`` selects a disjoint range of layout seeds, so evaluation on ``test`` uses
    workspaces never seen in training on ``train``. The ``tier`` (absent: the untiered family
    of ``procedural_train``/``procedural_test``) selects a difficulty tier: narrower corridors
    and doorways, sharper turns and more obstacles from ``easy`` to ``hard``, each tier and
    split with a seed range of its own (:func:`platoon_env.scenarios.procedural.layout_seed`).
    """

    kind: str = "mixed"
    split: str = "train"
    tier: str | None = None


@dataclass(frozen=True)
class ScenarioConfig:
    """A whole scenario as given in the file (``docs/scenarios.md``), before geometry is built."""

    name: str
    leader: LeaderConfig
    followers: int
    robot: RobotConfig
    camera: CameraConfig
    safety: SafetyConfig
    formation: FormationConfig
    workspace: WorkspaceConfig = WorkspaceConfig()
    generator: GeneratorConfig | None = None
    ppc: PPCConfig | None = None
    proximity: ProximityConfig = ProximityConfig()
    simulation: SimulationConfig = SimulationConfig()
    reward: RewardConfig = RewardConfig()
    initial: InitialConfig = InitialConfig()
    #: Left out of the mapping at its default: every scenario without it keeps its fingerprint.
    observation: ObservationConfig = field(default=ObservationConfig(), metadata=_OMIT_DEFAULT)
    description: str = ""

    @property
    def proximity_range(self) -> float:
        """Range at which the four clearances are capped (``d_con`` unless set)."""
        return self.camera.range if self.proximity.range is None else self.proximity.range

    @property
    def proximity_half_angle(self) -> float:
        """Half-angle of the proximity sensor's sector (``pi``, all around, unless set)."""
        return math.pi if self.proximity.half_angle is None else self.proximity.half_angle

    @property
    def obstacle_reach(self) -> float:
        """``r + m`` [m]: how close a robot's centre may come to a true obstacle before it
        collides with the inflated one (``safety.inflation`` ``m``; the compiled rule is
        :func:`platoon_env.safety.obstacle_contact`)."""
        return self.robot.radius + self.safety.inflation


# --------------------------------------------------------------------------------------------
# Parsing: mapping -> dataclasses, with the path of every offending key in the message.
# --------------------------------------------------------------------------------------------

T = TypeVar("T")


def _key_of(f: Any) -> str:
    return str(f.metadata.get("key", f.name))


# Python callers (keyword overrides) may pass numpy scalars, so the numeric checks go by the
# numbers ABCs; bools are numbers to Python but never to a scenario.
def _parse_number(value: Any, path: str) -> float:
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, numbers.Real):
        raise field_error(path, f"expected a number, got {_shown(value)}")
    try:
        out = float(value)
    except OverflowError:  # an int (or Fraction) beyond float's range, e.g. YAML 10**400
        out = math.inf
    if not math.isfinite(out):
        raise field_error(path, f"must be finite, got {_shown(value)}")
    return out


def _parse_int(value: Any, path: str) -> int:
    # A float, even 2.0, is rejected: YAML ``followers: 2.0`` always was, and a silent
    # int(2.7) == 2 is the bug this guards against.
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, numbers.Integral):
        raise field_error(path, f"expected an integer, got {_shown(value)}")
    return int(value)


def _shown(value: Any) -> str:
    """``repr(value)``, shortened for a huge integer (whose repr may even be refused)."""
    if isinstance(value, numbers.Integral) and not isinstance(value, bool):
        digits = abs(int(value)).bit_length() * 0.30103
        if digits > 30:
            return f"an integer of about {digits:.0f} digits"
    try:
        return repr(value)
    except ValueError:  # pragma: no cover - a number type whose repr refuses
        return f"a {type(value).__name__}"


def _parse_value(tp: Any, value: Any, path: str) -> Any:
    origin = typing.get_origin(tp)
    args = typing.get_args(tp)
    if origin in (typing.Union, types.UnionType):
        non_none = [a for a in args if a is not type(None)]
        if value is None:
            if len(non_none) < len(args):
                return None
            raise field_error(path, "must not be empty")
        return _parse_value(non_none[0], value, path)
    if tp is float:
        return _parse_number(value, path)
    if tp is int:
        return _parse_int(value, path)
    if tp is bool:
        if not isinstance(value, (bool, np.bool_)):
            raise field_error(path, f"expected a boolean (true or false), got {value!r}")
        return bool(value)
    if tp is str:
        if not isinstance(value, str):
            raise field_error(path, f"expected a string, got {value!r}")
        return str(value)
    if origin is tuple:
        is_array = isinstance(value, np.ndarray) and value.ndim > 0
        if not (is_array or isinstance(value, (list, tuple))):
            raise field_error(path, f"expected a list, got {value!r}")
        if len(args) == 2 and args[1] is Ellipsis:
            return tuple(_parse_value(args[0], v, f"{path}[{k}]") for k, v in enumerate(value))
        if len(value) != len(args):
            raise field_error(path, f"expected {len(args)} values, got {len(value)}")
        pairs = enumerate(zip(args, value, strict=True))
        return tuple(_parse_value(a, v, f"{path}[{k}]") for k, (a, v) in pairs)
    if isinstance(tp, type) and hasattr(tp, "__dataclass_fields__"):
        return parse_section(tp, value, path)
    raise TypeError(f"unsupported field type {tp!r} at {path}")  # pragma: no cover


def parse_section(cls: type[T], data: Any, path: str) -> T:
    """Build dataclass ``cls`` from a mapping, rejecting unknown keys and wrong types.

    ``path`` is the dotted location of ``data`` in the file, used in every error message.
    """
    if not isinstance(data, Mapping):
        raise field_error(path, f"expected a mapping, got {data!r}")
    hints = typing.get_type_hints(cls)
    known = {_key_of(f): f for f in fields(cls)}  # type: ignore[arg-type]
    unknown = sorted(str(k) for k in data if k not in known)
    if unknown:
        raise field_error(
            f"{path}.{unknown[0]}", f"unknown key (expected one of {', '.join(sorted(known))})"
        )
    kwargs: dict[str, Any] = {}
    for key, f in known.items():
        if key in data:
            kwargs[f.name] = _parse_value(hints[f.name], data[key], f"{path}.{key}")
        elif f.default is MISSING and f.default_factory is MISSING:
            raise field_error(f"{path}.{key}", "required key is missing")
    return cls(**kwargs)


def parse_scenario(data: Any, path: str = "scenario") -> ScenarioConfig:
    """Parse and range-check a scenario mapping (the schema of ``docs/scenarios.md``).

    Raises :class:`ScenarioError` naming the field for unknown keys, wrong types and
    out-of-range parameters (``docs/safety.md``: ``d_col >= 2r``, ``d_col < d_des < d_con``,
    ``0 < beta_con < pi/2``). A ``leader.trajectory`` without ``leader.speed`` gets its mean
    speed (:func:`trajectory_mean_speed`).
    """
    cfg = parse_section(ScenarioConfig, _with_trajectory_speed(data, path), path)
    check_ranges(cfg, path)
    return cfg


#: The parsed type of ``leader.trajectory``.
_TRAJECTORY_TYPE = tuple[TrajectorySample, ...]


def _with_trajectory_speed(data: Any, path: str) -> Any:
    """``data`` with ``leader.speed`` set to the trajectory's mean speed, when the leader block
    gives a ``trajectory`` and no ``speed`` (anything else is returned as is)."""
    if not isinstance(data, Mapping):
        return data
    leader = data.get("leader")
    if not isinstance(leader, Mapping) or "trajectory" not in leader or "speed" in leader:
        return data
    where = f"{path}.leader.trajectory"
    samples = _parse_value(_TRAJECTORY_TYPE, leader["trajectory"], where)
    check_trajectory_times(samples, where)
    return {**data, "leader": {**leader, "speed": trajectory_mean_speed(samples)}}


def check_trajectory_times(samples: tuple[TrajectorySample, ...], where: str) -> None:
    """The samples of a timed leader trajectory: at least two, at most
    :data:`MAX_TRAJECTORY_SAMPLES`; ``t`` starts at 0, increases by at least
    :data:`MIN_TRAJECTORY_INTERVAL` per sample and ends by :data:`MAX_TRAJECTORY_DURATION`; the
    leader moves (a length > 0). ``ScenarioError`` naming ``where`` (and the sample) otherwise.
    """
    n = len(samples)
    _require(n >= 2, where, f"needs at least two samples [t, x, y, theta], got {n}")
    _require(
        n <= MAX_TRAJECTORY_SAMPLES,
        where,
        f"must have at most {MAX_TRAJECTORY_SAMPLES} samples (MAX_TRAJECTORY_SAMPLES), got {n}",
    )
    t0 = samples[0][0]
    _require(t0 == 0.0, f"{where}[0]", f"the first sample's time t must be 0, got {t0!r}")
    for k in range(1, n):
        dt = samples[k][0] - samples[k - 1][0]
        _require(
            dt >= MIN_TRAJECTORY_INTERVAL,
            f"{where}[{k}]",
            f"sample times must increase by at least {MIN_TRAJECTORY_INTERVAL:g} s "
            f"(MIN_TRAJECTORY_INTERVAL), got t = {samples[k][0]!r} after {samples[k - 1][0]!r}",
        )
    end = samples[-1][0]
    _require(
        end <= MAX_TRAJECTORY_DURATION,
        f"{where}[{n - 1}]",
        f"the last sample's time must be at most {MAX_TRAJECTORY_DURATION:g} s "
        f"(MAX_TRAJECTORY_DURATION), got {end!r}",
    )
    length = _trajectory_length(samples)
    _require(length > 0.0, where, "the leader never moves: every sample is at the same position")


def _trajectory_length(samples: tuple[TrajectorySample, ...]) -> float:
    """Length [m] of the polyline of the samples' positions (the leader's path)."""
    xy = np.asarray([(x, y) for _, x, y, _ in samples], dtype=np.float64)
    return float(np.sum(np.hypot(np.diff(xy[:, 0]), np.diff(xy[:, 1]))))


def trajectory_mean_speed(samples: tuple[TrajectorySample, ...]) -> float:
    """A trajectory's mean speed [m/s]: its length over its duration (``leader.speed`` of the
    trajectory mode). The samples must pass :func:`check_trajectory_times`."""
    return _trajectory_length(samples) / samples[-1][0]


def _require(cond: bool, where: str, message: str) -> None:
    if not cond:
        raise field_error(where, message)


def check_ranges(cfg: ScenarioConfig, path: str = "scenario") -> None:
    """Check every scalar parameter against the ranges the model needs.

    Every message names the field and the offending value. Beyond the model's own ranges
    (``docs/safety.md``) this bounds what would overflow or allocate without limit: the actuator
    limits and the leader's speed and turn rate to :data:`ACTION_BOUND_RANGE`, the control
    period to ``[MIN_CONTROL_PERIOD, MAX_CONTROL_PERIOD]``, ``followers`` to
    :data:`MAX_FOLLOWERS`, ``physics_substeps`` to :data:`MAX_PHYSICS_SUBSTEPS`,
    ``max_episode_steps`` (given, or the default derived from the leader's path) to
    :data:`MAX_EPISODE_STEPS`, ``settle_time`` to :data:`MAX_SETTLE_TIME` and every coordinate
    to :data:`MAX_COORDINATE`.
    """
    r = cfg.robot.radius
    n = cfg.followers
    _require(n >= 1, f"{path}.followers", f"must be >= 1, got {_shown(n)}")
    _require(
        n <= MAX_FOLLOWERS,
        f"{path}.followers",
        f"must be at most {MAX_FOLLOWERS} (MAX_FOLLOWERS), got {_shown(n)}",
    )
    _require(r > 0, f"{path}.robot.radius", f"must be > 0, got {r!r}")
    lo, hi = ACTION_BOUND_RANGE
    for name in ("u_max", "omega_max"):
        bound = getattr(cfg.robot, name)
        _require(
            lo <= bound <= hi,
            f"{path}.robot.{name}",
            f"must lie in [{lo:g}, {hi:g}] (a float32 action bound), got {bound!r}",
        )
    lead = cfg.leader
    for name, unit in (("speed", "m/s"), ("max_turn_rate", "rad/s")):
        value = getattr(lead, name)
        if name == "speed" and lead.trajectory:
            _require(
                lo <= value <= hi,
                f"{path}.leader.trajectory",
                f"its mean speed (length over duration) must lie in [{lo:g}, {hi:g}] {unit} "
                f"(ACTION_BOUND_RANGE), got {value!r}",
            )
            continue
        _require(
            lo <= value <= hi,
            f"{path}.leader.{name}",
            f"must lie in [{lo:g}, {hi:g}] {unit} (ACTION_BOUND_RANGE), got {value!r}",
        )
    _require(lead.lookahead > 0, f"{path}.leader.lookahead", f"must be > 0, got {lead.lookahead!r}")
    _require(
        lead.settle_time >= 0,
        f"{path}.leader.settle_time",
        f"must be >= 0, got {lead.settle_time!r}",
    )
    _require(
        lead.settle_time <= MAX_SETTLE_TIME,
        f"{path}.leader.settle_time",
        f"must be at most {MAX_SETTLE_TIME:g} s (MAX_SETTLE_TIME), got {lead.settle_time!r}",
    )
    _check_coordinates(cfg, path)
    variation = lead.speed_variation
    _require(
        0.0 <= variation <= MAX_SPEED_VARIATION,
        f"{path}.leader.speed_variation",
        f"must lie in [0, {MAX_SPEED_VARIATION:g}] (MAX_SPEED_VARIATION), got {variation!r}",
    )
    _require(
        lead.speed * (1.0 + variation) <= hi,
        f"{path}.leader.speed_variation",
        f"the fastest leader, speed * (1 + speed_variation) = "
        f"{lead.speed * (1.0 + variation):g} m/s, must be at most {hi:g} m/s "
        "(ACTION_BOUND_RANGE)",
    )
    if cfg.generator is None:
        _require(
            (len(lead.path) > 0) != (len(lead.trajectory) > 0),
            f"{path}.leader",
            "give exactly one of 'path' (pure pursuit at 'speed') and 'trajectory' "
            "([[t, x, y, theta], ...] replayed exactly), got "
            + ("both" if lead.path else "neither"),
        )
        if lead.trajectory:
            _check_trajectory(cfg, path)
        else:
            _require(
                len(lead.path) >= 2,
                f"{path}.leader.path",
                f"needs at least two points, got {len(lead.path)}",
            )
    else:
        _require(
            not lead.trajectory,
            f"{path}.leader.trajectory",
            "a procedural scenario (with a 'generator' block) draws each layout's leader "
            "path; it takes no trajectory",
        )
        gen = cfg.generator
        _require(
            gen.kind in GENERATOR_KINDS,
            f"{path}.generator.kind",
            f"expected one of {', '.join(GENERATOR_KINDS)}, got {gen.kind!r}",
        )
        _require(
            gen.split in GENERATOR_SPLITS,
            f"{path}.generator.split",
            f"expected one of {', '.join(GENERATOR_SPLITS)}, got {gen.split!r}",
        )
        _require(
            gen.tier is None or gen.tier in GENERATOR_TIERS,
            f"{path}.generator.tier",
            f"expected one of {', '.join(GENERATOR_TIERS)} (or no tier), got {gen.tier!r}",
        )
    bc, dcon = cfg.camera.half_angle, cfg.camera.range
    _require(
        0 < bc < math.pi / 2,
        f"{path}.camera.half_angle",
        f"beta_con must satisfy 0 < beta_con < pi/2, got {bc!r}",
    )
    _require(dcon > 0, f"{path}.camera.range", f"d_con must be > 0, got {dcon!r}")
    dcol, ddes = cfg.safety.d_col, cfg.formation.d_des
    _require(
        dcol >= 2 * r - 1e-12,
        f"{path}.safety.d_col",
        f"d_col must be >= r_i + r_(i-1) = {2 * r:g}, got {dcol:g}",
    )
    _require(
        dcol < ddes < dcon,
        f"{path}.formation.d_des",
        f"d_des must lie in (d_col, d_con) = ({dcol:g}, {dcon:g}), got {ddes:g}",
    )
    inflation = cfg.safety.inflation
    _require(
        inflation >= 0.0,
        f"{path}.safety.inflation",
        f"must be >= 0 (the obstacles' margin), got {inflation!r}",
    )
    _require(
        inflation < cfg.proximity_range,
        f"{path}.safety.inflation",
        f"must be below the proximity range {cfg.proximity_range:g} m (a sensor that sees no "
        f"farther than the margin reads 0 everywhere), got {inflation!r}",
    )
    for cause in cfg.safety.terminate_on:
        _require(
            cause in VIOLATION_CAUSES,
            f"{path}.safety.terminate_on",
            f"unknown cause {cause!r} (expected some of {', '.join(VIOLATION_CAUSES)})",
        )
    prox = cfg.proximity_range
    _require(
        prox > r, f"{path}.proximity.range", f"must exceed the robot radius {r:g}, got {prox!r}"
    )
    sector = cfg.proximity.half_angle
    _require(
        sector is None or 0 < sector <= math.pi,
        f"{path}.proximity.half_angle",
        f"must satisfy 0 < half_angle <= pi, got {sector!r}",
    )
    _check_simulation(cfg, path)
    for name, value in asdict(cfg.reward).items():
        _require(math.isfinite(value), f"{path}.reward.{name}", f"must be finite, got {value!r}")
    margin = cfg.reward.wall_margin
    _require(margin > 0, f"{path}.reward.wall_margin", f"must be > 0, got {margin!r}")
    ini = cfg.initial
    for name in ("position_noise", "heading_noise"):
        noise = getattr(ini, name)
        _require(noise >= 0, f"{path}.initial.{name}", f"must be >= 0, got {noise!r}")
    if cfg.ppc is not None:
        p = cfg.ppc
        for name in ("lambda_", "rho_d_inf", "rho_beta_inf", "k_d", "k_beta", "delta"):
            key = "lambda" if name == "lambda_" else name
            value = getattr(p, name)
            _require(value > 0, f"{path}.ppc.{key}", f"must be > 0, got {value!r}")
        _require(0 < p.epsilon < 1, f"{path}.ppc.epsilon", f"must lie in (0, 1), got {p.epsilon!r}")
        _require(
            2 * p.rho_d_inf < min(ddes - dcol, dcon - ddes),
            f"{path}.ppc.rho_d_inf",
            "2 * rho_d_inf must be smaller than both d_des - d_col and d_con - d_des "
            f"= {min(ddes - dcol, dcon - ddes):g}, got rho_d_inf = {p.rho_d_inf!r}",
        )
        _require(
            2 * p.rho_beta_inf < bc,
            f"{path}.ppc.rho_beta_inf",
            f"2 * rho_beta_inf must be < beta_con = {bc:g}, got rho_beta_inf = {p.rho_beta_inf!r}",
        )
    _check_realism(cfg, path)


def _check_trajectory(cfg: ScenarioConfig, path: str) -> None:
    """A timed leader trajectory: its samples (:func:`check_trajectory_times`), its speed and
    its feasibility. The rule: on every segment the velocity the interpolation implies
    (:func:`platoon_env.dynamics.leader.segment_velocity`), times the fastest speed factor
    ``1 + speed_variation``, keeps ``|u| <= robot.u_max`` and ``|omega| <=
    leader.max_turn_rate`` (the leader is a robot of the platoon, and Problem 1 asks for a
    leader with bounded velocities), up to :data:`TRAJECTORY_LIMIT_TOLERANCE`."""
    # Imported here: the schema is read by every module, the compiled kernels only on demand.
    from platoon_env.dynamics.leader import trajectory_velocities

    lead = cfg.leader
    where = f"{path}.leader.trajectory"
    check_trajectory_times(lead.trajectory, where)
    mean = trajectory_mean_speed(lead.trajectory)
    _require(
        abs(lead.speed - mean) <= 1e-9 * mean,
        f"{path}.leader.speed",
        f"with a trajectory the leader's speed is the trajectory's mean speed (its length over "
        f"its duration), {mean!r} m/s: leave it out, got {lead.speed!r}",
    )
    u, omega = trajectory_velocities(trajectory_route(lead.trajectory))
    fastest = 1.0 + lead.speed_variation
    scaled = " times 1 + leader.speed_variation" if lead.speed_variation > 0 else ""
    limits = (
        (np.abs(u) * fastest, cfg.robot.u_max, "speed", "m/s", "robot.u_max"),
        (np.abs(omega) * fastest, lead.max_turn_rate, "turn rate", "rad/s", "leader.max_turn_rate"),
    )
    for values, limit, what, unit, name in limits:
        worst = int(np.argmax(values))
        _require(
            values[worst] <= limit * (1.0 + TRAJECTORY_LIMIT_TOLERANCE),
            f"{where}[{worst + 1}]",
            f"infeasible: from sample {worst} to {worst + 1} the leader's {what}{scaled} would "
            f"be {values[worst]:.6g} {unit}, above {name} = {limit:g} {unit}",
        )


def trajectory_route(samples: tuple[TrajectorySample, ...]) -> tuple[np.ndarray, np.ndarray]:
    """A trajectory's samples as the compiled leader reads them (a
    :data:`~platoon_env.records.Route`): the path ``(M, 4)`` with columns ``x, y, t, theta``
    (:data:`~platoon_env.records.PATH_X` ...) and the cumulative arc length ``(M,)`` of its
    positions."""
    arr = np.asarray(samples, dtype=np.float64).reshape(-1, 4)
    path = np.ascontiguousarray(arr[:, [1, 2, 0, 3]])
    seg = np.hypot(np.diff(path[:, 0]), np.diff(path[:, 1]))
    return path, np.concatenate([[0.0], np.cumsum(seg)])


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
        _require(
            abs(sample[3]) <= MAX_COORDINATE,
            f"{path}.leader.trajectory[{k}]",
            f"theta must lie in [-{MAX_COORDINATE:g}, {MAX_COORDINATE:g}] rad, got {sample[3]!r}",
        )
    for where, points in groups:
        for k, (x, y) in enumerate(points):
            _require(
                abs(x) <= MAX_COORDINATE and abs(y) <= MAX_COORDINATE,
                f"{path}.{where}" if where == "workspace.bounds" else f"{path}.{where}[{k}]",
                f"coordinates must lie in [-{MAX_COORDINATE:g}, {MAX_COORDINATE:g}] m "
                f"(MAX_COORDINATE), got {[x, y]!r}",
            )


def _check_simulation(cfg: ScenarioConfig, path: str) -> None:
    """The time discretisation and the step limit, given or derived (all bounded)."""
    sim = cfg.simulation
    dt = sim.control_period
    _require(
        0 < dt <= MAX_CONTROL_PERIOD,
        f"{path}.simulation.control_period",
        f"must lie in (0, {MAX_CONTROL_PERIOD:g}] s, got {dt!r}",
    )
    _require(
        dt >= MIN_CONTROL_PERIOD,
        f"{path}.simulation.control_period",
        f"must be at least {MIN_CONTROL_PERIOD:g} s (MIN_CONTROL_PERIOD), got {dt!r}",
    )
    substeps = sim.physics_substeps
    _require(
        substeps >= 1,
        f"{path}.simulation.physics_substeps",
        f"must be >= 1, got {_shown(substeps)}",
    )
    _require(
        substeps <= MAX_PHYSICS_SUBSTEPS,
        f"{path}.simulation.physics_substeps",
        f"must be at most {MAX_PHYSICS_SUBSTEPS} (MAX_PHYSICS_SUBSTEPS), got {_shown(substeps)}",
    )
    steps = sim.max_episode_steps
    where = f"{path}.simulation.max_episode_steps"
    if steps is not None:
        _require(steps >= 1, where, f"must be >= 1, got {_shown(steps)}")
        _require(
            steps <= MAX_EPISODE_STEPS,
            where,
            f"must be at most {MAX_EPISODE_STEPS} (MAX_EPISODE_STEPS), got {_shown(steps)}",
        )
    elif cfg.generator is None and (len(cfg.leader.path) >= 2 or cfg.leader.trajectory):
        # The default limit follows the path (a procedural template has none yet; each layout
        # is checked when it is built). The bounds above keep it finite; bound it as a given one.
        from platoon_env.scenarios.scenario import default_max_steps  # scenario imports us

        if cfg.leader.trajectory:
            length = _trajectory_length(cfg.leader.trajectory)
        else:
            xy = np.asarray(cfg.leader.path, dtype=np.float64)
            length = float(np.sum(np.hypot(*np.diff(xy, axis=0).T)))
        default = default_max_steps(cfg, length)
        _require(
            default <= MAX_EPISODE_STEPS,
            where,
            f"not given, and the default (2 * path length / (leader.speed * (1 - "
            f"speed_variation)) + settle_time + 10 s in control periods) would be {default} "
            f"steps, more than {MAX_EPISODE_STEPS} (MAX_EPISODE_STEPS): set it, or a faster "
            "leader.speed or a longer control_period",
        )


# --------------------------------------------------------------------------------------------
# Unparsing: dataclasses -> the mapping parse_scenario reads.
# --------------------------------------------------------------------------------------------


def _to_plain(value: Any) -> Any:
    if is_dataclass(value) and not isinstance(value, type):
        return _section_to_mapping(value)
    if isinstance(value, (tuple, list)):
        return [_to_plain(v) for v in value]
    if isinstance(value, np.generic):  # a config built in code may hold numpy scalars
        return value.item()
    return value


def _section_to_mapping(section: Any) -> dict[str, Any]:
    out: dict[str, Any] = {}
    for f in fields(section):
        value = getattr(section, f.name)
        # An absent optional (None by default) is left out, as a file would leave it out; so is
        # a field added later at its default (it would change every scenario's fingerprint).
        if value is None and f.default is None:
            continue
        if f.metadata.get("omit_default") and value == f.default:
            continue
        out[_key_of(f)] = _to_plain(value)
    return out


def config_to_mapping(cfg: ScenarioConfig) -> dict[str, Any]:
    """The mapping form of ``cfg``: the exact inverse of :func:`parse_scenario`.

    Keys are the file's (``ppc.lambda``, not ``lambda_``), tuples become lists, numpy scalars
    become Python ones and None-valued optional fields and blocks (e.g. ``ppc``, ``generator``)
    are omitted, so ``parse_scenario(config_to_mapping(cfg)) == cfg`` and the result is plain
    YAML (``yaml.safe_dump`` writes it). Units are those of the schema: metres, seconds, radians.
    """
    return _section_to_mapping(cfg)


def _check_realism(cfg: ScenarioConfig, path: str) -> None:
    """Ranges of the sensing and actuation realism (``docs/realism.md``)."""
    cam, noise = cfg.camera, cfg.camera.noise
    for name in ("position", "position_per_m", "bearing"):
        value = getattr(noise, name)
        _require(value >= 0, f"{path}.camera.noise.{name}", f"must be >= 0, got {value!r}")
    _require(
        0 <= cam.detection <= 1,
        f"{path}.camera.detection",
        f"must be a probability in [0, 1], got {cam.detection!r}",
    )
    _require(
        0 <= cam.detection_edge <= 1,
        f"{path}.camera.detection_edge",
        f"must lie in [0, 1], got {cam.detection_edge!r}",
    )
    dt = cfg.simulation.control_period
    if cam.frame_rate is not None:
        _require(
            0 < cam.frame_rate <= 1.0 / dt + 1e-9,
            f"{path}.camera.frame_rate",
            f"must lie in (0, 1 / control_period = {1.0 / dt:g}] Hz, got {cam.frame_rate!r}",
        )
    steps = cam.latency / dt
    _require(
        cam.latency >= 0 and abs(steps - round(steps)) <= 1e-6 * max(1.0, steps),
        f"{path}.camera.latency",
        f"must be >= 0 and a whole number of control periods ({dt:g} s), got {cam.latency!r}",
    )
    _require(
        steps <= MAX_LATENCY_STEPS,
        f"{path}.camera.latency",
        f"must be at most {MAX_LATENCY_STEPS} control periods, got {cam.latency!r}",
    )
    prox = cfg.proximity.noise
    _require(prox >= 0, f"{path}.proximity.noise", f"must be >= 0, got {prox!r}")
    rob = cfg.robot
    for name in ("accel_max", "alpha_max"):
        value = getattr(rob, name)
        _require(
            value is None or value > 0,
            f"{path}.robot.{name}",
            f"must be > 0 or null (no bound), got {value!r}",
        )
    _require(rob.lag >= 0, f"{path}.robot.lag", f"must be >= 0, got {rob.lag!r}")


def latency_steps(cfg: ScenarioConfig) -> int:
    """The camera latency in whole control periods."""
    return round(cfg.camera.latency / cfg.simulation.control_period)


def has_realism(cfg: ScenarioConfig) -> bool:
    """Whether any sensing or actuation realism differs from the ideal defaults."""
    cam, rob = cfg.camera, cfg.robot
    return (
        cam.noise != CameraNoiseConfig()
        or cam.detection != 1.0
        or cam.frame_rate is not None
        or cam.latency != 0.0
        or cfg.proximity.noise != 0.0
        or rob.accel_max is not None
        or rob.alpha_max is not None
        or rob.lag != 0.0
    )
