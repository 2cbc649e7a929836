"""The typed, frozen configuration of a scenario (``docs/scenarios.md``) and its error type.

These are plain records: the blocks of a scenario file as dataclasses, with their defaults,
and :class:`ScenarioError`, which names the offending field. This module imports nothing of the
package but :mod:`platoon_env.violations`, so the geometry (:mod:`platoon_env.geometry`), the
compiled records (:mod:`platoon_env.records`) and every layer above can read a config without
importing the scenario machinery. Reading a file or a mapping into these types
(:func:`platoon_env.scenarios.schema.parse_scenario`), their range checks
(:mod:`platoon_env.scenarios.validate`) and the trajectory maths
(:mod:`platoon_env.scenarios.trajectory`) live in :mod:`platoon_env.scenarios`;
:mod:`platoon_env.scenarios.schema` re-exports every name defined here.

**Identity.** A config's canonical form (:func:`~platoon_env.scenarios.schema.config_to_mapping`,
hashed by :mod:`~platoon_env.scenarios.fingerprint`) leaves out every field at its default, so
that a field added with a default keeps every stored fingerprint. The fields that were written
out at their defaults when fingerprints were first recorded are declared with :func:`identity`:
they are written out always, and those fingerprints stay.

Units are SI throughout: metres, seconds, radians.
"""

from __future__ import annotations

import functools
import math
import numbers
from collections.abc import Mapping
from dataclasses import Field, dataclass, field, fields
from types import MappingProxyType
from typing import Any, NamedTuple, TypeVar

from platoon_env.violations import VIOLATION_CAUSES

Point = tuple[float, float]
Polygon = tuple[Point, ...]
#: One sample of a timed leader trajectory: ``(t [s], x [m], y [m], theta [rad])``.
TrajectorySample = tuple[float, float, float, float]

_T = TypeVar("_T")

#: The metadata key of an identity-bearing field (see :func:`identity`).
IDENTITY_KEY = "identity"
#: The metadata of an identity-bearing field: ``field(default=..., metadata=IDENTITY)`` is
#: :func:`identity`, spelled out where the default is a section (a call in a default that
#: linters accept only inside ``field``).
IDENTITY: Mapping[str, bool] = MappingProxyType({IDENTITY_KEY: True})


def identity(default: _T) -> _T:
    """A dataclass field with ``default`` that is identity-bearing: the canonical form writes
    it out even at its default (the module docstring). Every other field is left out at its
    default, so a field added later changes no fingerprint unless it is declared with this."""
    out: _T = field(default=default, metadata=IDENTITY)
    return out


def is_identity(f: Field[Any]) -> bool:
    """Whether the dataclass field ``f`` is identity-bearing (declared with :func:`identity`)."""
    return bool(f.metadata.get(IDENTITY_KEY, False))


def field_key(f: Field[Any]) -> str:
    """The file's key of the dataclass field ``f`` (``lambda`` for ``PPCConfig.lambda_``)."""
    return str(f.metadata.get("key", f.name))


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


def require(cond: bool, path: str, reason: str) -> None:
    """Raise :func:`field_error` ``(path, reason)`` unless ``cond``."""
    if not cond:
        raise field_error(path, reason)


def shown(value: Any) -> str:
    """``repr(value)`` for an error message, shortened for a huge integer (whose repr may even
    be refused)."""
    if isinstance(value, numbers.Integral) and not isinstance(value, bool):
        digits = abs(int(value)).bit_length() * 0.30103
        if digits > 30:
            return f"an integer of about {digits:.0f} digits"
    try:
        return repr(value)
    except ValueError:  # pragma: no cover - a number type whose repr refuses
        return f"a {type(value).__name__}"


@dataclass(frozen=True)
class FreeSpaceConfig:
    """Free space given directly: an outer polygon with optional holes (obstacles)."""

    exterior: Polygon
    holes: tuple[Polygon, ...] = identity(())


@dataclass(frozen=True)
class WorkspaceConfig:
    """The workspace ``W`` and its static obstacles ``O_j``.

    ``bounds`` (``[xmin, ymin, xmax, ymax]``) and/or ``free_space`` give the outer region;
    ``obstacles`` (possibly non-convex polygons) are subtracted from it.
    """

    bounds: tuple[float, float, float, float] | None = None
    free_space: FreeSpaceConfig | None = None
    obstacles: tuple[Polygon, ...] = identity(())


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
    path: tuple[Point, ...] = identity(())
    trajectory: tuple[TrajectorySample, ...] = ()
    lookahead: float = identity(0.5)  # [m] pure-pursuit lookahead distance
    max_turn_rate: float = identity(1.5)  # [rad/s] bound on the leader's |omega|
    settle_time: float = identity(2.0)  # [s] after the leader stops, the episode is truncated
    #: relative half-range v of the episode's speed factor f in [1 - v, 1 + v]
    speed_variation: float = 0.0
    #: Whether the leader keeps the robots' drive (``robot.u_max``, ``omega_max``,
    #: ``accel_max``, ``alpha_max``; the leader is one of the robots): ``"free"`` (the
    #: default: only a trajectory's speed is held to ``u_max``), ``"check"`` (refused unless it
    #: does, the error naming the field) or ``"retime"`` (slowed until it does: a trajectory's
    #: sample times stretched by one factor, a path's speed and turn rate lowered), see
    #: :func:`platoon_env.scenarios.trajectory.fit_leader_to_drive`.
    drive: str = "free"


@dataclass(frozen=True)
class RobotConfig:
    """Disk robots ``R_i`` of radius ``r`` and their actuator limits (the action-space bounds).

    The paper imposes no actuator limits; the defaults are generous (above the peaks the PPC
    law commands on the shipped studies) so that the paper's law runs unclipped.
    """

    radius: float  # [m] r
    u_max: float = identity(10.0)  # [m/s] |u| bound of the action space
    omega_max: float = identity(10.0)  # [rad/s] |omega| bound of the action space
    #: Actuator dynamics (``docs/realism.md``); the defaults apply a command at once.
    accel_max: float | None = None  # [m/s^2] bound on the change of the applied u; None: none
    alpha_max: float | None = None  # [rad/s^2] bound on the change of the applied omega
    lag: float = identity(0.0)  # [s] first-order time constant from command to applied velocity


@dataclass(frozen=True)
class CameraNoiseConfig:
    """Gaussian errors of a reported detection (``docs/realism.md``): each body-frame coordinate
    gets noise of std ``position + position_per_m * d``, then the point is rotated by an angle of
    std ``bearing``."""

    position: float = identity(0.0)  # [m]
    position_per_m: float = identity(0.0)  # [m per m of d]
    bearing: float = identity(0.0)  # [rad]


@dataclass(frozen=True)
class CameraConfig:
    """Forward camera: field of view ``F_i``, a sector of half-angle ``beta_con`` and radius
    ``d_con``, and what it reports (``docs/realism.md``; the defaults are an ideal camera)."""

    half_angle: float  # [rad] beta_con
    range: float  # [m] d_con
    noise: CameraNoiseConfig = field(default=CameraNoiseConfig(), metadata=IDENTITY)
    #: Probability that a truly visible predecessor is reported in a frame ...
    detection: float = identity(1.0)
    #: ... lowered towards the edge of the field of view: ``detection * (1 - detection_edge *
    #: (|beta| / beta_con)^2)``.
    detection_edge: float = identity(0.0)
    frame_rate: float | None = None  # [Hz]; None: a frame every control step
    latency: float = identity(0.0)  # [s] a frame reports what was seen this long ago


@dataclass(frozen=True)
class ProximityConfig:
    """Proximity sensor (LiDAR) that measures the four clearances; ``range`` defaults to
    ``d_con`` (the camera range). ``half_angle`` limits it to the sector ``±half_angle`` about
    the robot's heading (boundary points at a bearing outside it are not sensed); None senses
    all around."""

    range: float | None = None  # [m]
    half_angle: float | None = None  # [rad] in (0, pi]; None (default): all around
    noise: float = identity(0.0)  # [m] std of each reported clearance (clipped to [0, range])


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
    terminate_on: tuple[str, ...] = identity(VIOLATION_CAUSES)
    inflation: float = 0.0  # [m] m


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

    control_period: float = identity(0.01)  # [s] one env step, one action
    physics_substeps: int = identity(2)  # exact unicycle arcs per control period
    #: None: enough for the leader to drive its path twice over, plus its settle time and 10 s
    #: (see :func:`platoon_env.scenarios.validate.default_max_steps`).
    max_episode_steps: int | None = None


@dataclass(frozen=True)
class RewardConfig:
    """Weights of the named reward terms (see :mod:`platoon_env.reward`)."""

    distance: float = identity(1.0)  # penalty on (e_d / (d_con - d_des))^2
    bearing: float = identity(1.0)  # penalty on (e_beta / beta_con)^2
    effort: float = identity(0.01)  # penalty on u^2 + omega^2
    alive: float = identity(1.0)  # bonus per step without violation
    violation: float = identity(100.0)  # penalty when a violation occurs
    wall: float = identity(5.0)  # penalty on (1 - (clearance - r) / wall_margin)^2 near a wall
    wall_margin: float = identity(0.4)  # [m] clearance beyond r below which the wall term applies


@dataclass(frozen=True)
class InitialConfig:
    """Seeded perturbation of the default initial configuration on ``reset(seed)``."""

    perturb: bool = identity(True)
    position_noise: float = identity(0.05)  # [m] uniform in [-a, a] per coordinate
    heading_noise: float = identity(0.05)  # [rad] uniform in [-a, a]


@dataclass(frozen=True)
class ObservationConfig:
    """What each follower's observation holds (:mod:`platoon_env.observation`,
    ``docs/sensing.md``).

    ``task_aware`` False (default): the 7-vector ``[visible, x~, y~, d_W_l, d_W_r, d_l, d_r]``.
    True: those 7, then what a real follower knows of its task and sensors, each over a fixed
    reference scale: ``d_des``, ``d_col``, ``d_con``, ``beta_con``, ``r``, and the time since
    its predecessor was last perceived visible (13 values).

    ``scale_free`` (needs ``task_aware``; default False): every length in the task's own unit
    ``d_con`` (``x~, y~`` and the four clearances over ``d_con``; ``d_des``, ``d_col``, ``r``
    over ``d_con``, ``d_con`` itself still over the fixed 5 m), then ``d / d_con`` and
    ``beta / beta_con`` (15 values), so that one policy's inputs keep fixed bounds across
    every formation (:data:`platoon_env.observation.OBS_NAMES_SCALE_FREE`).
    """

    task_aware: bool = identity(False)
    scale_free: bool = False


#: Kinds of procedural workspace (see :mod:`platoon_env.scenarios.procedural`).
GENERATOR_KINDS: tuple[str, ...] = ("corridor", "rooms", "mixed")
#: Disjoint families of procedural workspaces: train on one, evaluate on the other.
GENERATOR_SPLITS: tuple[str, ...] = ("train", "test")
#: Difficulty tiers of procedural workspaces: easy to hard (the parameters of each are
#: :data:`platoon_env.scenarios.procedural.TIERS`), then the two with the paper studies'
#: geometry, sharp corners in narrow passages and doors followed by a turn
#: (:data:`platoon_env.scenarios.procedural.SHARP_TIERS`). Appended: the earlier tiers keep
#: their seed blocks.
GENERATOR_TIERS: tuple[str, ...] = ("easy", "medium", "hard", "sharp", "paper")


#: Bounds of ``generator.formation.followers``: each drawn episode has 1 to this many followers.
MAX_DRAWN_FOLLOWERS = 10
#: [m] The least gap the drawn distances keep: ``d_col + gap <= d_des`` and
#: ``d_des + gap <= d_con`` (a start at chord ``d_des``, perturbed, stays inside both limits).
FORMATION_GAP = 0.1


@dataclass(frozen=True)
class FormationRanges:
    """``generator.formation``: each layout draws its formation from these ranges
    (``docs/scenarios.md``; :func:`platoon_env.scenarios.procedural.draw_formation`).

    Every field is a closed range ``[lo, hi]`` (``lo == hi`` pins it), None keeps the
    template's value. The draw is consistent by construction: ``r`` first, then ``d_col`` in
    ``[max(lo, 2 r), ..]``, ``d_des`` in ``[max(lo, d_col + FORMATION_GAP), ..]``, ``d_con``
    in ``[max(lo, d_des + FORMATION_GAP), ..]``, each upper end lowered so that the next one
    can still be drawn; ranges that admit no consistent draw are a ``ScenarioError``.
    """

    followers: tuple[int, int] | None = None  # N, in [1, MAX_DRAWN_FOLLOWERS]
    radius: tuple[float, float] | None = None  # [m] r
    d_col: tuple[float, float] | None = None  # [m] (eq. 4)
    d_des: tuple[float, float] | None = None  # [m] (Problem 1)
    d_con: tuple[float, float] | None = None  # [m] camera range (eq. 5)
    beta_con: tuple[float, float] | None = None  # [rad] camera half-angle (eq. 5)
    leader_speed: tuple[float, float] | None = None  # [m/s] leader.speed


@dataclass(frozen=True)
class GeneratorConfig:
    """A procedural scenario: a new workspace and leader path is sampled on every reset.

    The ``split`` selects a disjoint range of layout seeds, so evaluation on ``test`` uses
    workspaces never seen in training on ``train``. The ``tier`` (absent: the untiered family
    of ``procedural_train``/``procedural_test``) selects a difficulty tier: narrower corridors
    and doorways, sharper turns and more obstacles from ``easy`` to ``hard``, each tier and
    split with a seed range of its own (:func:`platoon_env.scenarios.procedural.layout_seed`).
    """

    kind: str = identity("mixed")
    split: str = identity("train")
    tier: str | None = None
    #: None (default): every layout keeps the template's formation; else the ranges each
    #: layout draws its formation from (:class:`FormationRanges`).
    formation: FormationRanges | None = None


#: How a realism field is drawn (:mod:`platoon_env.realism`): uniform in its range, its
#: reciprocal uniform, or uniform among the whole numbers of control periods in it.
LINEAR, RECIPROCAL, LATENCY = "linear", "reciprocal", "latency"
#: Which realism stage a field switches on (the params flags of :class:`StageFlags`): the
#: random perception (and so the perception), the perception alone, the actuators.
RANDOM_PERCEPTION, PERCEPTION, ACTUATION = "random_perception", "perceive", "actuate"


@dataclass(frozen=True)
class RealismField:
    """One field that ``realism`` may draw: its key (the scenario field's dotted path), how it
    is drawn (:data:`LINEAR`, :data:`RECIPROCAL`, :data:`LATENCY`), the least and greatest
    value the schema allows it (``hi`` None: unbounded), the
    :data:`~platoon_env.records.PARAMS_DTYPE` field it is written to, the stage it switches on
    away from its ideal value (:func:`stage_flags`) and that ideal (None: null)."""

    key: str
    kind: str
    lo: float
    hi: float | None
    param: str
    stage: str
    ideal: float | None


def _range_of(spec: RealismField) -> Any:
    """A field of :class:`RealismRanges`: None (not drawn) by default, named in the file by
    the dotted path of the scenario field it draws, and described by ``spec``
    (:data:`REALISM_FIELDS` reads it back)."""
    return field(default=None, metadata={"key": spec.key, "realism": spec})


@dataclass(frozen=True)
class RealismRanges:
    """``realism``: each episode draws its sensing and actuation realism from these ranges
    (``docs/realism.md``; the draw, its checks and the presets: :mod:`platoon_env.realism`).

    Each range field is named by the scenario field it draws (``camera.latency``) and is a
    closed range ``[lo, hi]`` (``lo == hi`` pins it); None (left out) keeps the scenario's
    value. ``camera.frame_rate``, ``robot.accel_max`` and ``robot.alpha_max``, whose ideal is
    null, take ``[lo, null]``: up to a frame every control step, or no bound. ``preset`` names
    a shipped set of ranges (:data:`platoon_env.realism.REALISM_PRESETS`); a range given
    beside it replaces the preset's for that field. The fields' order is the draw order, and
    each one's :class:`RealismField` is the one description of that realism field
    (:data:`REALISM_FIELDS`).
    """

    preset: str | None = None
    camera_noise_position: tuple[float, float] | None = _range_of(
        RealismField(
            "camera.noise.position", LINEAR, 0.0, None, "noise_position", RANDOM_PERCEPTION, 0.0
        )
    )
    camera_noise_position_per_m: tuple[float, float] | None = _range_of(
        RealismField(
            "camera.noise.position_per_m",
            LINEAR,
            0.0,
            None,
            "noise_position_per_m",
            RANDOM_PERCEPTION,
            0.0,
        )
    )
    camera_noise_bearing: tuple[float, float] | None = _range_of(
        RealismField(
            "camera.noise.bearing", LINEAR, 0.0, None, "noise_bearing", RANDOM_PERCEPTION, 0.0
        )
    )
    camera_detection: tuple[float, float] | None = _range_of(
        RealismField("camera.detection", LINEAR, 0.0, 1.0, "detection", RANDOM_PERCEPTION, 1.0)
    )
    camera_detection_edge: tuple[float, float] | None = _range_of(
        RealismField(
            "camera.detection_edge", LINEAR, 0.0, 1.0, "detection_edge", RANDOM_PERCEPTION, 0.0
        )
    )
    camera_frame_rate: tuple[float, float | None] | None = _range_of(
        RealismField("camera.frame_rate", RECIPROCAL, 0.0, None, "frame_period", PERCEPTION, None)
    )
    camera_latency: tuple[float, float] | None = _range_of(
        RealismField("camera.latency", LATENCY, 0.0, None, "latency_steps", PERCEPTION, 0.0)
    )
    proximity_noise: tuple[float, float] | None = _range_of(
        RealismField(
            "proximity.noise", LINEAR, 0.0, None, "proximity_noise", RANDOM_PERCEPTION, 0.0
        )
    )
    robot_accel_max: tuple[float, float | None] | None = _range_of(
        RealismField("robot.accel_max", RECIPROCAL, 0.0, None, "accel_max", ACTUATION, None)
    )
    robot_alpha_max: tuple[float, float | None] | None = _range_of(
        RealismField("robot.alpha_max", RECIPROCAL, 0.0, None, "alpha_max", ACTUATION, None)
    )


#: The fields ``realism`` may draw, in draw order: the :class:`RealismField` of each range
#: field of :class:`RealismRanges` (their one table).
REALISM_FIELDS: tuple[RealismField, ...] = tuple(
    f.metadata["realism"] for f in fields(RealismRanges) if "realism" in f.metadata
)


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
    workspace: WorkspaceConfig = field(default=WorkspaceConfig(), metadata=IDENTITY)
    generator: GeneratorConfig | None = None
    ppc: PPCConfig | None = None
    proximity: ProximityConfig = field(default=ProximityConfig(), metadata=IDENTITY)
    simulation: SimulationConfig = field(default=SimulationConfig(), metadata=IDENTITY)
    reward: RewardConfig = field(default=RewardConfig(), metadata=IDENTITY)
    initial: InitialConfig = field(default=InitialConfig(), metadata=IDENTITY)
    observation: ObservationConfig = ObservationConfig()
    #: None (default): the realism fields keep their values; else the ranges each episode
    #: draws them from (:class:`RealismRanges`).
    realism: RealismRanges | None = None
    description: str = identity("")

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


def latency_steps(cfg: ScenarioConfig) -> int:
    """The camera latency in whole control periods."""
    return round(cfg.camera.latency / cfg.simulation.control_period)


class StageFlags(NamedTuple):
    """Which realism stages the compiled step runs (the params fields of the same names)."""

    random_perception: bool  # some perception realism draws random numbers
    perceive: bool  # any camera or proximity realism is on
    actuate: bool  # the actuators' lag or rate limits are on


def realism_values(cfg: ScenarioConfig) -> dict[str, Any]:
    """``{key: value}`` of every :data:`REALISM_FIELDS` field of ``cfg``, in the schema's units
    (None for null): the scenario field at the key's dotted path."""
    return {f.key: functools.reduce(getattr, f.key.split("."), cfg) for f in REALISM_FIELDS}


def stage_flags(values: Mapping[str, Any], lag: float) -> StageFlags:
    """The realism stages that run with the realism fields at ``values`` (``{key: value}`` of
    every :data:`REALISM_FIELDS` field, in the schema's units, None for null:
    :func:`realism_values`, or an episode's draw, :func:`platoon_env.realism.draw_realism`)
    and the actuator lag ``lag`` [s]: a stage runs when one of its fields is away from its
    ideal (a perception field whose stage is the random perception switches on both)."""
    on = {RANDOM_PERCEPTION: False, PERCEPTION: False, ACTUATION: lag > 0}
    for f in REALISM_FIELDS:
        if not on[f.stage]:
            on[f.stage] = values[f.key] != f.ideal
    random = on[RANDOM_PERCEPTION]
    return StageFlags(random, random or on[PERCEPTION], on[ACTUATION])


def has_realism(cfg: ScenarioConfig) -> bool:
    """Whether any sensing or actuation realism differs from the ideal defaults: a realism
    stage runs (:func:`stage_flags`), or a ``realism`` block draws some."""
    flags = stage_flags(realism_values(cfg), cfg.robot.lag)
    return flags.perceive or flags.actuate or cfg.realism is not None
