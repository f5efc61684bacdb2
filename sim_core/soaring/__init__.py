"""soaring."""
