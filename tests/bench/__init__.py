"""Smoke test of the fleet-scale benchmark harness (bench/)."""
