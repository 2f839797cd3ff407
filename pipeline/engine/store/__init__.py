"""The artifact store: committed artifacts, their manifests and files, checked.

Modules:
    artifact_store: `<store>/<stage>/<key>/`, atomic commits, the store lock.
    artifact: a committed artifact's record and the path check its files go through.
    manifest: the shape of `manifest.json`, validated before any field is trusted.
    integrity: a file or artifact directory against its manifest.
    codecs: stage outputs by kind (parquet, json, bytes, frames).
    gc: what the store keeps and the leftovers it heals (`leases`: live runs' holds).
    disk: OS errors of the store or a dataset as one line.
"""
