"""Learning side of platoon_env: SB3 training with one policy shared by every follower.

* :class:`PlatoonVecEnv` — parameter-sharing SB3 ``VecEnv`` over platoon ``ParallelEnv``\\ s
  (one slot per follower), with fixed observation normalisation and ``[-1, 1]`` actions;
* :class:`LearnedPolicy` — a saved model (``model.zip`` + ``model.json``) behind the shared
  policy interface ``reset(seed=None)`` / ``act(observations)``;
* ``platoon-train`` (:mod:`training.train`) — the training command line and the SB3 driver;
  :mod:`training.config` holds its options and their checks, :mod:`training.run` what a run
  does in its folder (planning, the one-owner lock, segments), shared with the RLlib engine
  (:mod:`training.rllib`), and :mod:`training.seeding` the env seeds of every run.

Needs the ``train`` extra (torch, stable-baselines3, tensorboard, tqdm, rich).
"""

from training.policies import LearnedPolicy
from training.vec_env import ActionRange, PlatoonVecEnv

__all__ = ["ActionRange", "LearnedPolicy", "PlatoonVecEnv"]
