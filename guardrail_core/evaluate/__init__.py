"""Metrics against a drive's truth: detection (§5.1), reconstruction and the units sweep (§5.2)."""
