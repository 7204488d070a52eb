"""frng.plan."""
