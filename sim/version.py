"""The simulator's version, importable without loading open3d (dataset caches check it)."""

SIM_VERSION = "1.3.0"
"""Bumped whenever the same (scene, config, seed) would give different bytes: a cached
dataset whose recipe names another version is simulated again. 1.1.0: the MCAP layout of
747fd51 (navigation in chunks of its own, about one image a chunk); the messages are
unchanged, but a file's hash keys every stage downstream of it, and only the new layout
lets `keyframes` decompress just the chunks it needs. 1.2.0: the navigation chunks are
written every 5 s of log time instead of once at the end (a cut copy keeps its keyframes);
the messages are unchanged. 1.3.0: the sonar config gains `noise_shape` (issue 39's sensor
randomisation), so the recorded config JSON changes; default images are unchanged."""
