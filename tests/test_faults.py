"""The fault family (hardening round 4, item 7; ``pytest -m faults``, run by CI as a job of its
own: ``scripts/test_faults.sh``): a ``platoon-sweep`` parent stopped by SIGTERM, SIGINT or
SIGKILL leaves no training behind and no run its next sweep would find "in use"; a store on a
full disk fails with one clear error and stays readable, and the re-run completes it. (kill -9
of an evaluator and its resume: ``tests/test_evaluate_crash.py::test_kill_9_then_resume``.)"""

from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import pytest

pytestmark = [
    pytest.mark.faults,
    pytest.mark.skipif(
        not sys.platform.startswith("linux"), reason="reads /proc to find the processes"
    ),
]

REPO = Path(__file__).resolve().parents[1]


def _stat(pid: int) -> list[str] | None:
    """The fields of /proc/PID/stat after the command name (None: no such process)."""
    try:
        return Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    except OSError:
        return None


def _alive(pid: int) -> bool:
    fields = _stat(pid)
    return fields is not None and fields[0] != "Z"


def _children(pid: int) -> list[int]:
    return [
        int(p.parent.name)
        for p in Path("/proc").glob("[0-9]*/stat")
        if (fields := _stat(int(p.parent.name))) is not None and int(fields[1]) == pid
    ]


def _naming(text: str) -> list[int]:
    """The live processes whose command line contains ``text``."""
    found = []
    for cmdline in Path("/proc").glob("[0-9]*/cmdline"):
        try:
            args = cmdline.read_bytes().replace(b"\0", b" ").decode(errors="replace")
        except OSError:
            continue
        if text in args and _alive(int(cmdline.parent.name)):
            found.append(int(cmdline.parent.name))
    return found


# ----------------------------------------------------------------------------------------------
# The sweep's trainings die with it
# ----------------------------------------------------------------------------------------------
#: Two trainings of a shipped configuration at once (each far longer than the test waits).
SWEEP = [sys.executable, "-m", "experiments.studies.sweep", "--config", "ppo_ta_aruco"]
SWEEP += ["--seeds", "0", "1", "--jobs", "2"]


@pytest.mark.parametrize(
    "sig", [signal.SIGTERM, signal.SIGINT, signal.SIGKILL], ids=lambda s: signal.Signals(s).name
)
def test_a_stopped_sweep_leaves_no_training_and_no_run_in_use(tmp_path: Path, sig: int) -> None:
    """A real platoon-sweep with two trainings under way: SIGTERM or SIGINT stops and reaps
    them (exit 130), SIGKILL of the sweep takes them down too (PR_SET_PDEATHSIG); either way no
    process of the sweep is left, and each run's folder is free for the next sweep (not "in
    use"), which continues it."""
    from training.run import LOCK_FILE, hold_run, run_status

    runs = tmp_path / "runs"
    sweep = subprocess.Popen(
        [*SWEEP, "--runs", str(runs)],
        cwd=REPO,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env={**os.environ, "MPLBACKEND": "Agg"},
        # a test runner may ignore SIGINT, and children inherit that
        preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL),
    )
    folders = [runs / "ppo_ta_aruco" / f"s{seed}" for seed in (0, 1)]
    try:
        deadline = time.monotonic() + 300
        # both trainings hold their folders (started, not just forked)
        while not all((f / LOCK_FILE).is_file() for f in folders):
            assert sweep.poll() is None, sweep.communicate()[1][-3000:]
            assert time.monotonic() < deadline, "the trainings never started"
            time.sleep(0.2)
        trainings = _children(sweep.pid)
        assert len(trainings) == 2, trainings
        sweep.send_signal(sig)
        stdout, stderr = sweep.communicate(timeout=120)
    finally:
        if sweep.poll() is None:
            sweep.kill()
            sweep.communicate()
    if sig == signal.SIGKILL:
        assert sweep.returncode == -signal.SIGKILL
    else:
        assert sweep.returncode == 130, stderr[-3000:]
        assert "interrupted: 2 training(s) stopped; re-run to resume them" in stdout
        assert "Traceback" not in stderr
    deadline = time.monotonic() + 60
    while any(_alive(pid) for pid in trainings) or _naming(str(runs)):
        assert time.monotonic() < deadline, f"orphaned trainings: {_naming(str(runs))}"
        time.sleep(0.2)
    for folder in folders:
        assert run_status(folder).state != "running"
        with hold_run(folder):  # what the next sweep's training takes first: free
            pass


# ----------------------------------------------------------------------------------------------
# A full disk
# ----------------------------------------------------------------------------------------------
def _unshare() -> list[str]:
    """The command that runs a shell in a mount namespace of its own, where mounting a tmpfs
    touches nothing outside it (as root; otherwise as root of a new user namespace)."""
    cmd = ["unshare", "--mount"]
    return cmd if os.geteuid() == 0 else [*cmd, "--map-root-user"]


def _tmpfs_or_skip(probe: Path) -> None:
    if shutil.which("unshare") is None:
        pytest.skip("needs unshare(1) to mount a small tmpfs in a mount namespace")
    probe.mkdir()
    got = subprocess.run(
        [*_unshare(), "sh", "-c", f"mount -t tmpfs -o size=64k tmpfs '{probe}'"],
        capture_output=True,
        text=True,
        timeout=60,
    )
    if got.returncode != 0:
        pytest.skip(
            "needs root (or unprivileged user namespaces) to mount a small tmpfs: "
            + (got.stderr.strip() or f"exit {got.returncode}")
        )


#: Run inside the namespace, on a 2 MiB tmpfs at argv[1]; prints one JSON line of findings.
FULL_DISK = textwrap.dedent(
    """
    import json, math, subprocess, sys
    from pathlib import Path

    from experiments.store import EPISODE_METRICS, EpisodeKey, Store, StoreError

    disk = Path(sys.argv[1])
    report = {}


    def fill():
        with open(disk / "filler", "wb", buffering=0) as f:
            try:
                while True:
                    f.write(b"x" * 4096)
            except OSError:
                pass


    # 1. A write on a full disk: one StoreError; what was written before stays readable.
    key = EpisodeKey("a" * 64, "b" * 64, "c" * 64, 0, "platoon_env.rollout:episode_metrics")
    metrics = {f: (2 if k == "count" else 1.5) for f, k in EPISODE_METRICS.items()}
    metrics.update(success=True, leader_arrived=True, violation="", time_to_violation=math.inf)
    path = disk / "api.sqlite"
    store = Store(path)
    store.register({key.policy: ("ppc", {})}, {key.scenario: {}}, {key.overrides: {}})
    run = store.begin_run("test", {"tool": "test"})
    keys = [key._replace(seed=s) for s in range(50)]
    store.claim(keys, run, {k: ("ppc", "study_c") for k in keys})
    store.record(keys[0], run, "done", metrics=metrics, names=("ppc", "study_c"))
    fill()
    try:
        for k in keys[1:]:
            store.record(k, run, "failed", error="x" * 200_000, names=("ppc", "study_c"))
        report["write"] = None
    except StoreError as exc:
        report["write"] = str(exc)
    except Exception as exc:
        report["write"] = f"not a StoreError: {type(exc).__name__}: {exc}"
    store.close()
    (disk / "filler").unlink()
    with Store(path) as again:
        rows = again.episodes()
        report["kept"] = rows[keys[0]].metrics == metrics and rows[keys[0]].status == "done"
    path.unlink()

    # 2. platoon-evaluate into a store on a full disk: one line, exit non-zero; the re-run on
    # a disk with room runs each missing episode once.
    grid = [sys.executable, "-m", "experiments.studies.evaluate", "--policy", "ppc",
            "--scenario", "study_c", "--set", "max_episode_steps=300", "--no-plots",
            "--workers", "1", "--out", str(disk / "eval")]

    def evaluate(episodes):
        got = subprocess.run([*grid, "--episodes", str(episodes)], capture_output=True,
                             text=True)
        return {"rc": got.returncode, "stdout": got.stdout[-2000:], "stderr": got.stderr[-2000:]}

    report["first"] = evaluate(3)
    fill()
    report["full"] = evaluate(6)
    (disk / "filler").unlink()
    report["again"] = evaluate(6)
    with Store(disk / "eval" / "results.sqlite") as store:
        report["seeds"] = sorted(k.seed for k in store.episodes())
        report["statuses"] = sorted({r.status for r in store.episodes().values()})
    print(json.dumps(report))
    """
)


def test_a_full_disk_fails_one_write_with_one_error_and_the_store_stays_readable(
    tmp_path: Path,
) -> None:
    _tmpfs_or_skip(tmp_path / "probe")
    disk = tmp_path / "disk"
    disk.mkdir()
    script = tmp_path / "full_disk.py"
    script.write_text(FULL_DISK)
    # sh -c SCRIPT sh DISK PYTHON FILE: $1 is the disk, $2 and $3 the command run on it
    mount = 'mount -t tmpfs -o size=2m tmpfs "$1" && exec "$2" "$3" "$1"'
    got = subprocess.run(
        [*_unshare(), "sh", "-c", mount, "sh", str(disk), sys.executable, str(script)],
        cwd=REPO,
        capture_output=True,
        text=True,
        timeout=600,
        env={**os.environ, "MPLBACKEND": "Agg", "PYTHONPATH": str(REPO)},
    )
    assert got.returncode == 0, got.stderr[-3000:]
    report = json.loads(got.stdout.strip().splitlines()[-1])
    # the write: one StoreError naming the store and the reason, on one line
    write = report["write"]
    assert write is not None and write.startswith(f"{disk}/api.sqlite: "), write
    assert "full" in write and "\n" not in write, write
    assert report["kept"] is True
    # the command: one line naming the store and what to check, no traceback, nothing stored
    assert report["first"]["rc"] == 0, report["first"]
    full = report["full"]
    assert full["rc"] != 0 and "Traceback" not in full["stderr"], full
    (line,) = full["stderr"].strip().splitlines()
    assert line.startswith(f"platoon-evaluate: error: {disk}/eval/results.sqlite: "), line
    assert "full" in line and "not an evaluation store" not in line, line
    # the re-run with room: the three missing episodes, each stored once
    again = report["again"]
    assert again["rc"] == 0, again
    assert "3 episode(s) run, 3 already in the store" in again["stdout"], again
    assert report["seeds"] == list(range(6)) and report["statuses"] == ["done"]
