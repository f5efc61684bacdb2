"""urlhandlers."""
