#!/usr/bin/env bash
# Set up ./.venv-rllib (the [rllib] extra: Ray RLlib 2.60, which pins gymnasium==1.2.2, so it
# gets its own venv), run the RLlib tests in it (extra arguments go to pytest), then train once
# on a two-node Ray cluster started on this machine (RLLIB_PYTEST=0 skips the tests,
# RLLIB_CLUSTER=0 the cluster run).
# scripts/setup.sh names torch==2.13.0 in the same pip command as ray: any other torch request pulls a
# multi-GB CUDA build.
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh .venv-rllib train,plot,dev,rllib
export MPLBACKEND=Agg
# Ray must not join a cluster that happens to run on this machine.
unset RAY_ADDRESS
if [ "${RLLIB_PYTEST:-1}" != "0" ]; then
  echo "== pytest (rllib)"
  .venv-rllib/bin/python -m pytest -p no:cacheprovider tests/test_rllib.py tests/test_examples.py::test_rllib_example "$@"
fi

if [ "${RLLIB_CLUSTER:-1}" = "0" ]; then
  exit 0
fi
# ------------------------------------------------------------------------------------------
# The multi-node path (docs/rllib.md, "On a cluster"): a Ray head (`ray start --head`) and a
# second node (`ray start --address`) on this machine, one CPU each, and one short
# `platoon-train --engine rllib --address` run whose two env runners (one CPU each) must land
# one on each node. The check reads model.json's "ray" entry: two alive nodes, a runner on
# each that took env steps, and platoon_env imported from the runtime env's copy that Ray
# shipped (not from this checkout), i.e. the nodes needed no install of the project.
# Each node runs `ray start --block` in its own process group (setsid), which is stopped by
# its id on exit, also when a step fails; `ray stop` is not used: it stops every Ray process
# on the machine, other people's too.
echo "== two-node Ray cluster"
RAY=.venv-rllib/bin/ray
cluster=$(mktemp -d /tmp/platoon-rllib-cluster.XXXXXX)
node_pids=()
stop_cluster() {
  local status=$?
  # The second node first, then the head: each `ray start --block` gets SIGTERM (it drains
  # its node and stops the processes it started); its process group is killed after 45 s.
  local i pid
  for ((i = ${#node_pids[@]} - 1; i >= 0; i--)); do
    pid=${node_pids[i]}
    kill -TERM "$pid" 2>/dev/null || true
    for _ in $(seq 1 45); do
      kill -0 -- "-$pid" 2>/dev/null || break
      sleep 1
    done
    kill -KILL -- "-$pid" 2>/dev/null || true
  done
  if [ "$status" -ne 0 ]; then
    echo "two-node cluster step failed (status $status); node logs:" >&2
    tail -n 40 "$cluster"/*.log >&2 || true
  fi
  rm -rf "$cluster"
  exit "$status"
}
trap stop_cluster EXIT
free_port() {
  .venv-rllib/bin/python -c 'import socket; s = socket.socket(); s.bind(("127.0.0.1", 0)); print(s.getsockname()[1])'
}
# Ray 2.60 starts clusters with token authentication; this cluster gets its own token (not
# ~/.ray/auth_token), and a driver given an explicit address must opt in to token mode.
.venv-rllib/bin/python -c 'import secrets; print(secrets.token_hex(32))' >"$cluster/auth_token"
export RAY_AUTH_MODE=token RAY_AUTH_TOKEN_PATH="$cluster/auth_token"
port=$(free_port)
head="127.0.0.1:$port"
# Two nodes on one machine: every fixed default port (client server, dashboard agent) is set.
setsid "$RAY" start --head --block --node-ip-address=127.0.0.1 --port="$port" --num-cpus=1 \
  --include-dashboard=false --disable-usage-stats --temp-dir="$cluster/head" \
  --ray-client-server-port="$(free_port)" --dashboard-agent-listen-port="$(free_port)" \
  >"$cluster/head.log" 2>&1 &
node_pids+=($!)
wait_for_nodes() {  # wait_for_nodes N: until the cluster has N alive nodes (at most 180 s)
  .venv-rllib/bin/python - "$head" "$1" <<'EOF'
import sys
import time

import ray

address, want = sys.argv[1], int(sys.argv[2])
deadline = time.monotonic() + 180
while True:
    try:
        ray.init(address=address, log_to_driver=False)
        alive = [n for n in ray.nodes() if n["Alive"]]
        ray.shutdown()
    except Exception as e:  # the head is not up yet
        alive, error = [], e
    else:
        error = None
    if len(alive) >= want:
        print(f"{len(alive)} alive node(s) at {address}")
        break
    if time.monotonic() > deadline:
        sys.exit(f"{address}: {len(alive)} alive node(s) after 180 s, want {want} ({error})")
    time.sleep(2)
EOF
}
wait_for_nodes 1
setsid "$RAY" start --block --address="$head" --node-ip-address=127.0.0.1 --num-cpus=1 \
  --disable-usage-stats --temp-dir="$cluster/node2" \
  --dashboard-agent-listen-port="$(free_port)" >"$cluster/node2.log" 2>&1 &
node_pids+=($!)
wait_for_nodes 2
# The driver runs outside the checkout: Ray puts the driver's working directory on every
# worker's sys.path, which on this machine would hand the workers the checkout instead of the
# copy the runtime env ships.
mkdir "$cluster/driver"
(cd "$cluster/driver" && "$OLDPWD/.venv-rllib/bin/platoon-train" --engine rllib \
  --address "$head" --num-env-runners 2 --n-envs 1 --n-steps 64 --batch-size 128 \
  --n-epochs 1 --timesteps 512 --log-every 128 --checkpoint-every 0 --no-progress-bar \
  --seed 0 --out "$cluster/run")
.venv-rllib/bin/python - "$cluster/run" <<'EOF'
import json
import sys
from pathlib import Path

run = Path(sys.argv[1])
meta = json.loads((run / "model.json").read_text())
ray_info = meta["ray"]
nodes = ray_info["nodes_alive"]
runners = ray_info["env_runners"]
problems = []
if len(nodes) != 2:
    problems.append(f"{len(nodes)} alive nodes, want 2")
if sorted(r["worker_index"] for r in runners) != [1, 2]:
    problems.append(f"env runners {[r['worker_index'] for r in runners]}, want [1, 2]")
if len({r["node_id"] for r in runners}) != 2 or {r["node_id"] for r in runners} != set(nodes):
    problems.append("the two env runners did not run one on each node")
if not all(r["env_steps"] > 0 for r in runners):
    problems.append(f"an env runner took no env steps: {runners}")
shipped = [r["platoon_env"] for r in runners]
if not all("runtime_resources" in p for p in shipped):
    problems.append(f"platoon_env not imported from the runtime env's copy: {shipped}")
rows = (run / "progress.csv").read_text().splitlines()
if len(rows) < 2:
    problems.append("progress.csv has no row")
if problems:
    sys.exit("two-node run: " + "; ".join(problems))
steps = ", ".join(f"runner {r['worker_index']}: {r['env_steps']} env steps" for r in runners)
print(f"two-node run: {meta['timesteps']} timesteps on 2 nodes ({steps}); code shipped")
EOF
