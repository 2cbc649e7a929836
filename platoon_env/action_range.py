"""Normalised actions: a policy acts in ``[-1, 1]^2``, mapped affinely to ``[u, omega]``.

The env's own action Box is the actuator limit (``u_max``, ``omega_max``: +-10 m/s, +-10 rad/s by
default), far wider than a follower needs, so a policy acting in it would spend most of its
range on commands the actuators clip or the task never uses. :class:`ActionRange` names the
physical range that ``[-1, 1]`` covers instead; the Gymnasium ids use it with
``normalize_actions=True`` (:mod:`platoon_env.gym_env`, :mod:`platoon_env.gym_vector`).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import asdict, dataclass
from typing import Any

import numpy as np
from gymnasium import spaces
from numpy.typing import NDArray

from platoon_env.observation import ACT_OMEGA, ACT_SIZE, ACT_U
from platoon_env.scenarios.options import check_bool

__all__ = [
    "ActionRange",
    "action_range_of",
    "check_action_range",
    "normalised_action_space",
    "physical_actions",
]

#: Slack [m/s, rad/s] of the comparison of an action range with the actuator limits.
_LIMIT_TOLERANCE = 1e-6


@dataclass(frozen=True)
class ActionRange:
    """The physical range that the normalised action ``a in [-1, 1]^2`` maps to.

    ``u = u_low + (a_0 + 1) / 2 * (u_high - u_low)`` [m/s] and ``omega = a_1 * omega_high``
    [rad/s]. The defaults suit followers that mostly drive forwards at the speed scale of the
    shipped scenarios (leader at 0.25 m/s, 0.5 m/s in study A): some reverse to back off, a
    few times the leader's speed forward to catch up after a corner, and 2 rad/s to turn.
    """

    u_low: float = -0.5  # [m/s]
    u_high: float = 1.5  # [m/s]
    omega_high: float = 2.0  # [rad/s]

    def __post_init__(self) -> None:
        if not self.u_low < self.u_high:
            raise ValueError(f"ActionRange needs u_low < u_high, got {self.u_low}, {self.u_high}")
        if not self.omega_high > 0:
            raise ValueError(f"ActionRange needs omega_high > 0, got {self.omega_high}")

    def to_physical(self, action: NDArray[Any]) -> NDArray[np.float32]:
        """Map normalised actions ``(..., 2)`` (clipped to ``[-1, 1]``; NaN stays NaN, for the
        env to reject) to ``[u, omega]``."""
        a = np.clip(np.asarray(action, dtype=np.float64), -1.0, 1.0)
        out = np.empty(a.shape, dtype=np.float32)
        out[..., ACT_U] = self.u_low + 0.5 * (a[..., ACT_U] + 1.0) * (self.u_high - self.u_low)
        out[..., ACT_OMEGA] = a[..., ACT_OMEGA] * self.omega_high
        return out

    def to_dict(self) -> dict[str, float]:
        """JSON-friendly form (inverse: ``ActionRange(**d)``)."""
        return asdict(self)


def check_action_range(action_range: ActionRange, physical: spaces.Box, what: str) -> None:
    """Raise ``ValueError`` if ``action_range`` reaches beyond ``physical`` (``what``'s actuator
    Box ``[u, omega]``): the ends of ``[-1, 1]`` would map to commands the env clips."""
    low = np.array([action_range.u_low, -action_range.omega_high])
    high = np.array([action_range.u_high, action_range.omega_high])
    if np.any(low < physical.low - _LIMIT_TOLERANCE) or np.any(
        high > physical.high + _LIMIT_TOLERANCE
    ):
        raise ValueError(
            f"{action_range} exceeds {what}'s actuator limits {physical}; "
            "raise u_max/omega_max or narrow the range"
        )


def normalised_action_space() -> spaces.Box:
    """The action Box of a normalised follower: ``Box(-1, 1, (2,), float32)``."""
    return spaces.Box(-1.0, 1.0, (ACT_SIZE,), dtype=np.float32)


def action_range_of(
    normalize_actions: Any, action_range: Any, physical: spaces.Box, where: str
) -> ActionRange | None:
    """The :class:`ActionRange` an env maps its actions with, or None for physical actions.

    ``normalize_actions``: True or False; ``action_range``: None (the default
    :class:`ActionRange`), an :class:`ActionRange` or a mapping of its fields, allowed only
    with ``normalize_actions``. Checked against the ``physical`` actuator Box; ``where`` names
    the caller in errors.
    """
    if not check_bool("normalize_actions", normalize_actions, where):
        if action_range is not None:
            raise ValueError(f"{where}: action_range needs normalize_actions=True")
        return None
    if action_range is None:
        action_range = ActionRange()
    elif isinstance(action_range, Mapping):
        action_range = ActionRange(**action_range)
    elif not isinstance(action_range, ActionRange):
        raise TypeError(
            f"{where}: action_range must be an ActionRange, a mapping of its fields or None, "
            f"got {action_range!r}"
        )
    check_action_range(action_range, physical, where)
    return action_range


def physical_actions(
    actions: Any, shape: tuple[int, ...], action_range: ActionRange | None, what: str
) -> NDArray[Any]:
    """``actions`` as real numbers of ``shape`` and, with an ``action_range``, mapped from
    ``[-1, 1]`` to ``[u, omega]``; else ``TypeError``/``ValueError`` naming ``what``.

    Without a range NaN and inf pass (the core rejects them before any state changes, naming
    the env and agent); with one they raise here, since the clip to ``[-1, 1]`` would turn an
    infinite action into a valid one.
    """
    array = np.asarray(actions)
    # Real numbers only: numpy would read "0.3" as 0.3 and drop an imaginary part.
    if array.dtype.kind not in "fiu":
        raise TypeError(f"{what} must be real numbers, got dtype {array.dtype}")
    if array.shape != shape:
        raise ValueError(f"{what} must have shape {shape}, got {array.shape}")
    if action_range is None:
        return array
    if not np.all(np.isfinite(array)):
        raise ValueError(f"{what} contains NaN or inf: {array.tolist()}")
    return action_range.to_physical(array)
