"""Baseline policies for platoon_env, all behind the shared :class:`Policy` interface."""

from baselines.filtered_ppc import FilteredPPCPolicy, FilterParams
from baselines.last_seen import LastSeenFOVPolicy, LastSeenParams, LastSeenPolicy
from baselines.policy import Policy
from baselines.ppc import PPCParams, PPCPolicy

__all__ = [
    "FilterParams",
    "FilteredPPCPolicy",
    "LastSeenFOVPolicy",
    "LastSeenParams",
    "LastSeenPolicy",
    "PPCParams",
    "PPCPolicy",
    "Policy",
]
