"""scanmill planning core: pure functions on numpy arrays (no web, no database)."""
