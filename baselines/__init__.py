"""Baseline policies for platoon_env, all behind the shared :class:`Policy` interface."""

# First of the package's modules: keys numba's kernel cache on the source (see the module).
import baselines._numba_cache  # noqa: F401
from baselines.filtered_ppc import FilteredPPCPolicy, FilterParams
from baselines.filtered_ppc_drive import DriveAwareFilteredPPCPolicy
from baselines.last_seen import LastSeenFOVPolicy, LastSeenParams, LastSeenPolicy
from baselines.policy import Policy
from baselines.ppc import PPCParams, PPCPolicy
from baselines.ppc_tuned import TunedPPCPolicy

__all__ = [
    "DriveAwareFilteredPPCPolicy",
    "FilterParams",
    "FilteredPPCPolicy",
    "LastSeenFOVPolicy",
    "LastSeenParams",
    "LastSeenPolicy",
    "PPCParams",
    "PPCPolicy",
    "Policy",
    "TunedPPCPolicy",
]
