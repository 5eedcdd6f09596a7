"""Inverse models and feedforward compensation (MODELS.md §8)."""
