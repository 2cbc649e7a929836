"""The five violation causes, their reporting order and their bit masks (``docs/safety.md``).

A follower's violations in a step are an int bit mask: bit ``k`` is ``VIOLATION_CAUSES[k]``.
When several causes occur at once, ``info["violation"]`` reports the first in this order. This
module is the vocabulary only (it imports nothing of the package); the rules that decide a
violation are in :mod:`platoon_env.safety`.
"""

from __future__ import annotations

#: Violation causes, in the order in which a simultaneous violation is reported.
VIOLATION_CAUSES: tuple[str, ...] = (
    "collision_robot",
    "collision_obstacle",
    "occluded",
    "out_of_range",
    "out_of_fov",
)


COLLISION_ROBOT = 1 << VIOLATION_CAUSES.index("collision_robot")
COLLISION_OBSTACLE = 1 << VIOLATION_CAUSES.index("collision_obstacle")
OCCLUDED = 1 << VIOLATION_CAUSES.index("occluded")
OUT_OF_RANGE = 1 << VIOLATION_CAUSES.index("out_of_range")
OUT_OF_FOV = 1 << VIOLATION_CAUSES.index("out_of_fov")


def causes_to_mask(causes: tuple[str, ...] | list[str] | set[str] | frozenset[str]) -> int:
    """Bit mask of a set of cause names (unknown names raise ``ValueError``)."""
    mask = 0
    for cause in causes:
        if cause not in VIOLATION_CAUSES:
            raise ValueError(
                f"unknown violation cause {cause!r}; expected some of {', '.join(VIOLATION_CAUSES)}"
            )
        mask |= 1 << VIOLATION_CAUSES.index(cause)
    return mask


def _causes(mask: int) -> tuple[str, ...]:
    return tuple(c for k, c in enumerate(VIOLATION_CAUSES) if mask & (1 << k))


#: Cause names of every possible mask, in reporting priority order (a lookup table: masks are
#: read every step; ``CAUSES_OF_MASK[m]`` is :func:`mask_to_causes` without the call).
CAUSES_OF_MASK: tuple[tuple[str, ...], ...] = tuple(
    _causes(m) for m in range(1 << len(VIOLATION_CAUSES))
)


def mask_to_causes(mask: int) -> tuple[str, ...]:
    """Cause names set in ``mask``, in reporting priority order."""
    return CAUSES_OF_MASK[mask]


def first_cause(mask: int) -> str | None:
    """The highest-priority cause in ``mask`` (the one reported in ``info['violation']``)."""
    for k, cause in enumerate(VIOLATION_CAUSES):
        if mask & (1 << k):
            return cause
    return None


#: ``(info["violation"], info["violations"], info["cost"])`` of every mask: the first cause (or
#: None), all causes, and the Safety-Gymnasium-style cost (1 when any cause occurred).
VIOLATION_INFO: tuple[tuple[str | None, tuple[str, ...], int], ...] = tuple(
    (first_cause(mask), causes, 1 if causes else 0) for mask, causes in enumerate(CAUSES_OF_MASK)
)


#: Names of the numeric info view's violation codes (``make(..., info_view="numeric")``,
#: ``docs/api.md``): ``info["violation"]`` is the index into this table, ``0`` = no violation,
#: then the causes in :data:`VIOLATION_CAUSES` order (``1`` = ``collision_robot``, ...,
#: ``5`` = ``out_of_fov``).
VIOLATION_CODE_NAMES: tuple[str, ...] = ("none", *VIOLATION_CAUSES)


def violation_code(cause: str | None) -> int:
    """The numeric view's code of ``cause`` (None -> 0; an unknown name is ``ValueError``)."""
    if cause is None:
        return 0
    if cause not in VIOLATION_CAUSES:
        raise ValueError(
            f"unknown violation cause {cause!r}; expected None or one of "
            f"{', '.join(VIOLATION_CAUSES)}"
        )
    return 1 + VIOLATION_CAUSES.index(cause)


def violation_cause(code: int) -> str | None:
    """The cause a numeric view's code stands for (0 -> None), the inverse of
    :func:`violation_code`; a code outside ``0..len(VIOLATION_CAUSES)`` is ``ValueError``."""
    code = int(code)
    if not 0 <= code <= len(VIOLATION_CAUSES):
        raise ValueError(f"violation code must be in 0..{len(VIOLATION_CAUSES)}, got {code}")
    return None if code == 0 else VIOLATION_CAUSES[code - 1]


#: ``(info["violation"], info["violation_mask"], info["cost"])`` of every mask in the numeric
#: view: the first cause's code (:data:`VIOLATION_CODE_NAMES`), the mask itself, the cost.
VIOLATION_NUMERIC_INFO: tuple[tuple[int, int, int], ...] = tuple(
    (violation_code(first), mask, cost) for mask, (first, _, cost) in enumerate(VIOLATION_INFO)
)
