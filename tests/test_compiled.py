"""Compiled programs can be released: a long job (``jaxflex reproduce``) stays below the kernel's
per-process limit on memory mappings (``jaxflex.compiled``)."""
import jax
import jax.numpy as jnp
import pytest

from jaxflex.compiled import mapping_count, mapping_limit, release_compiled


def _program(n):
    """A jitted function with about n separate kernels (the elementwise fusions between the matrix
    products)."""
    def f(x):
        for k in range(n):
            x = jnp.sin(x + k) @ jnp.sin(x + k).T / (k + 1.0)
        return x
    return jax.jit(f)


def _release_check():
    """In a fresh process: mapping counts before compiling, with the program loaded, after release."""
    x = jnp.linspace(0.0, 1.0, 64 * 64).reshape(64, 64)
    release_compiled()
    before = mapping_count()
    _program(60)(x).block_until_ready()
    loaded = mapping_count()
    release_compiled()
    return before, loaded, mapping_count()


@pytest.mark.skipif(mapping_count() is None, reason="needs /proc/self/maps (Linux)")
def test_release_compiled_returns_the_mappings_of_compiled_programs():
    """The mappings of live compiled programs go away with ``release_compiled``. Measured in a fresh
    process (``run_isolated``): in a process that compiled large programs before, LLVM reuses the
    freed code memory and a new program may need no new mappings (seen in a full test run)."""
    from jaxflex.compiled import run_isolated

    assert mapping_limit() is None or mapping_limit() > 0
    before, loaded, after = run_isolated(_release_check)
    # each kernel maps a few regions: 60 kernels add well over 100 mappings
    assert loaded - before > 100, (before, loaded)
    # most of them are returned (the rest: allocator pools that stay with the process)
    assert loaded - after > 0.5 * (loaded - before), (before, loaded, after)


def _mappings_after_compiling(n):
    """In the calling process: compile and run a program of about n kernels, return the process's
    mapping count and the result's dtype (float64 expected: the parent's setting carried over)."""
    x = jnp.linspace(0.0, 1.0, 16 * 16).reshape(16, 16)
    y = _program(n)(x).block_until_ready()
    return mapping_count(), str(y.dtype)


def _fails():
    raise ValueError("bad design: e beyond the leg")


@pytest.mark.skipif(mapping_count() is None, reason="needs /proc/self/maps (Linux)")
def test_run_isolated_compiles_in_a_child_and_keeps_settings_and_errors():
    """``run_isolated`` runs in a fresh process: the parent's mapping count does not grow by the
    child's program, float64 carries over, and the child's exception reaches the caller."""
    from jaxflex.compiled import run_isolated

    release_compiled()
    before = mapping_count()
    child_maps, dtype = run_isolated(_mappings_after_compiling, 60)
    assert dtype == "float64"
    # the child loaded 60 kernels; the parent gains at most the pool's pipes and threads
    assert mapping_count() - before < 50, (before, mapping_count(), child_maps)
    with pytest.raises(ValueError, match="beyond the leg"):
        run_isolated(_fails)
