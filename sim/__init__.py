"""Pure-Python orthogonal sonar-pair simulator (scenes, sonar model, missions)."""
