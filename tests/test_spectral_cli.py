"""Welch PSD (Parseval, peak location) and the kinematics command's JSON contract (docs/conventions.md#file-formats)."""
import json

import jax.numpy as jnp
import numpy as np

from jaxflex.experiments.cli import main
from jaxflex.spectral import dominant_frequencies, welch


def test_welch_parseval_and_peak():
    fs = 2000.0
    t = np.arange(8192) / fs
    rng = np.random.default_rng(1)
    x = 3.0 * np.sin(2 * np.pi * 125.0 * t) + 0.5 * np.sin(2 * np.pi * 410.0 * t) + 0.1 * rng.standard_normal(t.size)
    f, p = welch(jnp.asarray(x), fs, 1024)
    # Parseval: the integral of the PSD equals the mean square (Hann-window leakage is inside the sum)
    ms = np.mean((x - x.mean()) ** 2)
    np.testing.assert_allclose(float(jnp.sum(p) * (f[1] - f[0])), ms, rtol=0.03)
    peaks = dominant_frequencies(f, p, k=2)
    np.testing.assert_allclose(sorted(peaks), [125.0, 410.0], atol=fs / 1024)


def test_kinematics_cli_json(tmp_path, capsys):
    out = tmp_path / "k.json"
    assert main(["kinematics", "--steps", "10000", "--json", str(out)]) == 0
    res = json.loads(out.read_text())
    assert set(res["blend_length_mm"]) >= {"lame", "clothoid", "polar", "lame_extended", "clothoid_extended"}
    for key in ("task_acc_max", "joint_acc_max"):
        assert set(res[key]) == {"lame", "clothoid", "polar"}
        for blend in res[key].values():
            assert set(blend) == {"poly7", "bang_bang", "trap_1_4", "trap_1_8"}
    assert abs(res["blend_length_mm"]["lame"] - 42.156) < 0.01
    assert "Table 5" in capsys.readouterr().out


def test_cli_reports_bad_input_without_traceback(capsys):
    assert main(["kinematics", "--tf", "-1"]) == 2
    assert "tf must be > 0" in capsys.readouterr().err


def test_modes_cli_json(tmp_path):
    out = tmp_path / "m.json"
    assert main(["modes", "--payload", "6", "--points", "3", "--json", str(out)]) == 0
    res = json.loads(out.read_text())
    assert res["payload"] == 6.0 and len(res["points"]) == 3
    for p in res["points"]:
        assert set(p) >= {"s", "x", "y", "freqs_hz"}
        assert p["freqs_hz"] == sorted(p["freqs_hz"]) and 56 < p["freqs_hz"][0] < 61


def test_modes_cli_rejects_negative_payload(capsys):
    assert main(["modes", "--payload", "-1"]) == 2
    assert "payload must be >= 0" in capsys.readouterr().err
