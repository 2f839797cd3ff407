"""Sharing artifacts with remotes: push and pull, verified on the way in.

Modules:
    push_pull: `push`, `pull` and listing a remote.
    remotes: fsspec filesystems for local paths, s3, ssh/sftp, http(s).
    remote_index: a remote's complete artifacts and their manifests, checked.
    transfer: streamed, capped, hashed copies.
    trust: what `pull` believes of a remote (recipes re-hashed, models pinned).
"""
