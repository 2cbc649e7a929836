#!/usr/bin/env bash
# Set up ./.venv-torchrl (the [torchrl] extra: TorchRL 0.14 and its tensordict, in their own
# venv beside the default one; [plot] because tests/conftest.py imports matplotlib) and run the
# TorchRL tests in it (PettingZooWrapper on the numeric info view, GymEnv on the Gymnasium ids,
# check_env_specs). Extra arguments go to pytest.
# scripts/setup.sh names torch==2.13.0 in the same pip command as torchrl: any other torch request pulls a
# multi-GB CUDA build.
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh .venv-torchrl plot,dev,torchrl
export MPLBACKEND=Agg
echo "== pytest (torchrl)"
.venv-torchrl/bin/python -m pytest -p no:cacheprovider tests/test_torchrl.py tests/test_gym_vector_wrappers.py::test_torchrl_gym_wrapper_route "$@"
