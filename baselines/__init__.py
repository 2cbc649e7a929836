"""Baseline policies for platoon_env, all behind the shared :class:`Policy` interface."""

from baselines.policy import Policy
from baselines.ppc import PPCParams, PPCPolicy

__all__ = ["PPCParams", "PPCPolicy", "Policy"]
