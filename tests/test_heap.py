"""The heap trimming (``jaxflex.runtime.heap``) returns freed memory to the system and changes no result."""
import threading

import numpy as np
import pytest

from jaxflex.runtime import heap
from jaxflex.runtime.compiled import run_isolated


def _fragment_then_trim(n_blocks: int = 6000, size: int = 48 * 1024):
    """In a fresh process: the resident size with a fragmented heap and after ``heap.trim``. A worker
    thread (its own malloc arena, as XLA's threads have) allocates n_blocks buffers of ``size`` bytes
    (below glibc's mmap threshold, so they come from the arena), touches them, and frees all but
    every 50th: the freed pages sit between live blocks, where glibc keeps them until a trim."""
    kept = []

    def work():
        blocks = [np.ones(size // 8) for _ in range(n_blocks)]
        kept.extend(blocks[::50])

    t = threading.Thread(target=work)
    t.start()
    t.join()
    before = heap.resident_bytes()
    done = heap.trim()
    after = heap.resident_bytes()
    return done, before, after, float(sum(float(b[0]) for b in kept))


@pytest.mark.skipif(not heap.available(), reason="needs glibc's malloc_trim (Linux)")
def test_trim_returns_the_freed_pages_of_a_fragmented_heap(monkeypatch):
    """6000 x 48 KiB = 281 MiB allocated in a thread, 98 % of it freed between the 2 % kept: the
    trim returns at least 150 MiB (the freed pages, less glibc's per-arena reserve and the kept
    blocks' pages; measured: 273 MiB). The kept blocks' values are intact (120 blocks of
    ones). The child runs without the trimming thread, which could trim first."""
    monkeypatch.setenv("JAXFLEX_HEAP_TRIM", "0")
    done, before, after, checksum = run_isolated(_fragment_then_trim)
    assert done
    assert before - after > 150 * 2**20, (before, after)
    assert checksum == 120.0


def _start_twice():
    return heap.start_trimming(), heap.start_trimming(), heap.trimming(), sum(
        t.name == "jaxflex-heap-trim" for t in threading.enumerate())


@pytest.mark.skipif(not heap.available(), reason="needs glibc's malloc_trim (Linux)")
def test_start_trimming_starts_one_thread_and_respects_the_switch(monkeypatch):
    """Starting twice runs one daemon thread; JAXFLEX_HEAP_TRIM=0 turns it off (checked in fresh
    processes so that the suite's own thread does not count)."""
    first, second, running, threads = run_isolated(_start_twice)
    assert first and second and running and threads == 1
    monkeypatch.setenv("JAXFLEX_HEAP_TRIM", "0")
    first, _, running, threads = run_isolated(_start_twice)
    assert not first and not running and threads == 0


def test_trimming_rule_waits_for_growth_above_the_floor():
    """``heap.should_trim``: below ``above`` (default 2 GiB: an optimizer's steps refill a few hundred
    MB of freed buffers at every step, and trimming them each time costs their page faults) no growth
    trims; above it, growth by more than ``slack`` since the last trim does, less does not."""
    mib = 2**20
    assert heap.TRIM_ABOVE == 2048 * mib
    assert not heap.should_trim(1900 * mib, 100 * mib, 128 * mib, heap.TRIM_ABOVE)       # 1.8 GB grown, below
    assert heap.should_trim(2100 * mib, 1900 * mib, 128 * mib, heap.TRIM_ABOVE)          # above, grown 200 MiB
    assert not heap.should_trim(2100 * mib, 2000 * mib, 128 * mib, heap.TRIM_ABOVE)      # above, grown 100 MiB
    assert heap.should_trim(300 * mib, 100 * mib, 128 * mib, 0)                          # no floor: growth alone
