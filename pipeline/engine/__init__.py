"""The engine: config, keys, the artifact store, planning and running stages.

Modules:
    config: the pipeline config: one YAML, a section per stage, CLI overrides.
    hashing: canonical JSON, artifact keys, dataset fingerprints.
    store: the artifact store, atomic commits and manifests.
    runner: hit-or-miss planning and execution.
    registry: the explicit, ordered stage registry.
    session: a dataset, config and store resolved into a run.
    codecs: stage outputs by kind (parquet, json, bytes, frames).
    errors: typed errors, one line in the CLI.
    progress: progress on stderr.
    share: push and pull of artifacts, verified.
"""
