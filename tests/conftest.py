"""Test configuration: float64 everywhere, strict dtype promotion, no implicit rank promotion, and a
compilation cache private to the test session (never the user's ~/.cache/jaxflex), shared by every
test and both xdist workers: a program compiled once in the session (the full model's functions, the
engine's rollout, the optimizer's gradient) is loaded, not compiled again, by the next test or worker
that needs the same program. The session starts with an empty cache, as on a clean machine."""
import os
import shutil
import tempfile

# The suite is mostly XLA compilation of programs that then run for well under a second: compile
# them with LLVM's quick optimization level (less compile time; the programs run somewhat slower and
# agree with the fully optimized ones to round-off) and with XLA's classic elemental emitters instead
# of the fusion emitters (the optimizer's gradient compiles faster, and runs faster). Each of the two
# xdist workers has one core of its own: LLVM code generation in one thread (XLA splits a module into
# up to 32 parts compiled by a thread pool) and single-threaded Eigen calls, so that the workers'
# threads do not compete for the two cores (the measurements are in docs/performance.md). Set
# XLA_FLAGS yourself to test with other options. Before jax is imported: the backend reads it once.
if "XLA_FLAGS" not in os.environ:
    os.environ["XLA_FLAGS"] = ("--xla_backend_optimization_level=0 --xla_cpu_use_fusion_emitters=false "
                               "--xla_cpu_parallel_codegen_split_count=1 --xla_cpu_multi_thread_eigen=false")

# Two xdist workers already keep both cores busy: each runs its engine calls one after another
# (``jaxflex.runtime.threads``: JAXFLEX_THREADS=1) instead of from a thread per core, which would put four
# busy threads on two cores (less CPU time over the suite, see docs/performance.md; the same results:
# the threads run the same programs on the same inputs). Set JAXFLEX_THREADS yourself to override.
os.environ.setdefault("JAXFLEX_THREADS", "1")

# Figures are drawn into files, headless (the library leaves the backend to its user).
os.environ.setdefault("MPLBACKEND", "Agg")

# The xdist workers start after this file is read, so they inherit the environment the ``jaxflex``
# console script runs in: glibc's malloc on transparent huge pages (less kernel time in XLA's buffer
# allocations, see docs/performance.md; ``jaxflex.experiments.cli.hugepages_env``).
from jaxflex.experiments.cli import hugepages_env  # noqa: E402  (imports no jax)

os.environ.update(hugepages_env() or {})

import jax  # noqa: E402
import pytest  # noqa: E402

jax.config.update("jax_enable_x64", True)
jax.config.update("jax_numpy_dtype_promotion", "strict")
jax.config.update("jax_numpy_rank_promotion", "raise")

from jaxflex.runtime import compiled  # noqa: E402  (after the configuration above)

# The workers do not run the CLI's heap trimming (``jaxflex.runtime.heap``): it costs kernel time (pages
# returned and faulted in again) and the suite's time is the tighter budget; the peak memory it would
# save is small (see docs/performance.md).

_OWN_CACHE = None


def pytest_configure(config):
    """The CLI enables a persistent compilation cache (JAXFLEX_CACHE_DIR): point it at an empty
    directory for this session (shared with worker processes, removed at the end), so tests neither
    read nor write the user's cache and every run compiles from scratch, as on a clean machine."""
    global _OWN_CACHE
    if "JAXFLEX_CACHE_DIR" not in os.environ:       # the controller; xdist workers inherit it
        _OWN_CACHE = tempfile.mkdtemp(prefix="jaxflex-test-cache-")
        os.environ["JAXFLEX_CACHE_DIR"] = _OWN_CACHE
    if os.environ["JAXFLEX_CACHE_DIR"]:
        jax.config.update("jax_compilation_cache_dir", os.environ["JAXFLEX_CACHE_DIR"])
        jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.5)


def pytest_unconfigure(config):
    if _OWN_CACHE:
        shutil.rmtree(_OWN_CACHE, ignore_errors=True)


_MAPPING_SHARE = 0.5     # release compiled programs when a worker holds half the kernel's mapping limit


@pytest.fixture(autouse=True)
def _bounded_memory_mappings():
    """XLA:CPU maps every compiled kernel into memory regions of its own, and one xdist worker runs
    hundreds of tests that each compile programs: without care it reaches the kernel's per-process
    limit on mappings (vm.max_map_count) and LLVM crashes while compiling (jaxflex.runtime.compiled). Before
    each test, a worker above half the limit drops its compiled programs; the next test that needs
    one loads it from the session's persistent compilation cache or compiles it again."""
    compiled.release_if_crowded(_MAPPING_SHARE)
    yield
