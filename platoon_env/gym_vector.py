"""Gymnasium's vector API over the batched core: the vector entry point of every Gymnasium id.

``gymnasium.make_vec("platoon_env/SingleFollower-StudyC-v1", num_envs=8)`` (the default
``vectorization_mode`` for these ids is ``"vector_entry_point"``) builds a
:class:`SingleFollowerVectorEnv`: ``num_envs`` copies of the id's single env
(:class:`~platoon_env.gym_env.SingleFollowerEnv`) held by one
:class:`~platoon_env.batched.BatchedPlatoon`, so a step of all of them is one compiled call.
Sub-env ``i`` reset with seed ``s`` and fed the same actions returns exactly what
``gymnasium.make(id)`` reset with ``s`` returns (``tests/test_gym_vector.py``), including the
infos, batched as Gymnasium's own vector envs batch them.

**Autoreset mode** (``envs.autoreset_mode``, also ``envs.metadata["autoreset_mode"]``), as
Gymnasium's ``SyncVectorEnv`` takes it: ``AutoresetMode.NEXT_STEP`` (the default, Gymnasium's
own: the step after an episode's end only resets that sub-env), ``SAME_STEP`` (the reset within
the ending step, the final observation and info under ``final_obs``/``final_info``) or
``DISABLED``. Choose it with the keyword ``gymnasium.make_vec(id, n,
autoreset_mode=AutoresetMode.SAME_STEP)``: Gymnasium 1.4's ``make_vec`` refuses
``vector_kwargs`` for a vector entry point ("Custom vector environment can be passed arguments
only through kwargs"), which takes keywords only; ``vector_kwargs={"autoreset_mode": ...}``
works with ``vectorization_mode="sync"``, Gymnasium's ``SyncVectorEnv`` over
``gymnasium.make(id)``. The default was ``SAME_STEP`` before version 0.2.0; it is ``NEXT_STEP``
so that ``gymnasium.make_vec(id, n)`` as it comes works under Gymnasium's vector wrappers:
its observation wrappers refuse ``SAME_STEP`` (``TransformObservation`` and every
``VectorObservationWrapper``: "Expected autoreset_mode to be NEXT_STEP or DISABLED";
``NormalizeObservation``: NEXT_STEP only), and loops written for Gymnasium 1.x (CleanRL's)
assume NEXT_STEP. ``RecordEpisodeStatistics``, ``NormalizeReward`` and ``ClipAction`` take
any mode (``tests/test_gym_vector_wrappers.py``). TorchRL's ``GymWrapper`` (0.14) reads the
``autoreset_mode`` attribute and takes only ``DISABLED`` (its preference: it resets ended
sub-envs itself, by ``reset_mask``) or ``SAME_STEP``, refusing NEXT_STEP with its own
RuntimeError; without the attribute it failed with an AttributeError. For TorchRL:
``GymWrapper(gymnasium.make_vec(id, n, info_view="numeric",
autoreset_mode=AutoresetMode.DISABLED))`` (``docs/ecosystem.md``).

**Infos for array libraries**: the default ``info_view="rich"`` (as ``gymnasium.make(id)``'s)
holds object arrays (cause names with None, tuples of causes) and a nested ``reward_terms``;
TorchRL and BenchMARL turn info values into tensors and fail on them deep inside
(``torch.as_tensor``: "Could not infer dtype of NoneType", "can't convert np.ndarray of type
numpy.object_"; TorchRL's ``GymWrapper``: an IndexError in SAME_STEP, "'dict' object has no
attribute 'dtype'" with an info reader). Pass ``info_view="numeric"``: the same information as
int64 and float64 arrays under fixed keys; with ``NEXT_STEP`` or ``DISABLED`` the infos then
hold nothing else (``SAME_STEP`` adds ``final_obs``, an object array, and the nested
``final_info``). The default stays rich so that ``make_vec(id)`` keeps equal to Gymnasium's
vectorisation of ``gymnasium.make(id)``, whose rich infos PettingZoo and Gymnasium users read
by name (``info["violation"] is None``).
"""

from __future__ import annotations

import warnings
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np
from gymnasium.vector import AutoresetMode, VectorEnv
from gymnasium.vector.utils import batch_space

from platoon_env.action_range import (
    ActionRange,
    action_range_of,
    normalised_action_space,
    physical_actions,
)
from platoon_env.batched import BatchedPlatoon
from platoon_env.env import (
    INFO_KEYS,
    N_VIOLATION_INFO,
    NUMERIC_INFO_KEYS,
    SENSE_INFO_KEYS,
    _check_seed,
    check_env_keywords,
    steps_per_second,
)
from platoon_env.geometry.sensing import SENSE_NAMES, SENSE_VISIBLE
from platoon_env.gym_env import GYM_OPTIONS, single_follower
from platoon_env.observation import ACT_SIZE
from platoon_env.reward import REWARD_TERMS
from platoon_env.scenarios.options import check_bool
from platoon_env.scenarios.source import SourceLike
from platoon_env.violations import VIOLATION_INFO, VIOLATION_NUMERIC_INFO, first_cause

__all__ = ["VECTOR_OPTIONS", "SingleFollowerVectorEnv", "sub_env_seeds"]

#: The keywords of :class:`SingleFollowerVectorEnv` (``gymnasium.make_vec(id, ...)``) that
#: configure the env rather than its scenario: the single env's, then the vector env's own.
VECTOR_OPTIONS: tuple[str, ...] = (*GYM_OPTIONS, "n_threads", "autoreset_mode")


def _objects(values: Sequence[Any]) -> np.ndarray:
    """A 1-D object array of ``values`` (tuples stay elements, not rows)."""
    array = np.empty(len(values), dtype=object)
    for k, value in enumerate(values):
        array[k] = value
    return array


# ``info["violation"]``, ``["violations"]`` and ``["cost"]`` of every violation mask, as arrays
# indexed by a batch of masks (the single env's VIOLATION_INFO, one lookup for all envs).
_FIRST_CAUSE = _objects([first for first, _, _ in VIOLATION_INFO])
_CAUSES = _objects([causes for _, causes, _ in VIOLATION_INFO])
_COST = np.array([cost for _, _, cost in VIOLATION_INFO], dtype=np.int64)
# ``info["violation"]`` of the numeric view: the first cause's code (VIOLATION_CODE_NAMES).
_CODE = np.array([code for code, _, _ in VIOLATION_NUMERIC_INFO], dtype=np.int64)


def sub_env_seeds(seed: int, num_envs: int) -> list[int]:
    """The reset seeds that ``reset(seed=seed)`` gives sub-envs ``0 .. num_envs - 1``: the first
    64-bit word of each child of ``numpy.random.SeedSequence(seed).spawn(num_envs)``, so
    different ``seed``\\ s share no sub-env stream (``seed + i`` would: seeds 0 and 1 would share
    ``num_envs - 1`` of them)."""
    children = np.random.SeedSequence(_check_seed(seed)).spawn(num_envs)
    return [int(child.generate_state(1, dtype=np.uint64)[0]) for child in children]


class SingleFollowerVectorEnv(VectorEnv):  # type: ignore[misc]
    """``num_envs`` single-follower envs of one scenario, stepped together by the batched core.

    **Spaces**: ``single_observation_space`` and ``single_action_space`` are the single env's
    (:class:`~platoon_env.gym_env.SingleFollowerEnv`: the follower's observation Box; the
    actuator Box ``[u, omega]``, or ``Box(-1, 1, (2,))`` with ``normalize_actions``);
    ``observation_space`` and ``action_space`` batch them: ``(num_envs, K)`` and
    ``(num_envs, 2)``. Actions outside the Box are clipped; a wrong shape, a non-real dtype,
    NaN or inf raise (``ValueError``/``TypeError``) and change nothing.

    **step** returns ``observations (num_envs, K) float32``, ``rewards (num_envs,) float64``,
    ``terminated``, ``truncated`` ``(num_envs,) bool`` (the single env's episode rules) and
    ``infos``: the single env's info keys as arrays over the sub-envs, each with its ``_key``
    mask (``reward_terms`` a dict of arrays with its own masks), as Gymnasium's
    ``SyncVectorEnv`` batches them. With ``info_view="numeric"`` the single env's numeric
    view batched the same way: ``int64`` and ``float64`` arrays only (``violation`` the code,
    ``violation_mask``, ``cost``, the diagnostics with ``visible`` as 0/1, ``reward_<term>``
    flat and 0.0 at reset), the same keys at reset and at every step.

    **Autoreset** (:attr:`autoreset_mode`, ``metadata["autoreset_mode"]``; the module doc says
    how to choose it), as Gymnasium's ``SyncVectorEnv`` does it. A sub-env is reset
    continuing its own RNG (no reseeding; as ``env.reset()`` without a seed).

    * ``NEXT_STEP`` (the default): the step that ends an episode returns its last observation,
      reward, flags and info, as any step. The next ``step`` resets that sub-env instead of
      stepping it (its action is ignored): its row holds the reset's observation and info,
      reward 0.0, ``terminated`` and ``truncated`` False; the others step as usual.
    * ``SAME_STEP``: a sub-env whose episode ends in a step is reset within that step: its row
      of the returned observations is the first observation of the next episode and its row of
      ``infos`` that reset's info; ``infos["final_obs"]`` (an object array, None for the
      others) and ``infos["final_info"]`` (a dict of arrays) hold the ended episode's last
      observation and info, masked by ``infos["_final_obs"]`` and ``infos["_final_info"]``.
      Its reward, ``terminated`` and ``truncated`` are the ended episode's last ones. There is
      never a step that only resets.
    * ``DISABLED``: no reset by ``step``; stepping a sub-env whose episode ended is a
      ``RuntimeError`` until ``reset`` restarts it (``options["reset_mask"]``).

    **reset(seed, options)**: ``seed`` None continues each sub-env's RNG; a list gives one seed
    (or None) per sub-env, exactly as ``gymnasium.make(id).reset(seed=...)`` would take it; one
    int ``s`` seeds the sub-envs with :func:`sub_env_seeds` (independent streams of
    ``SeedSequence(s)``, not Gymnasium's ``s + i``). ``options``: ``perturb`` (bool, as the
    single env's) and ``reset_mask`` (a bool array ``(num_envs,)``: reset only those sub-envs,
    as Gymnasium's vector envs do; the others keep their state and observation row, and the
    infos mask them out). The single env's ``poses`` option is not available (the batched core
    starts every episode from the scenario's configuration); other keys are ignored with a
    warning, as the single env does.

    **render()**: with ``render_mode="rgb_array"``, a tuple of one ``(H, W, 3)`` frame per
    sub-env. ``metadata["render_fps"]`` is the scenario's steps per second (one frame per
    step; :func:`~platoon_env.env.steps_per_second`).

    Args:
        num_envs: number of sub-envs.
        scenario: as :func:`platoon_env.make` (a shipped name, a YAML path, a dict, ...).
        render_mode: ``"rgb_array"`` or None.
        diagnostics: as the single env's (False: ``infos`` keeps only ``violation``,
            ``violations`` and ``cost``; in the numeric view ``violation``,
            ``violation_mask`` and ``cost``).
        info_view: ``"rich"`` (the default) or ``"numeric"``, as :func:`platoon_env.make`'s
            (:data:`~platoon_env.env.INFO_VIEWS`); ``"numeric"`` for TorchRL, BenchMARL and
            other libraries that turn infos into tensors (the module doc).
        normalize_actions, action_range: as :class:`~platoon_env.gym_env.SingleFollowerEnv`.
        n_threads: numba threads stepping the sub-envs (1: a serial loop); results do not
            depend on it.
        autoreset_mode: an ``AutoresetMode`` or its value (``"NextStep"``, ``"SameStep"``,
            ``"Disabled"``), as ``SyncVectorEnv`` takes it; default ``NEXT_STEP``.
        **overrides: the scenario options of :func:`platoon_env.make` (``followers`` is
            forced to 1). Any other keyword is a ``TypeError`` worded as Python words it
            (``make_vec() got an unexpected keyword argument ...``), listing the valid ones.
    """

    #: The class's defaults; each instance holds a copy with its own ``render_fps`` (its
    #: scenario's steps per second) and ``autoreset_mode``.
    metadata: dict[str, Any] = {
        "render_modes": ["rgb_array"],
        "render_fps": 100,
        "autoreset_mode": AutoresetMode.NEXT_STEP,
    }

    def __init__(
        self,
        num_envs: int = 1,
        scenario: SourceLike = "study_c",
        *,
        render_mode: str | None = None,
        diagnostics: bool = True,
        info_view: str = "rich",
        normalize_actions: bool = False,
        action_range: ActionRange | Mapping[str, float] | None = None,
        n_threads: int = 1,
        autoreset_mode: AutoresetMode | str = AutoresetMode.NEXT_STEP,
        **overrides: Any,
    ) -> None:
        check_env_keywords("make_vec()", overrides, VECTOR_OPTIONS, info_view)  # as make()
        #: When an ended sub-env is reset (see the class doc).
        self.autoreset_mode = _autoreset_mode(autoreset_mode)
        #: The view of ``infos``: ``"rich"`` or ``"numeric"`` (see the class doc).
        self.info_view = info_view
        if render_mode not in (None, *self.metadata["render_modes"]):
            raise ValueError(f"render_mode must be 'rgb_array' or None, got {render_mode!r}")
        self.diagnostics = check_bool("diagnostics", diagnostics, "make_vec()")
        #: The batched core holding the sub-envs (its ground-truth arrays: poses, sensing, ...).
        self.batch = BatchedPlatoon(
            scenario, num_envs, n_threads=n_threads, **single_follower(overrides, scenario)
        )
        self.num_envs = self.batch.batch_size
        self.render_mode = render_mode
        self.metadata = {
            **self.metadata,
            "render_fps": steps_per_second(self.batch.control_period),
            "autoreset_mode": self.autoreset_mode,
        }
        self.single_observation_space = self.batch.single_observation_space
        physical = self.batch.single_action_space
        #: The map of normalised actions to ``[u, omega]`` (None: actions are physical).
        self.action_range = action_range_of(
            normalize_actions, action_range, physical, "SingleFollowerVectorEnv"
        )
        self.single_action_space = (
            physical if self.action_range is None else normalised_action_space()
        )
        self.observation_space = batch_space(self.single_observation_space, self.num_envs)
        self.action_space = batch_space(self.single_action_space, self.num_envs)
        # Violation masks of the state on show (the last step's, zero after a reset): render().
        self._masks = np.zeros(self.num_envs, dtype=np.int64)
        # Sub-envs whose episode ended in the last step and that are not reset yet (NEXT_STEP:
        # the next step resets them; DISABLED: they may not step).
        self._ended = np.zeros(self.num_envs, dtype=bool)
        # Each sub-env's d_des (info["e_d"]); a procedural layout sets its own at reset.
        self._d_des = np.zeros(self.num_envs)
        self._renderers: list[Any] = [None] * self.num_envs
        self._drawn: list[Any] = [None] * self.num_envs  # the scenario each renderer draws

    # ----------------------------------------------------------------------------------------
    # Gymnasium VectorEnv API
    # ----------------------------------------------------------------------------------------
    def reset(
        self,
        *,
        seed: int | Sequence[int | None] | None = None,
        options: dict[str, Any] | None = None,
    ) -> tuple[np.ndarray, dict[str, Any]]:
        """Start new episodes (see the class doc for ``seed`` and ``options``); returns the
        observations ``(num_envs, K)`` and the reset infos."""
        options = dict(options or {})
        mask = self._reset_mask(options.pop("reset_mask", None))
        perturb = options.pop("perturb", None)
        if perturb is not None:
            perturb = check_bool("options['perturb']", perturb, "reset()")
        if "poses" in options:
            raise ValueError(
                "reset(): options['poses'] is not available in the vector env (the batched core "
                "starts from the scenario's configuration); use gymnasium.make(id) for it"
            )
        if options:
            warnings.warn(
                f"reset(): ignoring unknown option(s) {', '.join(sorted(map(str, options)))}",
                stacklevel=2,
            )
        seeds = self._seeds(seed)
        idx = np.flatnonzero(mask)
        obs = self.batch.reset([seeds[i] for i in idx], envs=idx, perturb=perturb)
        self._restarted(idx)
        self._ended[idx] = False
        return obs[:, 0], _masked(self._info_values(self._masks), mask)

    def step(
        self, actions: Any
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, dict[str, Any]]:
        """Advance every sub-env by one control period (``actions``: ``(num_envs, 2)``); a
        sub-env whose episode ended is reset as :attr:`autoreset_mode` says (the class doc)."""
        shape = (self.num_envs, ACT_SIZE)
        if self.autoreset_mode is AutoresetMode.NEXT_STEP and self._ended.any():
            return self._step_next(actions, shape)
        if self.autoreset_mode is AutoresetMode.DISABLED and self._ended.any():
            raise RuntimeError(
                f"sub-env(s) {np.flatnonzero(self._ended).tolist()} ended their episode and "
                "autoreset_mode is DISABLED: reset them first (reset(options={'reset_mask': "
                "...}))"
            )
        act = physical_actions(actions, shape, self.action_range, "actions")
        obs, rewards, terminated, truncated, step_info = self.batch.step(
            act.reshape(self.num_envs, 1, ACT_SIZE)
        )
        obs = obs[:, 0]
        masks = step_info["violations"][:, 0]
        values = self._info_values(masks, self.batch.reward_terms[:, 0])
        self._masks[:] = masks
        ended = terminated | truncated
        if not ended.any() or self.autoreset_mode is not AutoresetMode.SAME_STEP:
            self._ended[:] = ended  # NEXT_STEP resets them at the next step; DISABLED: reset()
            every = np.ones(self.num_envs, dtype=bool)
            return obs, rewards[:, 0], terminated, truncated, _masked(values, every)
        # SAME_STEP: the ended sub-envs' final observation and info, then their reset's.
        idx = np.flatnonzero(ended)
        final_obs = _objects([obs[i] if end else None for i, end in enumerate(ended.tolist())])
        final_info = _masked(values, ended)
        obs = self.batch.reset([None] * len(idx), envs=idx)[:, 0]
        self._restarted(idx)
        infos = _merged(_masked(values, ~ended), _masked(self._info_values(self._masks), ended))
        infos["final_obs"], infos["_final_obs"] = final_obs, ended.copy()
        infos["final_info"], infos["_final_info"] = final_info, ended.copy()
        return obs, rewards[:, 0], terminated, truncated, infos

    def _step_next(
        self, actions: Any, shape: tuple[int, int]
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, dict[str, Any]]:
        """A NEXT_STEP step while some sub-envs' episodes have ended, as ``SyncVectorEnv``
        does it: the others are stepped, then the ended ones reset (their actions ignored:
        reward 0.0, not terminated or truncated, the reset's observation and info). The step
        comes first so that a bad action raises before any state changes."""
        resetting = self._ended.copy()
        stepped = ~resetting
        given = np.asarray(actions)
        if given.shape == shape and given.dtype.kind in "fiu":
            given = given.copy()
            given[resetting] = 0.0  # ignored: a NaN there must not raise
        act = physical_actions(given, shape, self.action_range, "actions")
        rewards = np.zeros(self.num_envs)
        terminated = np.zeros(self.num_envs, dtype=bool)
        truncated = np.zeros(self.num_envs, dtype=bool)
        masks = np.zeros(self.num_envs, dtype=np.int64)
        terms = None
        if stepped.any():
            _, all_rewards, all_terminated, all_truncated, step_info = self.batch.step(
                act.reshape(self.num_envs, 1, ACT_SIZE), envs=stepped
            )
            rewards[stepped] = all_rewards[stepped, 0]
            terminated[stepped] = all_terminated[stepped]
            truncated[stepped] = all_truncated[stepped]
            masks[stepped] = step_info["violations"][stepped, 0]
            terms = self.batch.reward_terms[:, 0].copy()
        idx = np.flatnonzero(resetting)
        obs = self.batch.reset([None] * len(idx), envs=idx)[:, 0]
        self._restarted(idx)
        self._masks[:] = masks
        self._ended[:] = terminated | truncated
        infos = _merged(
            _masked(self._info_values(masks, terms), stepped),
            _masked(self._info_values(masks), resetting),
        )
        return obs, rewards, terminated, truncated, infos

    def render(self) -> tuple[np.ndarray, ...] | None:
        """One ``rgb_array`` frame per sub-env (None, with a warning, without a render_mode)."""
        if self.render_mode is None:
            warnings.warn(
                "render() called without a render_mode; pass render_mode='rgb_array' to make_vec()",
                stacklevel=2,
            )
            return None
        from platoon_env.rendering import Renderer

        poses = self.batch.poses
        visible = self.batch.sensed[:, :, SENSE_VISIBLE] > 0
        sim_time = self.batch.sim_time
        frames = []
        for i, scenario in enumerate(self.batch.scenarios):
            if self._drawn[i] is not scenario:  # a new layout: redraw from scratch
                if self._renderers[i] is not None:
                    self._renderers[i].close()
                self._renderers[i] = Renderer(
                    scenario.free_space,
                    scenario.config,
                    self.render_mode,
                    fps=self.metadata["render_fps"],
                    bounds=self.batch.source.bounds,
                )
                self._drawn[i] = scenario
            names = [first_cause(int(self._masks[i]))]
            frames.append(
                self._renderers[i].render(poses[i], visible[i], float(sim_time[i]), names)
            )
        return tuple(frames)

    def close_extras(self, **kwargs: Any) -> None:
        """Release the renderers."""
        for renderer in self._renderers:
            if renderer is not None:
                renderer.close()
        self._renderers = [None] * self.num_envs
        self._drawn = [None] * self.num_envs

    # ----------------------------------------------------------------------------------------
    # Internals
    # ----------------------------------------------------------------------------------------
    def _reset_mask(self, mask: Any) -> np.ndarray:
        """The sub-envs to reset: all, or ``options["reset_mask"]`` (checked as Gymnasium's
        vector envs check it)."""
        if mask is None:
            return np.ones(self.num_envs, dtype=bool)
        if not isinstance(mask, np.ndarray):
            raise TypeError(f"options['reset_mask'] must be a numpy array, got {type(mask)}")
        if mask.shape != (self.num_envs,):
            raise ValueError(
                f"options['reset_mask'] must have shape ({self.num_envs},), got {mask.shape}"
            )
        if mask.dtype != np.bool_:
            raise TypeError(f"options['reset_mask'] must have dtype bool, got {mask.dtype}")
        if not mask.any():
            raise ValueError("options['reset_mask'] must contain at least one True value")
        return mask.copy()

    def _seeds(self, seed: int | Sequence[int | None] | None) -> list[int | None]:
        """One checked seed (or None) per sub-env."""
        if seed is None:
            return [None] * self.num_envs
        if isinstance(seed, int | np.integer) and not isinstance(seed, bool):
            return list(sub_env_seeds(int(seed), self.num_envs))
        if isinstance(seed, str | bytes) or not isinstance(seed, Sequence | np.ndarray):
            raise TypeError(f"seed must be an int, a list of ints (or None) or None, got {seed!r}")
        if len(seed) != self.num_envs:
            raise ValueError(f"need one seed per sub-env ({self.num_envs}), got {len(seed)}")
        return [None if s is None else _check_seed(s) for s in seed]

    def _restarted(self, idx: np.ndarray) -> None:
        """Note the new episodes of sub-envs ``idx``: no violation on show, their d_des."""
        self._masks[idx] = 0
        scenarios = self.batch.scenarios
        self._d_des[idx] = [scenarios[i].config.formation.d_des for i in idx.tolist()]

    def _info_values(self, masks: np.ndarray, terms: np.ndarray | None = None) -> dict[str, Any]:
        """The single env's info entries of every sub-env, as arrays over the sub-envs (or, for
        ``reward_terms``, a dict of them): ``masks`` their violation masks, ``terms`` their
        reward terms ``(num_envs, len(REWARD_TERMS))`` (None after a reset, whose info has
        empty ``reward_terms``); the sensing is the core's current one."""
        if self.info_view == "numeric":
            return self._numeric_info_values(masks, terms)
        values: dict[str, Any] = dict(
            zip(INFO_KEYS, (_FIRST_CAUSE[masks], _CAUSES[masks], _COST[masks]))  # noqa: B905
        )
        if self.diagnostics:
            sensed = self.batch.sensed[:, 0]
            for name in SENSE_INFO_KEYS:
                values[name] = sensed[:, SENSE_NAMES.index(name)]
            values["e_d"] = values["d"] - self._d_des
            values["e_beta"] = values["beta"]
            values["visible"] = sensed[:, SENSE_VISIBLE] > 0.0
            values["reward_terms"] = (
                {} if terms is None else {t: terms[:, k] for k, t in enumerate(REWARD_TERMS)}
            )
        return values

    def _numeric_info_values(
        self, masks: np.ndarray, terms: np.ndarray | None
    ) -> dict[str, np.ndarray]:
        """:meth:`_info_values` in the numeric view: the single env's numeric info
        (``PlatoonParallelEnv._numeric_infos``, same keys in the same order) as ``int64`` and
        ``float64`` arrays over the sub-envs; the reward terms 0.0 after a reset."""
        masks = masks.astype(np.int64)
        columns: dict[str, np.ndarray] = {
            "violation": _CODE[masks],
            "violation_mask": masks.copy(),
            "cost": _COST[masks],
        }
        if not self.diagnostics:
            return {key: columns[key] for key in NUMERIC_INFO_KEYS[:N_VIOLATION_INFO]}
        sensed = self.batch.sensed[:, 0].astype(np.float64)
        for name in SENSE_INFO_KEYS:
            columns[name] = sensed[:, SENSE_NAMES.index(name)]
        columns["e_d"] = columns["d"] - self._d_des
        columns["e_beta"] = columns["beta"].copy()
        columns["visible"] = (sensed[:, SENSE_VISIBLE] > 0.0).astype(np.int64)
        for k, term in enumerate(REWARD_TERMS):
            columns[f"reward_{term}"] = (
                np.zeros(self.num_envs) if terms is None else terms[:, k].astype(np.float64)
            )
        return {key: columns[key] for key in NUMERIC_INFO_KEYS}


def _autoreset_mode(mode: Any) -> AutoresetMode:
    """``mode`` as an ``AutoresetMode`` (an ``AutoresetMode`` or its value, as
    ``SyncVectorEnv`` takes it), else ``ValueError`` listing the modes."""
    if isinstance(mode, AutoresetMode):
        return mode
    try:
        return AutoresetMode(mode)
    except (ValueError, TypeError):
        modes = ", ".join(f"AutoresetMode.{m.name} ({m.value!r})" for m in AutoresetMode)
        raise ValueError(
            f"make_vec(): autoreset_mode: expected one of {modes}, got {mode!r}"
        ) from None


def _masked(values: dict[str, Any], rows: np.ndarray) -> dict[str, Any]:
    """``values`` (arrays over all sub-envs, or dicts of them) kept in ``rows`` only, each key
    with its ``_key`` mask: Gymnasium's batched info of the sub-envs in ``rows`` (no keys for
    no rows: a key appears once some sub-env has it)."""
    out: dict[str, Any] = {}
    if not rows.any():
        return out
    for key, value in values.items():
        if isinstance(value, dict):
            out[key] = _masked(value, rows)
        else:
            array = np.zeros_like(value) if value.dtype != object else np.full_like(value, None)
            array[rows] = value[rows]
            out[key] = array
        out[f"_{key}"] = rows.copy()
    return out


def _merged(first: dict[str, Any], second: dict[str, Any]) -> dict[str, Any]:
    """Two batched infos of disjoint sub-envs (:func:`_masked`) as one: each row from the one
    whose ``_key`` mask holds it, as Gymnasium's vector envs gather their sub-envs' infos."""
    out: dict[str, Any] = {}
    for key in [*first, *(k for k in second if k not in first)]:
        if key.startswith("_"):
            continue
        if key not in second or key not in first:
            source = first if key in first else second
            out[key], out[f"_{key}"] = source[key], source[f"_{key}"]
            continue
        rows = second[f"_{key}"]
        if isinstance(first[key], dict):
            out[key] = _merged(first[key], second[key])
        else:
            out[key] = first[key].copy()
            out[key][rows] = second[key][rows]
        out[f"_{key}"] = first[f"_{key}"] | rows
    return out
