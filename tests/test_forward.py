"""The row-invariant forward pass (:mod:`training.forward`) and the batched learned-policy hook
(:meth:`training.LearnedPolicy.act_group`): a row's output is the same to the bit whatever the
batch it is computed in, and ``act_group`` gives each policy exactly what its ``act`` gives."""

from __future__ import annotations

import copy
import itertools
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("stable_baselines3")
import torch

from training import LearnedPolicy
from training.forward import MLPForward, sb3_forward
from training.policies import MLPActor, fast_actor

REPO = Path(__file__).resolve().parents[1]


def random_layers(seed: int, sizes: tuple[int, ...], activation: str = "tanh") -> list:
    rng = np.random.default_rng(seed)
    layers = []
    for k, (n_in, n_out) in enumerate(itertools.pairwise(sizes)):
        act = activation if k < len(sizes) - 2 else "identity"
        layers.append((rng.normal(size=(n_out, n_in)), rng.normal(size=n_out), act))
    return layers


@pytest.mark.parametrize("activation", ["tanh", "relu", "identity"])
def test_rows_do_not_depend_on_the_batch(activation: str) -> None:
    forward = MLPForward(random_layers(0, (15, 64, 64, 2), activation))
    x = np.random.default_rng(1).normal(scale=3.0, size=(1000, 15)).astype(np.float32)
    whole = forward(x)
    assert whole.dtype == np.float32 and whole.shape == (1000, 2)
    alone = np.concatenate([forward(x[i : i + 1]) for i in range(len(x))])
    assert np.array_equal(whole, alone)
    for size in (2, 7, 33, 999):
        chunks = np.concatenate([forward(x[i : i + size]) for i in range(0, len(x), size)])
        assert np.array_equal(whole, chunks)
    order = np.random.default_rng(2).permutation(len(x))
    assert np.array_equal(forward(x[order]), whole[order])


@pytest.mark.parametrize("activation", ["tanh", "relu"])
def test_it_computes_the_mlp(activation: str) -> None:
    layers = random_layers(3, (5, 8, 3), activation)
    forward = MLPForward(layers)
    x = np.random.default_rng(4).normal(size=(6, 5))
    h = x @ layers[0][0].T + layers[0][1]
    h = np.tanh(h) if activation == "tanh" else np.maximum(h, 0.0)
    expected = h @ layers[1][0].T + layers[1][1]
    np.testing.assert_allclose(forward(x), expected, rtol=1e-6, atol=1e-6)
    assert forward.input_dim == 5 and forward.output_dim == 3
    assert forward(np.zeros((0, 5))).shape == (0, 3)


def test_digest_deepcopy_and_bad_layers() -> None:
    forward = MLPForward(random_layers(0, (4, 3, 2)))
    assert copy.deepcopy(forward) is forward
    assert MLPForward(random_layers(0, (4, 3, 2))).digest == forward.digest
    assert MLPForward(random_layers(1, (4, 3, 2))).digest != forward.digest
    with pytest.raises(ValueError, match=r"shape \(B, 4\)"):
        forward(np.zeros((2, 5)))
    with pytest.raises(ValueError, match="at least one layer"):
        MLPForward([])
    w, b, _ = random_layers(0, (4, 3))[0]
    with pytest.raises(ValueError, match="do not match"):
        MLPForward([(w, b[:2], "identity")])
    with pytest.raises(ValueError, match="takes 5 inputs"):
        MLPForward([(w, b, "tanh"), (np.ones((2, 5)), np.ones(2), "identity")])
    with pytest.raises(ValueError, match="activation 'gelu'"):
        MLPForward([(w, b, "gelu")])
    with pytest.raises(ValueError, match="not finite"):
        MLPForward([(w * np.nan, b, "identity")])


def test_rllib_actor_computes_with_the_forward() -> None:
    layers = [
        (w.astype(np.float32), b.astype(np.float32)) for w, b, _ in random_layers(5, (7, 9, 2))
    ]
    actor = MLPActor(layers)
    x = np.random.default_rng(6).normal(size=(4, 7)).astype(np.float32)
    out, _ = actor.predict(x)
    h = np.tanh(x.astype(np.float64) @ layers[0][0].T.astype(np.float64) + layers[0][1])
    np.testing.assert_allclose(out, h @ layers[1][0].T + layers[1][1], rtol=1e-6, atol=1e-6)
    fast = fast_actor(actor)
    assert fast is not None and fast.forward is actor.forward


def _shipped(name: str, pickled: bool = False) -> LearnedPolicy:
    """A shipped model, weights-only (``load``) or with its SB3 object (``load_pickled``, to
    compare with SB3)."""
    path = REPO / "models" / name / "model.zip"
    if not path.is_file():
        pytest.skip(f"{name} is not in models/")
    return LearnedPolicy.load_pickled(path) if pickled else LearnedPolicy.load(path)


def test_sb3_forward_reads_a_shipped_actor() -> None:
    policy = _shipped("ppo_ta_aruco_s0", pickled=True)
    forward = sb3_forward(policy.model.policy)
    assert forward is not None
    x = np.random.default_rng(7).normal(size=(50, forward.input_dim)).astype(np.float32)
    with torch.no_grad():
        pi = policy.model.policy
        mean = pi.action_net(pi.mlp_extractor.forward_actor(torch.as_tensor(x))).numpy()
    np.testing.assert_allclose(forward(x), mean, rtol=1e-5, atol=1e-5)
    # what LearnedPolicy.load reads from the weights alone is that very network
    assert _shipped("ppo_ta_aruco_s0").model.forward.digest == forward.digest


@pytest.mark.parametrize("name", ["ppo_ta_aruco_s0", "residual_drive_aruco_s0"])
def test_act_group_is_each_act_to_the_bit(name: str) -> None:
    """Three copies of a shipped model on three envs (a residual's law is per copy): one
    ``act_group`` call per step gives what each copy's ``act`` gives, over an episode's start."""
    import platoon_env
    from experiments.policies import PolicySpec

    template = _shipped(name)
    overrides = PolicySpec.model(REPO / "models" / name).env_overrides()
    envs, grouped, alone, obs = [], [], [], []
    for seed in range(3):
        env = platoon_env.make("study_c", **overrides)
        o, _ = env.reset(seed=seed)
        for store in (grouped, alone):
            p = copy.deepcopy(template)
            p.bind(env)
            p.reset(seed=seed)
            store.append(p)
        envs.append(env)
        obs.append(o)
    for _ in range(40):
        together = LearnedPolicy.act_group(grouped, obs)
        for k in range(3):
            single = alone[k].act(obs[k])
            assert together[k].keys() == single.keys()
            for agent in single:
                assert np.array_equal(together[k][agent], single[agent])
        obs = [env.step(cmd)[0] for env, cmd in zip(envs, together, strict=True)]
        if not all(obs):
            break
    with pytest.raises(ValueError, match="one observation dict per policy"):
        LearnedPolicy.act_group(grouped, obs[:1])
