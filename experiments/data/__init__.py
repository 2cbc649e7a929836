"""Data shipped with the experiments: the published per-episode rows of the default benchmark
(``published_benchmark.json``, :mod:`experiments.published`)."""
