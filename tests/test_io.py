"""Resumable outputs: a finished section is loaded on a rerun, a changed key or a damaged file recomputes."""
import json

from jaxflex.experiments.io import resumable


def test_resumable_loads_finished_sections_and_recomputes_on_a_new_key(tmp_path):
    calls = []

    def compute():
        calls.append(1)
        return {"value": len(calls), "arr": [1.0, 2.0]}

    path = tmp_path / "sec" / "section.json"
    first = resumable(path, {"v": 1}, compute)
    again = resumable(path, {"v": 1}, compute)
    assert len(calls) == 1 and again == first and first["value"] == 1
    other = resumable(path, {"v": 2}, compute)           # parameters changed: recompute
    assert len(calls) == 2 and other["value"] == 2
    path.write_text("{ half written")                      # damaged file: recompute, never crash
    fixed = resumable(path, {"v": 2}, compute)
    assert len(calls) == 3 and json.loads(path.read_text())["value"] == 3 == fixed["value"]
    assert [p.name for p in path.parent.iterdir()] == ["section.json"]    # no temporary files left
