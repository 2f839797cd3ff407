"""The engine: config, keys, the artifact store, planning and running stages.

Modules:
    config: the pipeline config: one YAML, a section per stage, CLI overrides.
    hashing: canonical JSON, artifact keys, dataset fingerprints.
    store: the artifact store, atomic commits and manifests.
    planner: hit-or-miss planning (`planned`: the records it produces).
    runner: execution of a plan's misses.
    registry: the stage graph (`Graph`): the real pipeline's, or one named by the CLI.
    session: a dataset, config and store resolved into a run.
    codecs: stage outputs by kind (parquet, json, bytes, frames).
    errors: typed errors, one line in the CLI.
    progress: progress on stderr.
    share: push and pull of artifacts, verified.
"""
