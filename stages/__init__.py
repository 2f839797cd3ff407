"""Algorithms of sonarmap, one module per pipeline stage (pure functions over arrays)."""
