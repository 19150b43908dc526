"""The design scripts in optimize/ run in quick mode and write consistent results."""

import csv
import json
import math
import pathlib
import subprocess
import sys

import pytest

ROOT = pathlib.Path(__file__).resolve().parents[1]


def run_script(name, out):
    proc = subprocess.run(
        [sys.executable, str(ROOT / "optimize" / name), "--quick", "--out", str(out)],
        capture_output=True,
        text=True,
        timeout=1800,
    )
    assert proc.returncode == 0, proc.stderr[-3000:]
    return proc.stdout


def read_csv(path):
    with open(path) as fh:
        return list(csv.DictReader(fh))


@pytest.mark.slow
@pytest.mark.extended
def test_clamp_vs_object_size(tmp_path):
    stdout = run_script("clamp_vs_object_size.py", tmp_path)
    stem = tmp_path / "clamp_vs_object_size"
    rows = read_csv(stem.with_suffix(".csv"))
    meta = json.loads(stem.with_suffix(".json").read_text())
    assert stem.with_suffix(".png").stat().st_size > 10_000
    assert "lc_gradient_mm" in stdout
    lo, hi = meta["clamp_bounds_mm"]
    assert [float(r["diameter_mm"]) for r in rows] == [18.0, 35.0]
    for r in rows:
        v = {k: float(x) for k, x in r.items()}
        assert all(math.isfinite(x) for x in v.values())
        assert lo <= v["lc_gradient_mm"] <= hi
        assert lo <= v["lc_scan_mm"] <= hi
        assert v["force_gradient_N"] > 0
        # the gradient optimum is no worse than the best point of the coarse scan
        assert v["force_gradient_N"] >= v["force_scan_N"] * (1 - 1e-6)
        # first-order optimality: an interior optimum has a small slope, one at a bound a
        # slope pointing out of the interval
        x, g = v["lc_gradient_mm"], v["slope_at_optimum_N_per_mm"]
        if x >= hi - 1e-9:
            assert g >= -1e-3
        elif x <= lo + 1e-9:
            assert g <= 1e-3
        else:
            assert abs(g) < 0.05 * v["force_gradient_N"] / (hi - lo)
        assert v["max_penetration_mm"] < 0.02 * 3.0
    for rec in meta["diameters"]:
        assert len(rec["scan_force_N"]) == len(meta["scan_clamp_lengths_mm"])
        # every accepted gradient step increased the force
        acc = [it["force"] for it in rec["iterations"] if it["accepted"]]
        assert all(b >= a for a, b in zip(acc, acc[1:]))


@pytest.mark.slow
@pytest.mark.extended
def test_crossbeam_count_angle(tmp_path):
    run_script("crossbeam_count_angle.py", tmp_path)
    stem = tmp_path / "crossbeam_count_angle"
    rows = read_csv(stem.with_suffix(".csv"))
    meta = json.loads(stem.with_suffix(".json").read_text())
    assert stem.with_suffix(".png").stat().st_size > 10_000
    assert len(rows) == len(meta["counts"]) * len(meta["angles_deg"])
    for r in rows:
        assert r["fig3_status"] == "converged"
        f, df = float(r["contact_force_N"]), float(r["dF_dangle_N_per_rad"])
        assert math.isfinite(f) and f > 0 and math.isfinite(df)
        assert float(r["tip_stiffness_N_per_mm"]) > 0
        if float(r["angle_deg"]) == 0.0:  # the implicit derivative against differences
            fd = float(r["dF_dangle_fd_N_per_rad"])
            assert df == pytest.approx(fd, rel=1e-3, abs=1e-4)
    for n in meta["counts"]:
        r = [x for x in rows if int(x["count"]) == n]
        a = [math.radians(float(x["angle_deg"])) for x in r]
        f = [float(x["contact_force_N"]) for x in r]
        s = [float(x["dF_dangle_N_per_rad"]) for x in r]
        for i in range(len(r) - 1):  # the slopes integrate to the force differences
            trapezoid = 0.5 * (s[i] + s[i + 1]) * (a[i + 1] - a[i])
            assert f[i + 1] - f[i] == pytest.approx(trapezoid, rel=0.3, abs=0.02)
