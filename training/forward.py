"""The deterministic forward pass of a learned policy's network, the same for any batch size.

A shipped model's actor is a small multilayer perceptron: ``y = W_L σ(... σ(W_0 x + b_0) ...)
+ b_L``. Evaluated with torch or a BLAS matrix product, the value of one row depends in its last
bits on how many rows are computed with it (the library picks other kernels, blockings and
summation orders for other shapes), so a batched evaluation gave other results than one episode
at a time. :class:`MLPForward` computes every row on its own, in one fixed order (each output
``b_j + Σ_k W_jk x_k`` summed left to right in float64, the activations of float64 values,
the result rounded once to float32), with one compiled kernel: row ``r`` of ``forward(x)`` is
the same to the bit whether ``x`` holds 1 row or 10,000 and wherever row ``r`` sits in it
(``tests/test_forward.py``). Against torch's float32 forward it differs by float32 rounding
(≤ a few ulp; float64 accumulation is the more accurate of the two).

:func:`sb3_forward` reads the actor of a Stable-Baselines3 actor-critic (PPO's ``MlpPolicy``:
the features extractor's flatten, ``mlp_extractor.policy_net``, ``action_net``) into an
:class:`MLPForward`; :class:`training.policies.MLPActor` (an RLlib-trained actor) computes with
one too. Both the one-episode path (:meth:`training.LearnedPolicy.act`) and the batched
evaluator's (:meth:`training.LearnedPolicy.act_group`, one call for every copy of a chunk) use
it, so results never depend on the chunk size.
"""

from __future__ import annotations

import hashlib
from collections.abc import Sequence
from typing import Any

import numpy as np
from numba import njit
from numpy.typing import NDArray

import training._numba_cache  # noqa: F401  (before the first kernel: the cache's directory)

__all__ = ["ACTIVATIONS", "MLPForward", "sb3_forward"]

#: The hidden layers' activations a forward computes, by name, and their codes in the kernel.
ACTIVATIONS: dict[str, int] = {"identity": 0, "tanh": 1, "relu": 2}


@njit(cache=True)
def _forward_rows(
    x: NDArray[np.float64],
    params: NDArray[np.float64],
    shapes: NDArray[np.int64],
    width: int,
    out: NDArray[np.float32],
) -> None:  # pragma: no cover - compiled; tested through MLPForward
    """``out[r] = mlp(x[r])`` for every row ``r``, each row alone in a fixed order.

    ``params`` holds each layer's weight (row-major, ``n_out × n_in``) then its bias; row ``l``
    of ``shapes`` is layer ``l``'s ``(n_out, n_in, activation code)``; ``width`` the widest
    layer."""
    a = np.empty(width)
    b = np.empty(width)
    for r in range(x.shape[0]):
        n = x.shape[1]
        for k in range(n):
            a[k] = x[r, k]
        offset = 0
        for layer in range(shapes.shape[0]):
            n_out = shapes[layer, 0]
            n_in = shapes[layer, 1]
            act = shapes[layer, 2]
            bias = offset + n_out * n_in
            for j in range(n_out):
                acc = params[bias + j]
                row = offset + j * n_in
                for k in range(n_in):
                    acc += params[row + k] * a[k]
                if act == 1:
                    acc = np.tanh(acc)
                elif act == 2 and acc < 0.0:
                    acc = 0.0
                b[j] = acc
            a, b = b, a
            offset = bias + n_out
            n = n_out
        for j in range(n):
            out[r, j] = a[j]


class MLPForward:
    """An MLP's deterministic forward pass whose rows do not depend on the batch (module doc).

    Args:
        layers: ``(W, b, activation)`` per layer, ``W`` of shape ``(n_out, n_in)``, ``b`` of
            ``(n_out,)``, ``activation`` a name of :data:`ACTIVATIONS` applied after the layer
            (``"identity"`` for the output layer).

    Immutable: a deep copy is the same object (copies of a policy share their network).
    """

    def __init__(self, layers: Sequence[tuple[NDArray[Any], NDArray[Any], str]]) -> None:
        if not layers:
            raise ValueError("an MLP needs at least one layer")
        chunks: list[NDArray[np.float64]] = []
        shapes: list[tuple[int, int, int]] = []
        for k, (w, b, activation) in enumerate(layers):
            w = np.asarray(w, dtype=np.float64)
            b = np.asarray(b, dtype=np.float64)
            if w.ndim != 2 or b.shape != (w.shape[0],):
                raise ValueError(f"layer {k}: weight {w.shape} and bias {b.shape} do not match")
            if shapes and w.shape[1] != shapes[-1][0]:
                raise ValueError(
                    f"layer {k} takes {w.shape[1]} inputs, layer {k - 1} gives {shapes[-1][0]}"
                )
            if activation not in ACTIVATIONS:
                raise ValueError(
                    f"layer {k}: activation {activation!r} is not one of {tuple(ACTIVATIONS)}"
                )
            if not (np.isfinite(w).all() and np.isfinite(b).all()):
                raise ValueError(f"layer {k}: weights or biases are not finite")
            chunks += [w.ravel(), b]
            shapes.append((int(w.shape[0]), int(w.shape[1]), ACTIVATIONS[activation]))
        self._params = np.ascontiguousarray(np.concatenate(chunks))
        self._params.setflags(write=False)
        self._shapes = np.array(shapes, dtype=np.int64)
        self._shapes.setflags(write=False)
        self._width = max(max(s[0], s[1]) for s in shapes)
        digest = hashlib.sha256(self._shapes.tobytes())
        digest.update(self._params.tobytes())
        #: Hex SHA-256 of the layers: two forwards with equal digests compute the same values.
        self.digest: str = digest.hexdigest()

    @property
    def input_dim(self) -> int:
        """Length of an input row."""
        return int(self._shapes[0, 1])

    @property
    def output_dim(self) -> int:
        """Length of an output row."""
        return int(self._shapes[-1, 0])

    def __call__(self, x: NDArray[Any]) -> NDArray[np.float32]:
        """The outputs ``(B, output_dim)`` (float32) of the inputs ``(B, input_dim)``."""
        rows = np.ascontiguousarray(x, dtype=np.float64)
        if rows.ndim != 2 or rows.shape[1] != self.input_dim:
            raise ValueError(f"inputs must have shape (B, {self.input_dim}), got {np.shape(x)}")
        out = np.empty((rows.shape[0], self.output_dim), dtype=np.float32)
        if rows.shape[0]:
            _forward_rows(rows, self._params, self._shapes, self._width, out)
        return out

    def __deepcopy__(self, memo: dict[int, Any]) -> MLPForward:
        return self

    def __repr__(self) -> str:
        dims = [int(self._shapes[0, 1]), *(int(s[0]) for s in self._shapes)]
        return f"MLPForward({' → '.join(map(str, dims))}, {self.digest[:12]})"


def sb3_forward(policy: Any) -> MLPForward | None:
    """The actor mean of an SB3 ``ActorCriticPolicy`` as an :class:`MLPForward`, or None where
    it is not a plain MLP: a features extractor other than a flatten, a latent network of
    anything but ``Linear`` layers each followed by one ``Tanh`` or ``ReLU`` (or nothing),
    a non-``Linear`` action head."""
    from torch import nn

    try:
        extractor = policy.pi_features_extractor
        latent = policy.mlp_extractor.policy_net
        head = policy.action_net
    except AttributeError:
        return None
    if not (
        isinstance(getattr(extractor, "flatten", None), nn.Flatten)
        and len(list(extractor.children())) == 1
        and isinstance(latent, nn.Sequential)
        and isinstance(head, nn.Linear)
    ):
        return None
    layers: list[tuple[NDArray[Any], NDArray[Any], str]] = []
    names = {nn.Tanh: "tanh", nn.ReLU: "relu"}
    for module in latent:
        if isinstance(module, nn.Linear) and module.bias is not None:
            layers.append((_array(module.weight), _array(module.bias), "identity"))
        elif type(module) in names and layers and layers[-1][2] == "identity":
            w, b, _ = layers[-1]
            layers[-1] = (w, b, names[type(module)])
        else:
            return None
    if head.bias is None:
        return None
    layers.append((_array(head.weight), _array(head.bias), "identity"))
    return MLPForward(layers)


def _array(tensor: Any) -> NDArray[np.float32]:
    """A torch parameter's values as a float32 array (a copy)."""
    return np.array(tensor.detach().cpu().numpy(), dtype=np.float32)
