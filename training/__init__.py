"""Learning side of platoon_env: SB3 training with one policy shared by every follower.

* :class:`PlatoonVecEnv` — parameter-sharing SB3 ``VecEnv`` over platoon ``ParallelEnv``\\ s
  (one slot per follower), with fixed observation normalisation and ``[-1, 1]`` actions;
* :class:`LearnedPolicy` — a saved model (``model.zip`` + ``model.json``) behind the shared
  policy interface ``reset(seed=None)`` / ``act(observations)``;
* ``platoon-train`` (:mod:`training.train`) — the training command line.

Needs the ``train`` extra (torch, stable-baselines3, tensorboard, tqdm, rich).
"""

from training.policies import LearnedPolicy
from training.vec_env import ActionRange, PlatoonVecEnv

__all__ = ["ActionRange", "LearnedPolicy", "PlatoonVecEnv"]
