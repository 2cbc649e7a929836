"""What the ``aruco`` sensor profile means on the shipped studies: the table of docs/realism.md.

Usage::

    python scripts/aruco_table.py [--profile aruco]

Prints, per study (A, B, C), the formation's ``d_des`` and ``d_con``, the camera's per-axis
position noise std at both (``position + position_per_m * d``), the extra lateral std of the
bearing error at ``d_des`` (``d_des * bearing``), the detection probability straight ahead and
at ``beta = beta_con`` (``detection * (1 - detection_edge)``), then the age of a camera report
when it is acted on (the latency, plus up to the longest gap between two frames at the study's
control period, from the camera's own frame rule: a frame is used from its delivery until
the next one arrives) and the largest change of the applied ``u``
and ``omega`` in one control period (``accel_max dt``, ``alpha_max dt``). Everything is read
from the profile and the studies' configs as ``platoon_env.make`` builds them.
"""

from __future__ import annotations

import argparse
import itertools
import math

import platoon_env
from experiments.suites import STUDIES
from platoon_env.perception import frame_due_at


def _cm(value: float) -> str:
    return f"{100 * value:.1f} cm"


def _letter(study: str) -> str:
    return study.rsplit("_", 1)[-1].upper()


def main() -> None:
    ap = argparse.ArgumentParser(description=(__doc__ or "").split("\n\n")[0])
    ap.add_argument("--profile", default="aruco")
    args = ap.parse_args()
    envs = {s: platoon_env.make(s, sensor_profile=args.profile) for s in STUDIES}
    cfgs = {s: env.scenario.config for s, env in envs.items()}
    head = "| | " + " | ".join(f"study {_letter(s)}" for s in STUDIES) + " |"
    rows = [head, "|---|" + "---|" * len(STUDIES)]

    def row(label: str, cell: dict[str, str]) -> None:
        rows.append(f"| {label} | " + " | ".join(cell[s] for s in STUDIES) + " |")

    row("`d_des`, `d_con`", {s: f"{c.formation.d_des:g} m, {c.camera.range:g} m"
                              for s, c in cfgs.items()})  # fmt: skip
    std = {}
    for s, c in cfgs.items():
        n = c.camera.noise
        std[s] = (
            f"{_cm(n.position + n.position_per_m * c.formation.d_des)} "
            f"({_cm(n.position + n.position_per_m * c.camera.range)})"
        )
    row("per-axis position std at `d_des` (at `d_con`)", std)
    row("extra lateral std from the bearing error at `d_des`",
        {s: _cm(c.formation.d_des * c.camera.noise.bearing) for s, c in cfgs.items()})  # fmt: skip
    row("detection straight ahead / at `β_con`",
        {s: f"{c.camera.detection:g} / {c.camera.detection * (1 - c.camera.detection_edge):g}"
         for s, c in cfgs.items()})  # fmt: skip
    print("\n".join(rows))
    print()
    ages, du, dw, steps = [], [], [], set()
    for s, env in envs.items():
        cam, rob, dt = cfgs[s].camera, cfgs[s].robot, float(env.control_period)
        period = 0.0 if cam.frame_rate is None else 1.0 / cam.frame_rate
        taken = [k for k in range(1, 1000) if frame_due_at(k, dt, period)]
        # a frame is used from its delivery (latency after it was taken) until the next one
        gap = max(b - a for a, b in itertools.pairwise(taken)) if len(taken) > 1 else 1
        ages.append((cam.latency, cam.latency + (gap - 1) * dt))
        du.append((rob.accel_max or math.inf) * dt)
        dw.append((rob.alpha_max or math.inf) * dt)
        steps.add(dt)
    if len(steps) != 1:
        raise SystemExit(f"the studies' control periods differ ({sorted(steps)}): one sentence "
                         "cannot describe them")  # fmt: skip
    (step,) = steps
    low = min(a for a, _ in ages) * 1000
    high = max(b for _, b in ages) * 1000
    print(
        f"On every study a camera report is {low:.0f}–{high:.0f} ms old at the control steps "
        "that use it (the latency, then held until the next frame arrives), and the command "
        f"acts for one more {step:g} s period. The applied `u` changes by at most {max(du):g} "
        f"m/s and `ω` by at most {max(dw):g} rad/s per step."
    )


if __name__ == "__main__":
    main()
