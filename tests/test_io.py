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


def test_a_rerun_resumes_only_from_the_same_code_and_fresh_starts_over(tmp_path):
    """``prepare_resume``: checkpoints written under another key (other code, another mode) or under
    no recorded key are removed, those of the same key kept; ``fresh`` removes them and every
    section's JSON, and leaves other files alone. ``code_digest`` is stable and changes with the
    sources' bytes."""
    import json
    from jaxflex.experiments import io

    digest = io.code_digest()
    assert len(digest) == 16 and digest == io.code_digest()
    key = {"jaxflex_version": "x", "code": digest, "quick": False}
    (tmp_path / "optimize_6kg").mkdir()
    ckpt = tmp_path / "optimize_6kg" / "checkpoint.npz"
    section = tmp_path / "vibration.json"
    other = tmp_path / "notes.json"
    write = lambda: (ckpt.write_bytes(b"0"), section.write_text(json.dumps({"a": 1, "resume_key": key})),
                     other.write_text("{}"))
    write()
    assert io.prepare_resume(tmp_path, key) == 1 and not ckpt.exists()     # no key recorded yet
    write()
    assert io.prepare_resume(tmp_path, key) == 0 and ckpt.exists()         # the same key: resume
    assert io.prepare_resume(tmp_path, {**key, "code": "0" * 16}) == 1 and not ckpt.exists()   # other code
    write()
    assert io.prepare_resume(tmp_path, key) == 1           # written under the other code's marker
    write()
    assert io.prepare_resume(tmp_path, key, fresh=True) == 2
    assert not ckpt.exists() and not section.exists() and other.exists()


def test_a_refined_design_record_reads_back_as_the_design_it_was_written_from():
    """``corners_design`` inverts the closed-loop study's ``refined`` entry (both corners' d, e [m]
    and n, the law's coefficients), exactly: JSON keeps float64."""
    import json

    import numpy as np

    from jaxflex.designs import design
    from jaxflex.experiments.io import corners_design

    x = design(0.021, 0.13, 3.5, [1.5, 0.25, -0.75, 2.0], d2=0.024, e2=0.11, n2=4.25)
    rec = json.loads(json.dumps({"corners": [{"d_m": float(x.d[k]), "e_m": float(x.e[k]), "n": float(x.n[k])}
                                             for k in range(2)], "coef": np.asarray(x.coef).tolist()}))
    y = corners_design(rec)
    for a, b in zip(x, y):
        assert np.array_equal(np.asarray(a), np.asarray(b)) and np.asarray(b).dtype == np.float64
