"""Progress on stderr: plain throttled lines in a log, one line rewritten in place on a terminal, an
ETA from the measured rate (first unit excluded: it usually compiles), remembered compile times."""
import io
import types

import jax
import jax.numpy as jnp
import pytest

from jaxflex import progress
from jaxflex.progress import Progress


class Clock:
    def __init__(self):
        self.now = 1000.0

    def perf_counter(self):
        return self.now


class Terminal(io.StringIO):
    def isatty(self):
        return True


@pytest.fixture
def clock(monkeypatch):
    c = Clock()
    monkeypatch.setattr(progress, "time", types.SimpleNamespace(perf_counter=c.perf_counter))
    return c


def test_log_lines_are_throttled_and_the_eta_follows_the_measured_rate(clock):
    log = io.StringIO()
    bar = Progress("opt", total=100, unit="step", stream=log)
    clock.now += 30.0                     # the first step compiles: 30 s
    bar.update(1)
    for k in range(2, 101):
        clock.now += 2.0                  # then 2 s per step
        bar.update(k, f"value {k}")
    bar.close("stopped: steps")
    lines = log.getvalue().splitlines()
    assert "\r" not in log.getvalue()
    # the first line, then one per LOG_INTERVAL (10 s = 5 steps), the last step and the close
    assert 20 <= len(lines) <= 24, lines
    assert lines[0] == "opt: 1/100 steps [30 s]"
    # at step 6 (10 s after the first): 2 s per step measured, 94 steps left -> 188 s
    assert lines[1] == "opt: 6/100 steps value 6 [40 s, ETA 3:08]"
    assert lines[-1] == "opt: 100/100 steps stopped: steps [3:48]"
    assert "ETA" not in lines[-2] and lines[-2].startswith("opt: 100/100 steps value 100")


def test_terminal_rewrites_one_line_and_ends_it(clock):
    term = Terminal()
    with Progress("rk4", total=4, unit="chunk", stream=term) as bar:
        for k in range(1, 5):
            clock.now += 1.0
            bar.update(k)
    out = term.getvalue()
    assert out.count("\n") == 1 and out.endswith("done [4 s]\n")
    assert out.startswith("\rrk4: 1/4 chunks [1 s]") and "\rrk4: 2/4 chunks [2 s, ETA 2 s]" in out


def test_disabled_progress_writes_nothing(clock):
    log = io.StringIO()
    with Progress("quiet", total=3, stream=log, enabled=False) as bar:
        with bar.waiting("compiling"):
            pass
        bar.update(3)
        bar.say("hello")
    assert log.getvalue() == ""


def test_compile_waits_are_remembered_and_give_the_next_eta(tmp_path):
    progress.remember(tmp_path / "timings.json")
    try:
        log = io.StringIO()
        bar = Progress("study", stream=log)
        f = jax.jit(lambda x: jnp.sin(x) * 3.0 + x**2)
        with bar.waiting("compiling f", key="f") as wait:
            f(jnp.arange(7.0)).block_until_ready()
        assert wait.compiled
        assert progress.recorded("f") is not None and progress.recorded("f") >= 0
        with bar.waiting("running f again", key="f") as again:          # cached: nothing compiles
            f(jnp.arange(7.0)).block_until_ready()
        assert not again.compiled
        lines = log.getvalue().splitlines()
        assert lines[0].startswith("study: compiling f ... [0 s]") and "ETA" not in lines[0]
        assert lines[1].startswith("study: compiling f: ")
        assert lines[2].startswith("study: running f again ... [0 s, ETA ~")      # from the remembered time
    finally:
        progress.remember(None)


def test_clock_format():
    assert [progress.clock(s) for s in (0.4, 59.4, 61, 3600 + 62)] == ["0 s", "59 s", "1:01", "1:01:02"]
