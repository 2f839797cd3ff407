"""Experiments over many runs: sweeps and the paper's simulation study.

Modules:
    sweep: the cross product of datasets and override values.
    sweep_output: a sweep's parquet, table and plot.
    study: Table I, Fig. 4 and the per-class accounting of the study.
    headline_columns: the headline error columns of sweep and study tables.
    submap_columns: the dense-submap ratio columns of sweep tables.
"""
