"""Test configuration: float64 everywhere, strict dtype promotion, no implicit rank promotion, and a
compilation cache private to the test session (never the user's ~/.cache/jaxflex)."""
import os
import shutil
import tempfile

import jax

jax.config.update("jax_enable_x64", True)
jax.config.update("jax_numpy_dtype_promotion", "strict")
jax.config.update("jax_numpy_rank_promotion", "raise")

_OWN_CACHE = None


def pytest_configure(config):
    """The CLI enables a persistent compilation cache (JAXFLEX_CACHE_DIR): point it at an empty
    directory for this session (shared with worker processes, removed at the end), so tests neither
    read nor write the user's cache and every run compiles from scratch, as on a clean machine."""
    global _OWN_CACHE
    if "JAXFLEX_CACHE_DIR" not in os.environ:
        _OWN_CACHE = tempfile.mkdtemp(prefix="jaxflex-test-cache-")
        os.environ["JAXFLEX_CACHE_DIR"] = _OWN_CACHE


def pytest_unconfigure(config):
    if _OWN_CACHE:
        shutil.rmtree(_OWN_CACHE, ignore_errors=True)
