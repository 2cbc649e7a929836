"""The published per-episode rows of the default benchmark, and a user's policy ranked against them.

``platoon-evaluate`` with no arguments runs the analytic laws and every shipped configuration on
the paper's three studies (``experiments/studies/evaluate.py``). Its rows, one per episode, are
shipped as :data:`PUBLISHED` (a compact JSON file: policy, configuration, scenario, seed and a
few metrics per row), written by :func:`write_published` from a run at one clean commit. A
researcher then compares their own policy with every entry without re-running any of them::

    platoon-evaluate --policy mine=my_policy:MyPolicy --compare-to published

runs only ``mine`` on the published scenarios and seeds and writes ``OUT/comparison.md``
(:func:`comparison_markdown`): per scenario, every entry's successes on the same seeds, the
difference with its paired test, and the rank the policy would take.

**Refused when it would not compare like with like** (:func:`check_compatible`): the file
records a digest of the sources that decide an episode (``platoon_env``, ``baselines``,
``training``: :func:`code_fingerprint`) and each scenario's fingerprint; other code, or a
scenario that resolves differently, is an error naming what differs, never a silent comparison.

**The test.** Each entry plays the same seeds as the user's policy (a configuration's training
seeds share them, one episode each), so the outcomes are paired by seed. Per scenario and entry
the two-sided exact McNemar test (a binomial test on the discordant seeds: those one policy
succeeds on and the other fails) gives a p-value; Holm's correction runs over every entry and
scenario of one user policy (the family the rank is read from).
"""

from __future__ import annotations

import json
import math
from collections import defaultdict
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from experiments.report import write_text_atomic
from experiments.significance import holm, mcnemar_exact, wilson

__all__ = [
    "FORMAT",
    "PUBLISHED",
    "PublishedError",
    "PublishedRows",
    "check_compatible",
    "code_fingerprint",
    "comparison_markdown",
    "load_published",
    "mcnemar_exact",
    "write_published",
]

#: The shipped rows of the default benchmark.
PUBLISHED = Path(__file__).resolve().parent / "data" / "published_benchmark.json"
#: The file's ``format`` field.
FORMAT = "platoon_env.published_rows"
_VERSION = 1
#: The per-episode fields kept (beside policy, configuration, training seed, scenario, seed).
FIELDS: tuple[str, ...] = (
    "success",
    "violation",
    "time_to_violation",
    "sim_time",
    "rms_e_d",
    "min_obstacle_clearance",
)
#: The packages whose sources decide an episode's outcome.
_PACKAGES: tuple[str, ...] = ("platoon_env", "baselines", "training")


class PublishedError(ValueError):
    """The published rows cannot be used: a malformed file, or rows made by other code or of
    other scenarios than this run's."""


def code_fingerprint() -> str:
    """A SHA-256 of every ``.py`` file (relative path and content) of the packages that decide
    an episode (:data:`_PACKAGES`): equal fingerprints, the same simulator, laws and models'
    forward pass."""
    from platoon_env._numba_cache import source_digest

    root = Path(__file__).resolve().parents[1]
    dirs = [root / name for name in _PACKAGES]
    return source_digest(dirs[0], *dirs[1:])


@dataclass(frozen=True)
class PublishedRows:
    """The contents of a published file: ``rows`` (dicts with ``policy``, ``configuration``,
    ``training_seed``, ``scenario``, ``seed`` and :data:`FIELDS`), the ``code`` fingerprint, each
    scenario's fingerprint (``scenarios``), the seeds, and where it came from (``made``)."""

    rows: tuple[dict[str, Any], ...]
    code: str
    scenarios: dict[str, str]
    seeds: tuple[int, ...]
    made: dict[str, Any]

    def entries(self) -> list[str]:
        """The configurations (an analytic law is one), in the file's order."""
        return list(dict.fromkeys(r["configuration"] for r in self.rows))


def _success(value: Any) -> bool:
    return str(value).strip().lower() in ("true", "1")


def _number(value: Any) -> float | None:
    try:
        x = float(value)
    except (TypeError, ValueError):
        return None
    return x if math.isfinite(x) else None


def write_published(
    rows: Iterable[Mapping[str, Any]],
    path: Path = PUBLISHED,
    made: Mapping[str, Any] | None = None,
) -> Path:
    """Write the default benchmark's ``rows`` (``results.csv`` rows of a finished run, status
    ``done``) to ``path`` with this checkout's :func:`code_fingerprint` (atomically: a
    temporary file renamed into place). A row that is not done, or rows mixing two scenario
    fingerprints for the analytic laws of one scenario, are a :class:`PublishedError`."""
    kept: list[dict[str, Any]] = []
    scenarios: dict[str, str] = {}
    for r in rows:
        if r.get("status") != "done":
            raise PublishedError(
                f"row {r.get('policy')}/{r.get('scenario')}/{r.get('seed')} is "
                f"{r.get('status')!r}, not done: publish a finished run"
            )
        if not str(r.get("training_seed", "")).strip():  # an analytic law: the plain scenario
            seen = scenarios.setdefault(r["scenario"], r["scenario_fingerprint"])
            if seen != r["scenario_fingerprint"]:
                raise PublishedError(f"{r['scenario']}: two scenario fingerprints among the laws")
        seed = str(r.get("training_seed", "")).strip()
        kept.append(
            {
                "policy": r["policy"],
                "configuration": r["configuration"],
                "training_seed": int(seed) if seed else None,
                "scenario": r["scenario"],
                "seed": int(r["seed"]),
                "success": _success(r["success"]),
                "violation": r.get("violation") or "",
                **{k: _number(r.get(k)) for k in FIELDS if k not in ("success", "violation")},
            }
        )
    if not kept:
        raise PublishedError("no rows to publish")
    document = {
        "format": FORMAT,
        "version": _VERSION,
        "code": code_fingerprint(),
        "made": dict(made or {}),
        "scenarios": scenarios,
        "seeds": sorted({r["seed"] for r in kept}),
        "rows": kept,
    }
    text = json.dumps(document, indent=None, separators=(",", ":"), allow_nan=False)
    return write_text_atomic(path, text + "\n")


def load_published(path: Path = PUBLISHED) -> PublishedRows:
    """Read a published file; anything malformed is a :class:`PublishedError` naming the file
    and the field."""
    try:
        document = json.loads(Path(path).read_text(encoding="utf-8"))
    except (OSError, ValueError) as exc:
        raise PublishedError(f"{path}: not a readable published-rows file ({exc})") from None
    if not isinstance(document, dict) or document.get("format") != FORMAT:
        raise PublishedError(f"{path}: not a published-rows file (format is not {FORMAT!r})")
    if document.get("version") != _VERSION:
        raise PublishedError(f"{path}: version {document.get('version')!r}, expected {_VERSION}")
    rows = document.get("rows")
    if not isinstance(rows, list) or not rows:
        raise PublishedError(f"{path}: 'rows' must be a non-empty list")
    need = {"policy", "configuration", "training_seed", "scenario", "seed", *FIELDS}
    for i, r in enumerate(rows):
        if not isinstance(r, dict) or not need <= set(r):
            raise PublishedError(f"{path}: row {i} lacks {sorted(need - set(r or {}))}")
        if not isinstance(r["seed"], int) or not isinstance(r["success"], bool):
            raise PublishedError(f"{path}: row {i}: seed must be an integer, success a boolean")
    scenarios = document.get("scenarios")
    if not isinstance(scenarios, dict) or not all(isinstance(v, str) for v in scenarios.values()):
        raise PublishedError(f"{path}: 'scenarios' must map names to fingerprints")
    code = document.get("code")
    if not isinstance(code, str):
        raise PublishedError(f"{path}: 'code' must be a fingerprint")
    made = document.get("made") if isinstance(document.get("made"), dict) else {}
    seeds = tuple(sorted({r["seed"] for r in rows}))
    return PublishedRows(tuple(rows), code, dict(scenarios), seeds, dict(made or {}))


def check_compatible(
    published: PublishedRows, scenarios: Mapping[str, str], seeds: Iterable[int]
) -> None:
    """A :class:`PublishedError` unless this checkout's code is the published rows' and each of
    ``scenarios`` (name → the run's resolved fingerprint) and ``seeds`` is among them."""
    here = code_fingerprint()
    if here != published.code:
        commit = published.made.get("commit", "an unknown commit")
        raise PublishedError(
            f"the published rows were made by other code (commit {commit}; the sources of "
            f"{', '.join(_PACKAGES)} differ: fingerprint {published.code[:12]}, here "
            f"{here[:12]}): they cannot be compared with this run. Evaluate the baselines "
            "beside your policy instead (platoon-evaluate --policy ppc --policy mine=...)"
        )
    for name, fingerprint in scenarios.items():
        if name not in published.scenarios:
            raise PublishedError(
                f"scenario {name!r} is not in the published rows (they have "
                f"{', '.join(published.scenarios)})"
            )
        if published.scenarios[name] != fingerprint:
            raise PublishedError(
                f"scenario {name!r} resolves to another fingerprint here "
                f"({fingerprint[:12]}) than in the published rows "
                f"({published.scenarios[name][:12]}): other options or scenario files"
            )
    missing = sorted(set(seeds) - set(published.seeds))
    if missing:
        raise PublishedError(
            f"seeds {missing[:5]}{'...' if len(missing) > 5 else ''} are not in the published "
            f"rows (seeds {published.seeds[0]}..{published.seeds[-1]})"
        )


def comparison_markdown(
    user_rows: Sequence[Mapping[str, Any]], published: PublishedRows
) -> tuple[str, dict[str, int]]:
    """The ``comparison.md`` of the user's policies' rows (``results.csv`` rows) against the
    published rows on the same scenarios and seeds, and each user policy's rank (1 = first)
    among the published entries by mean success over the scenarios."""
    by_entry: dict[tuple[str, str], dict[int, bool]] = defaultdict(dict)
    for r in published.rows:
        by_entry[(r["configuration"], r["scenario"])][r["seed"]] = r["success"]
    users: dict[str, dict[str, dict[int, bool]]] = defaultdict(lambda: defaultdict(dict))
    for row in user_rows:
        if row.get("status") == "done":
            outcome = _success(row["success"])
            users[str(row["policy"])][str(row["scenario"])][int(row["seed"])] = outcome
    entries = published.entries()
    lines = [
        "# Against the published benchmark",
        "",
        f"Published rows: {len(published.rows)} episodes, made {published.made.get('date', '?')}"
        f" at commit {published.made.get('commit', '?')}; code fingerprint "
        f"`{published.code[:12]}` (this checkout's). Each entry played the same seeds as "
        "the policy below (a configuration's training seeds sharing them), so outcomes are "
        "paired by seed: Δ is the policy's success rate minus the entry's, p the two-sided "
        "exact McNemar test, p_Holm adjusted over every entry and scenario of the policy.",
        "",
    ]
    ranks: dict[str, int] = {}
    for name, scenarios in users.items():
        tests: list[tuple[str, str, int, int, int, int, float]] = []
        means: dict[str, list[float]] = defaultdict(list)
        mine: list[float] = []
        for scenario, outcomes in scenarios.items():
            seeds = sorted(outcomes)
            mine.append(sum(outcomes[s] for s in seeds) / len(seeds))
            for entry in entries:
                theirs = by_entry.get((entry, scenario), {})
                if not all(s in theirs for s in seeds):
                    continue
                b = sum(1 for s in seeds if outcomes[s] and not theirs[s])
                c = sum(1 for s in seeds if theirs[s] and not outcomes[s])
                k_mine = sum(outcomes[s] for s in seeds)
                k_theirs = sum(theirs[s] for s in seeds)
                means[entry].append(k_theirs / len(seeds))
                tests.append((scenario, entry, k_mine, k_theirs, len(seeds), b - c,
                              mcnemar_exact(b, c)))  # fmt: skip
        adjusted = holm([t[6] for t in tests]) if tests else []
        full = {e: sum(v) / len(v) for e, v in means.items() if len(v) == len(scenarios)}
        score = sum(mine) / len(mine) if mine else 0.0
        rank = 1 + sum(1 for v in full.values() if v > score)
        ranks[name] = rank
        lines += [
            f"## {name}",
            "",
            f"Mean success over {len(scenarios)} scenario(s): {score:.3f}; rank {rank} of "
            f"{len(full) + 1} (ties share the better rank).",
            "",
            "| rank | entry | mean success |",
            "|---:|---|---:|",
        ]
        table = sorted([*full.items(), (f"**{name}**", score)], key=lambda kv: -kv[1])
        lines += [f"| {1 + sum(1 for _, v in table if v > s)} | {e} | {s:.3f} |" for e, s in table]
        lines += [
            "",
            f"| scenario | entry | {name} | entry's | Δ | p | p_Holm | verdict |",
            "|---|---|---:|---:|---:|---:|---:|---|",
        ]
        for (scenario, entry, k1, k2, n, diff, p), q in zip(tests, adjusted, strict=True):
            lo, hi = wilson(k1, n)
            verdict = "n.s." if q >= 0.05 else (name if diff > 0 else entry)
            lines.append(
                f"| {scenario} | {entry} | {k1}/{n} [{lo:.2f}, {hi:.2f}] | {k2}/{n} | "
                f"{(k1 - k2) / n:+.2f} | {p:.3g} | {q:.3g} | {verdict} |"
            )
        lines.append("")
    return "\n".join(lines), ranks
