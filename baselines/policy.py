"""The interface every policy shares (``docs/api.md``).

A policy acts for all followers at once: it receives the PettingZoo ``ParallelEnv`` observation
dict (agent name -> float32 observation vector, see :mod:`platoon_env.observation`) and returns
an action dict (agent name -> float32 ``[u, omega]``) for every agent it was given. Stateful
policies (the PPC law keeps its performance functions) restore their initial state in
:meth:`Policy.reset`, which is called once per episode, after ``env.reset``.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any, Protocol, runtime_checkable

import numpy as np
from numpy.typing import ArrayLike, NDArray

from platoon_env.observation import OBS_SIZE, OBS_SIZE_SCALE_FREE, OBS_SIZE_TASK, sensor_columns
from platoon_env.scenarios.schema import ScenarioConfig

__all__ = [
    "Followers",
    "Policy",
    "PolicyEnv",
    "agent_indices",
    "as_float",
    "kernel_record",
    "sensor_part",
]


class _Scenario(Protocol):
    @property
    def config(self) -> ScenarioConfig: ...


class PolicyEnv(Protocol):
    """What the scripted policies (:class:`baselines.PPCPolicy`, :class:`baselines.LastSeenPolicy`)
    read from the env: the agents, the control period and the scenario's parameters."""

    @property
    def possible_agents(self) -> Sequence[str]: ...

    @property
    def control_period(self) -> float: ...

    @property
    def scenario(self) -> _Scenario: ...


@runtime_checkable
class Policy(Protocol):
    """A multi-follower policy: ``reset(seed=None)`` and ``act(observations) -> actions``."""

    def reset(self, seed: int | None = None) -> None:
        """Restore the policy's initial internal state (and reseed it, if it is stochastic)."""
        ...

    def act(self, observations: dict[str, NDArray[Any]]) -> dict[str, NDArray[np.float32]]:
        """Map ``{agent: observation}`` to ``{agent: np.array([u, omega], dtype=float32)}``."""
        ...


_SIZES = (OBS_SIZE, OBS_SIZE_TASK, OBS_SIZE_SCALE_FREE)


def sensor_part(
    obs: NDArray[np.float64], n: int, config: ScenarioConfig | None = None
) -> NDArray[np.float64]:
    """The ``(n, 7)`` physical sensor part of ``n`` stacked observations: the 7-vector itself,
    or the first 7 columns of a task-aware 13-vector (the analytic laws read their task from
    the scenario, not from the observation), or of a scale-free 15-vector un-scaled by
    :func:`platoon_env.observation.sensor_columns` (which needs the env's ``config``). Any
    other shape, or a scale-free shape without ``config``, is a ``ValueError``."""
    if obs.ndim != 2 or obs.shape[0] != n or obs.shape[1] not in _SIZES:
        raise ValueError(
            f"expected observations of shape ({OBS_SIZE},), ({OBS_SIZE_TASK},) or "
            f"({OBS_SIZE_SCALE_FREE},), got {obs.shape[1:]}"
        )
    if config is not None:
        return sensor_columns(obs, config)
    if obs.shape[1] == OBS_SIZE_SCALE_FREE:
        raise ValueError(
            "scale-free observations (observation.scale_free) are read back into metres with "
            "the env's scenario config: pass it (Followers(agents, env.scenario.config))"
        )
    return obs[:, :OBS_SIZE]


def agent_indices(
    keys: tuple[str, ...], agents: tuple[str, ...], index: Mapping[str, int]
) -> NDArray[np.intp] | None:
    """The followers an ``act`` call was given: None when ``keys`` are all of ``agents`` in
    their order (the common case: the caller uses its own "all" index), else their indices
    ``index[a]`` (a subset, or another order). An unknown agent is a ``KeyError`` naming it."""
    if keys == agents:
        return None
    try:
        return np.array([index[a] for a in keys], dtype=np.intp)
    except KeyError as err:
        raise KeyError(f"unknown agent {err.args[0]!r}; expected some of {agents}") from None


class Followers:
    """The followers a policy acts for, indexed as ``env.possible_agents`` (the order of the
    policy's state arrays), and the reading of one ``act`` call's observations."""

    def __init__(self, agents: Sequence[str], config: ScenarioConfig | None = None) -> None:
        """``agents``: ``env.possible_agents``; ``config``: the env's scenario config, by which
        :meth:`read` un-scales scale-free observations (``observation.scale_free``); None:
        observations in metres (the 7- or 13-vector)."""
        #: the scenario config whose observation layout :meth:`read` undoes (None: physical)
        self.config: ScenarioConfig | None = (
            config if config is not None and config.observation.scale_free else None
        )
        #: the followers, in ``env.possible_agents`` order
        self.agents: tuple[str, ...] = tuple(agents)
        #: follower name -> its index
        self.index: dict[str, int] = {a: i for i, a in enumerate(self.agents)}
        #: the indices of all followers, ``0 .. N-1``
        self.all: NDArray[np.intp] = np.arange(len(self.agents), dtype=np.intp)

    def read(
        self, observations: Mapping[str, ArrayLike]
    ) -> tuple[tuple[str, ...], NDArray[np.float64], NDArray[np.intp] | None]:
        """``(keys, obs, found)``: the agents of ``observations`` in their order, their
        ``(n, 7)`` float64 physical sensor parts (:func:`sensor_part`) and
        :func:`agent_indices` (None when they are all followers in order)."""
        keys = tuple(observations)
        stacked = np.array(list(observations.values()), dtype=np.float64)
        obs = sensor_part(stacked, len(keys), self.config)
        return keys, obs, agent_indices(keys, self.agents, self.index)


def as_float(x: ArrayLike) -> NDArray[np.float64]:
    """``x`` as a float64 array (no copy when it is one): the pure functions' inputs."""
    return np.asarray(x, dtype=np.float64)


def kernel_record(dtype: np.dtype[np.void], source: object, **values: float) -> NDArray[np.void]:
    """The constants of a compiled kernel: a ``(1,)`` array of the structured ``dtype`` (the
    kernel reads its record ``[0]`` by field name), each field ``values[name]`` if given, else
    the attribute of that name of ``source`` (a parameter dataclass)."""
    out = np.zeros(1, dtype=dtype)
    for name in dtype.names or ():
        out[name] = values[name] if name in values else getattr(source, name)
    return out
