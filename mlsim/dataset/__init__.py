"""Synthetic datasets of sensor episodes: generation, storage, reading."""
