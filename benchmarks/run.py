"""Speed of platoon_env against PettingZoo MPE and VMAS, in one command (prints the tables).

Usage::

    python benchmarks/run.py [--out DIR] [--seconds 1.5] [--threads 2] [--quick]
                             [--no-mpe] [--no-vmas] [--no-plot]

What is timed (every number is the median of three timed runs after a warm-up):

* **headline** — one PettingZoo ``ParallelEnv`` of study A (7 followers, dict I/O) against MPE
  ``simple_spread`` with 7 agents (mpe2, also a PettingZoo ``ParallelEnv``), the batched array
  API (:class:`platoon_env.batched.BatchedPlatoon`) at 1, 32 and 1,024 envs, and VMAS
  ``navigation`` with 7 agents on the CPU (torch, 1,024 envs);
* **scaling** — synthetic maps of about 200, 1,000 and 5,000 boundary edges
  (:mod:`maps`: the same lane and nearby pillars, more rows of pillars farther away) with
  N = 1, 7 and 50 followers: the ParallelEnv and the batched API at B = 1, 32 and 1,024, and the
  batched API at B = 32 with edge culling switched off (``grid_cell_size=0``) for comparison;
* **formations** — the batched API on ``procedural_formations_train`` (each env its own
  layout and formation: 1-7 followers, r, d_des, d_col, d_con, beta_con, leader speed) at
  1,024 envs and ``--threads`` threads, physical and scale-free observations; agent-steps count
  the live followers only (``BatchedPlatoon.live``); the followers pursue their reported
  predecessors (a vectorised proportional law);
  and the median time of one env's reset onto a new layout (draw, build, install, sensing);
* **PPC** — ``baselines.PPCPolicy.act`` per follower.

The followers replay actions recorded from the PPC policy on the same scenario and seed (so the
platoon moves as in a real episode; the policy's own cost is not timed), with
``terminate_on=()`` so that no violation shortens an episode; episodes that reach their end are
reset inside the timed loop. MPE and VMAS get constant pre-sampled random actions.

Writes ``results.md`` (the tables, as quoted in the README), ``results.json`` and
``scaling.png`` to ``--out`` (default: ``platoon_bench`` in the temporary directory).
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import sys
import tempfile
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

from maps import pillar_lane

import platoon_env
from baselines import PPCPolicy
from platoon_env.batched import BatchedPlatoon

REPEATS = 3


# ------------------------------------------------------------------------------------------------
# Timing
# ------------------------------------------------------------------------------------------------
def rate(step: Callable[[], Any], units_per_call: float, seconds: float) -> float:
    """Median over :data:`REPEATS` runs of ``units_per_call * calls / elapsed``."""
    step()  # warm-up (compilation, caches)
    rates = []
    budget = seconds / REPEATS
    for _ in range(REPEATS):
        calls = 0
        start = time.perf_counter()
        while True:
            step()
            calls += 1
            elapsed = time.perf_counter() - start
            if elapsed >= budget:
                break
        rates.append(units_per_call * calls / elapsed)
    return statistics.median(rates)


def machine() -> dict[str, Any]:
    """What the numbers were measured on."""
    import numba

    cpu = platform.processor() or platform.machine()
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    info: dict[str, Any] = {
        "cpu": cpu,
        "cores": os.cpu_count(),
        "os": f"{platform.system()} {platform.release()}",
        "python": platform.python_version(),
        "numpy": np.__version__,
        "numba": numba.__version__,
        "numba_threads": numba.config.NUMBA_NUM_THREADS,  # type: ignore[attr-defined]
        "platoon_env": platoon_env.__version__,
    }
    try:
        info["load_average"] = [round(x, 2) for x in os.getloadavg()]
    except OSError:
        pass
    return info


# ------------------------------------------------------------------------------------------------
# Workloads
# ------------------------------------------------------------------------------------------------
def record_ppc_actions(scenario: Any, steps: int, seed: int = 0) -> np.ndarray:
    """``(T, N, 2)`` float32 actions of the PPC policy over one episode from ``seed``."""
    env = platoon_env.make(scenario, terminate_on=())
    policy = PPCPolicy(env)
    obs, _ = env.reset(seed=seed)
    policy.reset(seed=seed)
    out = []
    for _ in range(steps):
        act = policy.act(obs)
        out.append(np.stack([np.asarray(act[a], dtype=np.float32) for a in env.possible_agents]))
        obs, _, _, _, _ = env.step(act)
        if not env.agents:
            break
    return np.stack(out)


def time_parallel_env(
    scenario: Any, actions: np.ndarray, seconds: float, diagnostics: bool = True, **realism: Any
) -> float:
    """Env-steps/s of one ParallelEnv replaying ``actions`` (PettingZoo dict I/O); ``realism``:
    e.g. ``sensor_profile="aruco"``."""
    env = platoon_env.make(scenario, terminate_on=(), diagnostics=diagnostics, **realism)
    agents = env.possible_agents
    dicts = [{a: row[i] for i, a in enumerate(agents)} for row in actions]
    env.reset(seed=0)
    state = {"t": 0}

    def step() -> None:
        env.step(dicts[state["t"]])
        state["t"] += 1
        if state["t"] == len(dicts) or not env.agents:
            env.reset(seed=0)
            state["t"] = 0

    return rate(step, 1, seconds)


def time_batched(
    scenario: Any,
    actions: np.ndarray,
    batch: int,
    threads: int,
    seconds: float,
    grid_cell_size: float | None = None,
    **realism: Any,
) -> float:
    """Env-steps/s of :class:`BatchedPlatoon` with ``batch`` envs replaying ``actions``."""
    core = BatchedPlatoon(
        scenario,
        batch,
        n_threads=threads,
        auto_reset=True,
        terminate_on=(),
        grid_cell_size=grid_cell_size,
        **realism,
    )
    shape = (batch, core.n_followers, 2)
    core.reset(0)
    state = {"t": 0}

    def step() -> None:
        core.step(np.broadcast_to(actions[state["t"]], shape))
        state["t"] += 1
        if state["t"] == len(actions):
            core.reset(0)
            state["t"] = 0

    return rate(step, batch, seconds)


#: The scenario of the formations rows: every env draws its layout and formation.
FORMATIONS = "procedural_formations_train"


def time_formations(
    batch: int, threads: int, seconds: float, **overrides: Any
) -> tuple[float, float, float, float]:
    """``(env-steps/s, mean live followers, median reset [ms], its CPU time [ms])`` of
    :class:`BatchedPlatoon` on :data:`FORMATIONS` with ``batch`` envs (auto-reset,
    ``terminate_on=()``), the followers pursuing their reported predecessors (a vectorised
    proportional law, its cost included). The reset time is one
    env's reset onto a new layout (the first ``batch`` resets, each timed alone, wall clock
    and this process's CPU time: on a loaded machine the first exceeds the second)."""
    core = BatchedPlatoon(
        FORMATIONS, batch, n_threads=threads, auto_reset=True, terminate_on=(), **overrides
    )
    resets, cpu = [], []
    for b in range(batch):
        start, start_cpu = time.perf_counter(), time.process_time()
        obs = core.reset([b], envs=[b])  # every env's observations (the last: all reset)
        resets.append(time.perf_counter() - start)
        cpu.append(time.process_time() - start_cpu)
    params = core._core.params  # each env's own d_des and d_con (the benchmark's pursuit law)
    scale_free = bool(params["scale_free"][0])
    live: list[float] = []
    state = {"obs": obs}

    def step() -> None:
        # Pursuit of the reported predecessor, vectorised over every slot (a stand-in for a
        # policy, so that the platoon drives as in an episode and not into the walls).
        o = state["obs"]
        unit = params["d_con"][:, None] if scale_free else 1.0
        x, y = o[..., 1] * unit, o[..., 2] * unit
        seen = o[..., 0] > 0
        gap = np.hypot(x, y) - params["d_des"][:, None]
        u = np.where(seen, np.clip(0.8 * gap + 0.2, -0.3, 0.8), 0.0)
        omega = np.where(seen, np.clip(2.0 * np.arctan2(y, x), -2.0, 2.0), 0.0)
        state["obs"] = core.step(np.stack([u, omega], axis=-1))[0]
        live.append(float(core.n_active.mean()))

    rate_ = rate(step, batch, seconds)
    return (
        rate_,
        statistics.fmean(live),
        1e3 * statistics.median(resets),
        1e3 * statistics.median(cpu),
    )


def isolated(fn: Callable[..., Any], *args: Any) -> Any:
    """``fn(*args)`` in a fresh process, so that another library's thread pools (numba's, torch's
    OpenMP) neither slow it down nor are slowed down by it."""
    import multiprocessing

    with multiprocessing.get_context("spawn").Pool(1) as pool:
        return pool.apply(fn, args)


def time_mpe(n_agents: int, seconds: float) -> tuple[float | None, str]:
    """Env-steps/s of MPE ``simple_spread`` (PettingZoo ParallelEnv), or None and why."""
    try:
        from mpe2 import simple_spread_v3
    except ImportError:
        try:
            from pettingzoo.mpe import simple_spread_v3  # older PettingZoo
        except ImportError as exc:
            return None, f"MPE not installed ({exc}); pip install 'platoon-env[bench]'"
    env = simple_spread_v3.parallel_env(N=n_agents, max_cycles=10**9, continuous_actions=True)
    env.reset(seed=0)
    rng = np.random.default_rng(0)
    dicts = [
        {a: rng.uniform(0, 1, env.action_space(a).shape).astype(np.float32) for a in env.agents}
        for _ in range(64)
    ]
    state = {"t": 0}

    def step() -> None:
        env.step(dicts[state["t"] % 64])
        state["t"] += 1

    return rate(step, 1, seconds), f"mpe2 simple_spread_v3, N={n_agents}, continuous actions"


def time_vmas(n_agents: int, batch: int, threads: int, seconds: float) -> tuple[float | None, str]:
    """Env-steps/s of VMAS ``navigation`` on the CPU, or None and why."""
    try:
        import torch
        import vmas
    except ImportError as exc:
        return None, f"VMAS not installed ({exc}); pip install vmas"
    previous = torch.get_num_threads()
    torch.set_num_threads(threads)
    try:
        env = vmas.make_env(
            "navigation",
            num_envs=batch,
            device="cpu",
            continuous_actions=True,
            n_agents=n_agents,
            seed=0,
        )
        env.reset()
        gen = torch.Generator().manual_seed(0)
        acts = [torch.rand(batch, 2, generator=gen) * 2 - 1 for _ in range(n_agents)]
        result = rate(lambda: env.step(acts), batch, seconds)
    finally:
        torch.set_num_threads(previous)
    return result, f"vmas {vmas.__version__} navigation, N={n_agents}, CPU, torch threads={threads}"


def time_ppc(scenario: Any, seconds: float) -> tuple[float, int]:
    """Microseconds per follower of one ``PPCPolicy.act`` call, and N."""
    env = platoon_env.make(scenario)
    policy = PPCPolicy(env)
    obs, _ = env.reset(seed=0)
    policy.reset(seed=0)
    calls_per_s = rate(lambda: policy.act(obs), 1, seconds)
    return 1e6 / calls_per_s / env.n_followers, env.n_followers


# ------------------------------------------------------------------------------------------------
# Report
# ------------------------------------------------------------------------------------------------
@dataclass
class Row:
    """One timed configuration."""

    what: str
    map: str
    edges: int
    n: int
    batch: int | None
    threads: int | None
    env_steps: float
    culling: bool = True
    note: str = ""
    extra: dict[str, Any] = field(default_factory=dict)
    #: the mean live followers per env (a drawn formation; None: all ``n``)
    live: float | None = None

    @property
    def agent_steps(self) -> float:
        return self.env_steps * (self.n if self.live is None else self.live)


def _fmt(x: float | None) -> str:
    if x is None:
        return "—"
    if x >= 1e6:
        return f"{x / 1e6:.2f} M"
    if x >= 1e3:
        return f"{x / 1e3:.1f} k"
    return f"{x:.0f}"


def headline_table(rows: list[Row], mpe: float | None, vmas: float | None) -> str:
    lines = [
        "| what | N | envs | threads | env-steps/s | agent-steps/s | vs MPE (env-steps) "
        "| vs VMAS (agent-steps) |",
        "|---|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for r in rows:
        vs_mpe = f"{r.env_steps / mpe:,.0f}×" if mpe and r.what != "MPE simple_spread" else ""
        vs_vmas = (
            f"{r.agent_steps / vmas:.1f}×"
            if vmas and r.batch and r.batch > 1 and not r.what.startswith("VMAS")
            else ""
        )
        lines.append(
            f"| {r.what} | {r.n} | {r.batch or 1:,} | {r.threads or 1} | {_fmt(r.env_steps)} "
            f"| {_fmt(r.agent_steps)} | {vs_mpe} | {vs_vmas} |"
        )
    return "\n".join(lines)


def formations_table(rows: list[Row]) -> str:
    """The formations rows: envs, threads, mean live followers, agent-steps/s, reset time."""
    lines = [
        "| what | envs | threads | mean live followers | agent-steps/s | reset per layout "
        "(median) | its CPU time |",
        "|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        lines.append(
            f"| {r.what} | {r.batch} | {r.threads} | {r.live:.2f} | {_fmt(r.agent_steps)} | "
            f"{r.extra['reset_ms_median']:.1f} ms | {r.extra['reset_cpu_ms_median']:.1f} ms |"
        )
    return "\n".join(lines)


def scaling_table(rows: list[Row]) -> str:
    lines = [
        "| map edges | N | API | envs | threads | culling | env-steps/s | agent-steps/s "
        "| µs per agent-step |",
        "|---:|---:|---|---:|---:|---|---:|---:|---:|",
    ]
    for r in rows:
        api = "ParallelEnv (dicts)" if r.batch is None else "batched arrays"
        lines.append(
            f"| {r.edges:,} | {r.n} | {api} | {r.batch or 1:,} | {r.threads or 1} "
            f"| {'grid' if r.culling else 'off'} | {_fmt(r.env_steps)} | {_fmt(r.agent_steps)} "
            f"| {1e6 / r.agent_steps:.2f} |"
        )
    return "\n".join(lines)


def plot(scaling: list[Row], mpe: Row | None, vmas: list[Row], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (ax1, ax2) = plt.subplots(1, 2, figsize=(11, 4.2))
    biggest = max(r.edges for r in scaling)
    for n in sorted({r.n for r in scaling}):
        pts = sorted(
            (r.batch, r.agent_steps)
            for r in scaling
            if r.n == n and r.edges == biggest and r.batch and r.culling
        )
        if pts:
            ax1.plot(*zip(*pts, strict=True), "o-", label=f"platoon batched, N={n}")
        single = [r for r in scaling if r.n == n and r.edges == biggest and r.batch is None]
        if single:
            ax1.plot([1], [single[0].agent_steps], "s", label=f"platoon ParallelEnv, N={n}")
    for r in vmas:
        ax1.plot([r.batch], [r.agent_steps], "^", label=f"VMAS navigation N={r.n}, {r.threads} th")
    if mpe is not None:
        ax1.plot([1], [mpe.agent_steps], "v", label=f"MPE simple_spread N={mpe.n}")
    ax1.set(
        xscale="log",
        yscale="log",
        xlabel="batched envs",
        ylabel="agent-steps/s",
        title=f"throughput ({biggest:,}-edge map)",
    )
    ax1.legend(fontsize=7)
    for culling, style in ((True, "o-"), (False, "x--")):
        for n in sorted({r.n for r in scaling}):
            pts = sorted(
                (r.edges, 1e6 / r.agent_steps)
                for r in scaling
                if r.n == n and r.batch == 32 and r.culling == culling
            )
            if pts:
                label = f"N={n}, {'grid culling' if culling else 'no culling'}"
                ax2.plot(*zip(*pts, strict=True), style, label=label)
    edge_ticks = sorted({r.edges for r in scaling})
    ax2.set(
        xscale="log",
        yscale="log",
        xticks=edge_ticks,
        xticklabels=[f"{e:,}" for e in edge_ticks],
        xlabel="boundary edges in the map",
        ylabel="µs per agent-step (32 envs)",
        title="cost vs map size",
    )
    ax2.minorticks_off()
    ax2.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


# ------------------------------------------------------------------------------------------------
# Main
# ------------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class Sizes:
    """What a run times: ``seconds`` per number, the PPC episode's length recorded for
    replay, the scaling maps' edges, followers and batches, the large batch ``big`` and the
    numba ``threads`` of the batched rows (``--quick``: a small smoke run)."""

    seconds: float
    record_steps: int
    edge_counts: tuple[int, ...]
    followers: tuple[int, ...]
    batches: tuple[int, ...]
    big: int
    threads: int
    quick: bool

    @classmethod
    def of(cls, args: argparse.Namespace) -> Sizes:
        """The sizes of the command line ``args``."""
        quick = bool(args.quick)
        return cls(
            seconds=0.15 if quick else args.seconds,
            record_steps=100 if quick else 2000,
            edge_counts=(200,) if quick else (200, 1000, 5000),
            followers=(1, 7) if quick else (1, 7, 50),
            batches=(1, 32) if quick else (1, 32, 1024),
            big=32 if quick else 1024,
            threads=args.threads,
            quick=quick,
        )


@dataclass
class Headline:
    """The headline rows, the notes on the other libraries, MPE's row and VMAS's rows."""

    rows: list[Row]
    notes: list[str]
    mpe: Row | None
    vmas: list[Row]

    @property
    def best_vmas(self) -> float | None:
        """VMAS's best agent-steps/s (None: not timed)."""
        return max((r.agent_steps for r in self.vmas), default=None)


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    """The command line (module doc)."""
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument(
        "--out",
        default=os.path.join(tempfile.gettempdir(), "platoon_bench"),
        help="output directory (default: platoon_bench in the temporary directory)",
    )
    parser.add_argument("--seconds", type=float, default=1.5, help="timed seconds per number")
    parser.add_argument("--threads", type=int, default=2, help="numba threads (batched API)")
    parser.add_argument("--quick", action="store_true", help="a small smoke run")
    parser.add_argument("--no-mpe", action="store_true", help="skip MPE")
    parser.add_argument("--no-vmas", action="store_true", help="skip VMAS")
    parser.add_argument("--no-plot", action="store_true", help="skip the scaling plot")
    return parser.parse_args(argv)


def headline_rows(sizes: Sizes, mach: dict[str, Any], no_mpe: bool, no_vmas: bool) -> Headline:
    """MPE (in its own process), study A's ParallelEnv (with and without diagnostics, with
    ArUco sensors), the batched API at 1, 32 and ``big`` envs, and VMAS (own process)."""
    seconds, big, threads = sizes.seconds, sizes.big, sizes.threads
    headline: list[Row] = []
    notes: list[str] = []
    mpe_rate, mpe_note = (None, "skipped (--no-mpe)") if no_mpe else isolated(time_mpe, 7, seconds)
    mpe_row = None
    if mpe_rate is not None:
        mpe_row = Row("MPE simple_spread", "-", 0, 7, None, 1, mpe_rate, note=mpe_note)
        headline.append(mpe_row)
    notes.append(f"MPE: {mpe_note}")
    study_a = record_ppc_actions("study_a", sizes.record_steps)
    edges_a = int(platoon_env.make("study_a").scenario.workspace.edges.shape[0])
    aruco: dict[str, Any] = {"sensor_profile": "aruco"}
    for diagnostics, realism, suffix in (
        (True, {}, ""),
        (False, {}, ", diagnostics=False"),
        (True, aruco, ", aruco sensors"),
    ):
        env_rate = time_parallel_env(
            "study_a", study_a, seconds, diagnostics=diagnostics, **realism
        )
        what = f"platoon study_a, ParallelEnv (dicts){suffix}"
        headline.append(Row(what, "study_a", edges_a, 7, None, 1, env_rate))
        print(f"ParallelEnv study_a{suffix}: {_fmt(env_rate)} env-steps/s", flush=True)
    batched_runs: list[tuple[int, int, dict[str, Any]]] = [
        (b, th, {}) for b, th in dict.fromkeys([(1, 1), (32, 1), (big, 1), (big, threads)])
    ]
    batched_runs.append((big, threads, aruco))
    for batch, th, realism in batched_runs:
        if th > 1 and th > mach["numba_threads"]:
            continue
        suffix = ", aruco sensors" if realism else ""
        env_rate = time_batched("study_a", study_a, batch, th, seconds, **realism)
        what = f"platoon study_a, batched arrays{suffix}"
        headline.append(Row(what, "study_a", edges_a, 7, batch, th, env_rate))
        print(
            f"batched study_a B={batch} threads={th}: {_fmt(headline[-1].agent_steps)} "
            "agent-steps/s",
            flush=True,
        )
    vmas_rows: list[Row] = []
    if no_vmas:
        notes.append("VMAS: skipped (--no-vmas)")
    else:
        for th in sorted({1, threads}):
            vmas_rate, vmas_note = isolated(time_vmas, 7, big, th, seconds)
            if vmas_rate is None:
                notes.append(f"VMAS: {vmas_note}")
                break
            vmas_rows.append(Row("VMAS navigation (CPU)", "-", 0, 7, big, th, vmas_rate))
            notes.append(f"VMAS: {vmas_note}")
    headline.extend(vmas_rows)
    return Headline(headline, notes, mpe_row, vmas_rows)


def formation_rows(sizes: Sizes) -> list[Row]:
    """:data:`FORMATIONS` at ``big`` envs, physical and scale-free observations."""
    big, threads = sizes.big, sizes.threads
    formations: list[Row] = []
    scale_free = {"observation": {"task_aware": True, "scale_free": True}}
    for obs_opts, suffix in (({}, ""), (scale_free, ", scale-free observations")):
        env_rate, live, reset_ms, reset_cpu = time_formations(
            big, threads, sizes.seconds, **obs_opts
        )
        formations.append(
            Row(
                f"platoon {FORMATIONS}, batched arrays{suffix}",
                FORMATIONS,
                0,
                7,
                big,
                threads,
                env_rate,
                live=live,
                extra={"reset_ms_median": reset_ms, "reset_cpu_ms_median": reset_cpu},
            )
        )
        print(
            f"formations B={big} threads={threads}{suffix}: "
            f"{_fmt(formations[-1].agent_steps)} agent-steps/s (mean {live:.2f} live "
            f"followers), reset {reset_ms:.1f} ms median ({reset_cpu:.1f} ms CPU)",
            flush=True,
        )
    return formations


def scaling_rows(sizes: Sizes) -> list[Row]:
    """The pillar-lane maps of every edge count and number of followers: the ParallelEnv,
    the batched API at every batch size, and at 32 envs without edge culling."""
    seconds, threads, batches = sizes.seconds, sizes.threads, sizes.batches
    scaling: list[Row] = []
    for n_edges in sizes.edge_counts:
        for n in sizes.followers:
            scenario = platoon_env.load_scenario(pillar_lane(n_edges, n))
            edges = int(scenario.workspace.edges.shape[0])
            acts = record_ppc_actions(scenario, sizes.record_steps)
            env_rate = time_parallel_env(scenario, acts, seconds)
            scaling.append(Row("ParallelEnv", scenario.name, edges, n, None, 1, env_rate))
            for batch in batches:
                th = 1 if batch == 1 else threads
                env_rate = time_batched(scenario, acts, batch, th, seconds)
                scaling.append(Row("batched", scenario.name, edges, n, batch, th, env_rate))
            env_rate = time_batched(scenario, acts, 32, threads, seconds, grid_cell_size=0.0)
            scaling.append(
                Row("batched", scenario.name, edges, n, 32, threads, env_rate, culling=False)
            )
            print(
                f"map {edges} edges, N={n}: "
                + ", ".join(
                    f"{r.batch or 'PZ'}{'' if r.culling else '/nocull'}={_fmt(r.agent_steps)}"
                    for r in scaling[-len(batches) - 2 :]
                ),
                flush=True,
            )
    return scaling


def report(
    mach: dict[str, Any],
    headline: Headline,
    scaling: list[Row],
    formations: list[Row],
    ppc: list[tuple[float, int]],
) -> str:
    """``results.md``: the machine, then the headline, scaling, formations and PPC tables."""
    mpe_rate_or_none = headline.mpe.env_steps if headline.mpe else None
    md = [
        "## Speed (benchmarks/run.py)",
        "",
        "Machine: "
        + ", ".join(f"{k} {v}" for k, v in mach.items() if k != "load_average")
        + (f"; load average at start {mach['load_average']}" if "load_average" in mach else ""),
        "",
        headline_table(headline.rows, mpe_rate_or_none, headline.best_vmas),
        "",
        *[f"- {n}" for n in headline.notes],
        "",
        "Scaling with map size, followers and batch size (synthetic pillar-lane maps; the "
        "ParallelEnv row is one env with PettingZoo dicts):",
        "",
        scaling_table(scaling),
        "",
        "Every formation (`procedural_formations_train`, each env its own layout and "
        "formation; agent-steps count live followers only):",
        "",
        formations_table(formations),
        "",
        "PPC policy (`baselines.PPCPolicy.act`): "
        + "; ".join(f"{us:.2f} µs per follower (N = {n})" for us, n in ppc),
        "",
    ]
    return "\n".join(md)


def main(argv: list[str] | None = None) -> int:
    """Time everything (module doc), print the tables and write them to ``--out``."""
    args = parse_args(argv)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    sizes = Sizes.of(args)

    mach = machine()
    print("machine: " + ", ".join(f"{k}={v}" for k, v in mach.items()), flush=True)
    headline = headline_rows(sizes, mach, args.no_mpe, args.no_vmas)
    formations = formation_rows(sizes)
    scaling = scaling_rows(sizes)
    ppc = [time_ppc("study_a", sizes.seconds)]
    if not sizes.quick:
        ppc.append(time_ppc(pillar_lane(200, 50), sizes.seconds))

    text = report(mach, headline, scaling, formations, ppc)
    print()
    print(text)
    (out / "results.md").write_text(text)
    (out / "results.json").write_text(
        json.dumps(
            {
                "machine": mach,
                "notes": headline.notes,
                "headline": [asdict(r) | {"agent_steps": r.agent_steps} for r in headline.rows],
                "scaling": [asdict(r) | {"agent_steps": r.agent_steps} for r in scaling],
                "formations": [asdict(r) | {"agent_steps": r.agent_steps} for r in formations],
                "ppc_us_per_follower": [{"n": n, "us": us} for us, n in ppc],
            },
            indent=1,
        )
    )
    if not args.no_plot:
        plot(scaling, headline.mpe, headline.vmas, out / "scaling.png")
    print(f"\nwrote {out / 'results.md'}, results.json" + ("" if args.no_plot else ", scaling.png"))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
