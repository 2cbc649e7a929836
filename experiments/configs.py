"""The shipped learned configurations: named sets of ``platoon-train`` options.

:data:`CONFIGS` is what ``platoon-sweep`` (:mod:`experiments.studies.sweep`) trains and what the
model cards (:mod:`experiments.cards`) summarise; :data:`SHIPPED` names those whose runs are in
``models/``. A table of data below the drivers, so that both read it without importing each
other.
"""

from __future__ import annotations

from dataclasses import dataclass

from experiments.names import by_name

__all__ = ["CONFIGS", "DEFAULT_SEEDS", "SHIPPED", "Config"]


@dataclass(frozen=True)
class Config:
    """A shipped learned configuration: its ``platoon-train`` options and what they are for."""

    name: str
    summary: str
    args: tuple[str, ...]


#: The options the two SB3 configurations share: the medium procedural tier (corridors and
#: rooms, disjoint from every test split), trained under the aruco sensing profile (camera noise,
#: 30 Hz frames with 50 ms latency, detection drop-outs, LiDAR noise, acceleration limits) with
#: the task-aware observation; 25 ms control period (aruco's 30 Hz camera needs one <= 1/30 s).
_COMMON = (
    "--scenario",
    "procedural_medium_train",
    "--sensor-profile",
    "aruco",
    "--task-aware-observations",
    "--control-period",
    "0.025",
    "--timesteps",
    "1500000",
)

#: The fast engine's env copies and step size in every configuration of it: 64 copies, each
#: keeping a layout for 8 episodes, Adam at 3e-4.
_FAST_COPIES = ("--layout-repeats", "8", "--n-envs", "64", "--learning-rate", "3e-4")

#: The fast engine's cloning + fine-tuning options (``training/bc.py``, ``docs/training.md``): 30 ms
#: control period (at 50 ms the PPC law itself fails the sharp tier), ideal sensing, task-aware
#: observations, 64 env copies keeping a layout for 8 episodes, DAgger with 6 iterations of
#: 1,500 steps per copy, then 1.5 M transitions of PPO at learning rate 3e-4.
_BC_PPO = (
    "--engine",
    "fast",
    "--algo",
    "bc_ppo",
    "--task-aware-observations",
    "--control-period",
    "0.03",
    *_FAST_COPIES,
    "--timesteps",
    "1500000",
    "--bc-iterations",
    "6",
    "--bc-steps-per-iteration",
    "1500",
    "--bc-epochs",
    "8",
    "--log-every",
    "100000",
)


def _with(args: tuple[str, ...], **options: str) -> tuple[str, ...]:
    """``args`` with each ``--option value`` of ``options`` (``control_period`` is
    ``--control-period``) replaced, or appended if ``args`` lacks it."""
    out = list(args)
    for key, value in options.items():
        flag = "--" + key.replace("_", "-")
        if flag in out:
            out[out.index(flag) + 1] = value
        else:
            out += [flag, value]
    return tuple(out)


#: The residual configurations' options (``--residual ppc``, ``training/fast_ppo.py``): PPO on
#: the batched core whose mean action is the PPC law's command (normalised, clipped to the
#: action range) plus the network's output, which starts at zero; the sharp and paper tiers
#: mixed with a formation per layout, scale-free observations, 25 ms (a whole number of periods
#: in the aruco profile's 50 ms latency, so the policies can be evaluated under it; PPC
#: clipped to the action range passes studies A, B and C at 25 ms, 10/10 each), exploration noise
#: ``sigma = e^-1.5``, the critic warmed up for 3 rollouts, the residual kept small
#: (``--anchor-coef 1``: the squared residual). Under ideal sensing the law alone completes the
#: training episodes (the curve starts near its end), so that run is shorter.
_RESIDUAL = (
    "--engine",
    "fast",
    "--algo",
    "ppo",
    "--residual",
    "ppc",
    "--scenario",
    "procedural_formations_sharp_train+procedural_formations_paper_train",
    "--task-aware-observations",
    "--scale-free-observations",
    "--control-period",
    "0.025",
    *_FAST_COPIES,
    "--log-std-init",
    "-1.5",
    "--value-warmup",
    "3",
    "--anchor-coef",
    "1.0",
    "--log-every",
    "100000",
)

#: The configurations trained by ``python -m experiments.studies.sweep`` and shipped in ``models/``.
CONFIGS: dict[str, Config] = by_name(
    Config(
        "ppo_ta_aruco",
        "SB3 PPO on the env's reward, aruco profile, task-aware observations",
        ("--algo", "ppo", *_COMMON),
    ),
    Config(
        "lag_ta_aruco",
        "PPO-Lagrangian (cost budget 0.05 per follower episode), aruco profile, task-aware "
        "observations",
        ("--algo", "ppo_lagrangian", "--cost-budget", "0.05", *_COMMON),
    ),
    Config(
        "bc_ppo_sharp",
        "fast engine: the PPC law cloned with DAgger (6 iterations), then PPO fine-tuning, on "
        "the sharp tier (study C's formation), ideal sensing, task-aware observations, 30 ms",
        ("--scenario", "procedural_sharp_train", *_BC_PPO),
    ),
    Config(
        "bc_ppo_formations_sf",
        "fast engine: as bc_ppo_sharp, on the sharp tier with a formation drawn per layout "
        "(1-7 followers, the three studies' ranges), scale-free observations",
        (
            "--scenario",
            "procedural_formations_sharp_train",
            "--scale-free-observations",
            *_BC_PPO,
        ),
    ),
    Config(
        "bc_ppo_mixed_anchor",
        "fast engine: as bc_ppo_formations_sf, on the sharp and paper tiers mixed (a family "
        "drawn per episode), the fine-tuning anchored to the clone (--anchor-coef 1)",
        (
            "--scenario",
            "procedural_formations_sharp_train+procedural_formations_paper_train",
            "--scale-free-observations",
            "--anchor-coef",
            "1.0",
            *_BC_PPO,
        ),
    ),
    Config(
        "bc_ppo_mixed_20ms",
        "fast engine: as bc_ppo_mixed_anchor at a 20 ms control period (PPC clipped to the "
        "learner's action range fails study A at 30 ms, 2/10, and passes it at 20 ms, 10/10), "
        "128-128 layers, 8 DAgger iterations of 2,000 steps",
        _with(
            (
                "--scenario",
                "procedural_formations_sharp_train+procedural_formations_paper_train",
                "--scale-free-observations",
                "--anchor-coef",
                "1.0",
                "--net-arch",
                "128",
                "128",
                *_BC_PPO,
            ),
            control_period="0.02",
            bc_iterations="8",
            bc_steps_per_iteration="2000",
        ),
    ),
    Config(
        "residual_ppc",
        "fast engine: a residual policy on the PPC law (its clipped command plus a learned "
        "correction that starts at zero), sharp and paper tiers mixed, formations drawn, "
        "scale-free observations, ideal sensing, 25 ms, 5 M transitions",
        _with(_RESIDUAL, timesteps="5000000"),
    ),
    Config(
        "residual_filtered_aruco",
        "fast engine: as residual_ppc on the filtered PPC law (the law on filtered, "
        "latency-compensated estimates), trained under the aruco sensing profile (camera "
        "noise, 30 Hz frames with 50 ms latency, drop-outs, LiDAR noise, acceleration limits) "
        "for 10 M transitions",
        _with(_RESIDUAL, sensor_profile="aruco", residual="filtered_ppc", timesteps="10000000"),
    ),
    Config(
        "residual_drive_aruco",
        "fast engine: as residual_filtered_aruco on the drive-aware filtered PPC (the "
        "filtered PPC with a lookahead sized for the rate-limited drive, chosen on training "
        "layouts: baselines/filtered_ppc_drive.py), 20 M transitions",
        _with(
            _RESIDUAL,
            sensor_profile="aruco",
            residual="filtered_ppc_drive",
            timesteps="20000000",
        ),
    ),
    Config(
        "residual_drive_realism",
        "fast engine: as residual_drive_aruco with the realism drawn per episode "
        "(--realism-preset ideal_to_beyond_aruco: from ideal sensing to beyond the aruco "
        "profile; the law keeps the nominal aruco parameters), 20 M transitions",
        _with(
            _RESIDUAL,
            sensor_profile="aruco",
            residual="filtered_ppc_drive",
            realism_preset="ideal_to_beyond_aruco",
            timesteps="20000000",
        ),
    ),
    Config(
        "residual_filtered_realism",
        "fast engine: as residual_drive_realism on the filtered PPC law (no drive lookahead), "
        "10 M transitions (its aruco twin residual_filtered_aruco flattened within them)",
        _with(
            _RESIDUAL,
            sensor_profile="aruco",
            residual="filtered_ppc",
            realism_preset="ideal_to_beyond_aruco",
            timesteps="10000000",
        ),
    ),
    Config(
        "lag_residual_drive_realism",
        "fast engine: as residual_drive_realism trained by PPO-Lagrangian with a cost critic "
        "(budget 0.15 violations per follower episode, below the law's level at the start of "
        "training; cost advantages standardised over each rollout, so the anchor to the law "
        "does not outweigh the penalty as the multiplier grows)",
        _with(
            _RESIDUAL,
            algo="ppo_lagrangian",
            cost_budget="0.15",
            cost_advantage="standardised",
            sensor_profile="aruco",
            residual="filtered_ppc_drive",
            realism_preset="ideal_to_beyond_aruco",
            timesteps="20000000",
        ),
    ),
    Config(
        "residual_filtered_aruco_cmd",
        "fast engine: as residual_filtered_aruco, the policy also reading its own previous "
        "command (--previous-command: under the aruco profile's acceleration limits the applied "
        "velocity lags the command)",
        (
            *_with(
                _RESIDUAL, sensor_profile="aruco", residual="filtered_ppc", timesteps="10000000"
            ),
            "--previous-command",
        ),
    ),
)

#: The configurations whose runs are in ``models/`` (five seeds each, with the cards the
#: leaderboard writes once it has evaluated a run on every task,
#: ``experiments.studies.leaderboard``). The behaviour-cloning configurations are defined and
#: trained here but not shipped: none completes the paper's studies (README, "Learned policies
#: against PPC").
SHIPPED: tuple[str, ...] = (
    "ppo_ta_aruco",
    "lag_ta_aruco",
    "residual_ppc",
    "residual_filtered_aruco",
    "residual_drive_aruco",
    "residual_drive_realism",
    "residual_filtered_realism",
    "lag_residual_drive_realism",
)

#: The seeds of a sweep unless ``--seeds`` says otherwise.
DEFAULT_SEEDS = (0, 1, 2, 3, 4)
