"""Helpers the tests share (fixtures' builders, caches shared across xdist workers, the CPU profile)."""
