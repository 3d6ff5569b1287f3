"""Seeded simulation of drives and of the gyro's errors (placeholder while being built)."""
