"""Shared setup: JAX in float64 (the comparisons are to 1e-8) on the CPU."""

import os

os.environ.setdefault("JAX_PLATFORMS", "cpu")

import jax  # noqa: E402

jax.config.update("jax_enable_x64", True)
