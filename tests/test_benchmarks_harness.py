"""The benchmarks harness: row schema, timing rule, JSON/PNG writing, and each benchmark's --quick path (tiny)."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:  # `benchmarks` is not an installed package; it runs from the repository root.
    sys.path.insert(0, str(ROOT))

from benchmarks import _harness as H  # noqa: E402
from benchmarks import profile_throughput, rd_inversion  # noqa: E402


def test_make_row_schema_and_validation():
    row = H.make_row("b", "m", "s", np.float64(1e-3), "rel", 0.5, None, evals_per_second=np.float32(2.0))
    assert list(row)[: len(H.ROW_KEYS)] == list(H.ROW_KEYS)
    assert isinstance(row["error"], float) and isinstance(row["evals_per_second"], float)
    assert row["compile_seconds"] is None
    # Non-finite errors become None (strict JSON has no NaN).
    assert H.make_row("b", "m", "s", float("inf"), "rel", 0.5, 0.1)["error"] is None
    with pytest.raises(ValueError, match="seconds"):
        H.make_row("b", "m", "s", 0.0, "rel", 0.0, 0.1)
    with pytest.raises(ValueError, match="error"):
        H.make_row("b", "m", "s", -1.0, "rel", 1.0, 0.1)
    with pytest.raises(ValueError, match="no raw arrays"):
        H.make_row("b", "m", "s", 0.0, "rel", 1.0, 0.1, data=np.zeros(100))


def test_time_call_times_the_first_call_separately():
    calls = []

    def fn(x):
        calls.append(x)
        if len(calls) == 1:  # the "compilation": much slower first call
            import time

            time.sleep(0.05)
        return np.asarray(x) * 2

    t = H.time_call(fn, 3, repeats=3)
    assert len(calls) == 4 and t.repeats == 3
    assert t.compile_seconds >= 0.05 > t.median_seconds >= t.seconds > 0
    assert t.output == 6
    with pytest.raises(ValueError, match="repeats"):
        H.time_call(fn, 1, repeats=0)


def test_time_interleaved_runs_round_robin():
    order = []
    calls = {name: (lambda name=name: order.append(name), ()) for name in ("a", "b")}
    timings = H.time_interleaved(calls, repeats=2)
    # First calls (compilation) one by one, then rounds a, b, a, b.
    assert order == ["a", "b", "a", "b", "a", "b"] and set(timings) == {"a", "b"}


def test_write_results_json_and_png(tmp_path):
    rows = [
        H.make_row("demo", "a", 1, 1e-3, "rel", 0.01, 0.2),
        H.make_row("demo", "a", 2, 0.0, "rel", 0.02, 0.2),  # exact 0 is drawn at the plot floor
        H.make_row("demo", "b", "x", 1e-8, "rel", 0.1, None),
    ]
    json_path, png_path = H.write_results("demo", rows, tmp_path, quick=True, summary={"ratio": np.float64(2.0)},
                                          notes=["n"])
    doc = json.loads(json_path.read_text())
    assert doc["benchmark"] == "demo" and doc["quick"] is True and doc["summary"] == {"ratio": 2.0}
    for key in ("platform", "cpu_count", "jax", "backend"):
        assert key in doc["machine"]
    assert [r["method"] for r in doc["rows"]] == ["a", "a", "b"]
    assert png_path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    with pytest.raises(ValueError, match="lacks"):
        H.write_results("bad", [{"method": "a"}], tmp_path, quick=True)


def test_numpy_twin_matches_jax_dipole():
    """The NumPy formula the throughput benchmark compares against is the same function as the library's."""
    from jaxsss.medium import Medium
    from jaxsss.profiles.dipole import dipole_profile

    p = profile_throughput.SKIN1
    sa, ss, eta = np.asarray(p["sigma_a"]), np.asarray(p["sigma_s_prime"]), np.full(3, p["eta"])
    r = np.linspace(0.0, 20.0, 257)[:, None]
    ref = np.asarray(dipole_profile(r, Medium(sa, ss, eta)))
    assert profile_throughput.max_rel_error(profile_throughput.np_dipole(r, sa, ss, eta), ref) < 1e-13


def test_table_inversion_is_accurate_away_from_the_stiff_end():
    # Same batch size and table size as the end-to-end test below, so that the compilations are shared.
    Rd, A, k, A_values = rd_inversion.workload(300)
    ref_alpha, ref_om, check = rd_inversion.reference(Rd, A)
    assert check["forward_rel_residual_Rd"] < 1e-13 and check["forward_rel_residual_1_minus_Rd"] < 1e-13
    alpha, one_minus = rd_inversion.invert_table(*rd_inversion.build_table(100, A_values), Rd, k, n=100)
    mid = (np.asarray(Rd) > 0.05) & (np.asarray(Rd) < 0.9)
    # A 100-sample Catmull-Rom table is good to ~1e-3 in alpha' in the middle of the range (measured ~1e-4).
    assert np.max(np.abs(np.asarray(alpha)[mid] / ref_alpha[mid] - 1.0)) < 3e-3
    np.testing.assert_allclose(np.asarray(alpha) + np.asarray(one_minus), 1.0, atol=1e-15)


@pytest.mark.parametrize(
    "module, tiny",
    [
        (profile_throughput, {"N": 2000, "M": 4, "N_r": 100, "N_multi": 500, "repeats": 1}),
        (rd_inversion, {"n_batch": 300, "repeats": 1, "tols": (1e-12,), "caps": (3,), "tables": (100,)}),
    ],
    ids=["profile_throughput", "rd_inversion"],
)
def test_quick_path_end_to_end(module, tiny, tmp_path, monkeypatch):
    monkeypatch.setitem(module.CONFIG, "quick", tiny)
    assert module.main(["--quick", "--out", str(tmp_path)]) == 0
    doc = json.loads((tmp_path / f"{module.NAME}.json").read_text())
    assert (tmp_path / f"{module.NAME}.png").exists()
    assert doc["quick"] is True and doc["rows"]
    for row in doc["rows"]:
        assert set(H.ROW_KEYS) <= set(row) and row["seconds"] > 0
    if module is profile_throughput:
        assert {r["method"] for r in doc["rows"]} == {"jax f64", "jax f32", "numpy f64"}
        f32 = [r for r in doc["rows"] if r["method"] == "jax f32"]
        assert all(r["output_dtype"] == "float32" for r in f32)
        assert all(r["error"] < 1e-3 for r in f32)  # float32 against float64 (measured ~1e-5)
        numpy_rows = [r for r in doc["rows"] if r["method"] == "numpy f64"]
        assert all(r["error"] < 1e-12 for r in numpy_rows)
    else:
        assert "goal" in doc["summary"] and "met" in doc["summary"]["goal"]


def test_run_all_reports_a_failing_benchmark_and_carries_on(tmp_path, monkeypatch, capsys):
    from benchmarks import run_all

    monkeypatch.setattr(run_all, "BENCHMARKS", ("no_such_benchmark",))
    assert run_all.main(["--quick", "--out", str(tmp_path)]) == 1
    assert "failed: no_such_benchmark" in capsys.readouterr().err
