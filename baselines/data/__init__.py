"""Data files of the baselines: ``ppc_tuned.yaml``, the tuned PPC gains of
:mod:`baselines.ppc_tuned` (written by ``python -m experiments.studies.tune_ppc``)."""
