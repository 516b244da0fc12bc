"""Studies that answered a question of past work, kept to reproduce their results/ files:
``./dev bench NAME`` runs one (benchmarks/__main__.py lists them)."""
