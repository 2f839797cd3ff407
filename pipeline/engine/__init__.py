"""The engine: config, keys, the artifact store, planning and running stages.

Sub-packages, by job:
    config: the pipeline config: one YAML, a section per stage, CLI overrides.
    store: the artifact store, atomic commits, manifests, integrity, gc, codecs.
    run: the stage graph type, planning and running.
    share: push and pull of artifacts, verified.

Shared by all of them:
    errors: typed errors, one line in the CLI.
    hashing: canonical JSON, artifact keys, dataset fingerprints.
    text: one-line message text.
"""
