"""Hydra entry points (console scripts): validate, run the whole pipeline, or one stage of it."""
