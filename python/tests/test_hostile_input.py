"""Hostile input, round 3 (issue 32), from Python: what crashed, aborted or
silently read wrong values in the bindings. Each must raise a Python error
naming the argument, key or file (never kill the interpreter), or use the
values given."""

import json
import subprocess
import sys

import numpy as np
import pytest

import tofkit

PLATE = """[[surface]]
kind = "plane"
center_m = [2, 0, 0]
normal = [-1, 0, 0]
size_m = [1, 1]
reflectance = 0.5
"""


def _in_child(code):
    """Runs `code` in a fresh interpreter (a crash there must not end the
    test run); returns the CompletedProcess."""
    return subprocess.run([sys.executable, "-c", "import tofkit, numpy as np\n" + code],
                          capture_output=True, text=True, timeout=300,
                          env={"PYTHONPATH": str(__import__("pathlib").Path(
                              tofkit.__file__).resolve().parents[1])})


# Classes 1 and 8: subnormal or absurdly small positive keys crashed the
# interpreter (SIGSEGV in the device's setup) or wrote inf.
@pytest.mark.parametrize("key,value", [
    ("laser.pulse_width_ns", 1e-300),
    ("thermal.sensor_resolution_c", 1e-310),
    ("receiver.saturation_v", 1e-310),
    ("receiver.bandwidth_mhz", 5e-324),
    ("tdc.lsb_ps", 1e-200),
])
def test_tiny_positive_keys_are_refused_by_name(key, value):
    child = _in_child(
        f"try:\n    tofkit.measure([1, 2], 0.5, shots=5, config=tofkit.DeviceConfig("
        f"set={{'{key}': {value!r}}}))\nexcept ValueError as e:\n    print('refused:', e)")
    assert child.returncode == 0, child.stderr
    assert "refused:" in child.stdout and key in child.stdout, child.stdout


# Class 2: a B-spline model whose domain is wider than its knots was loaded
# (correct then read coefficients out of bounds: SIGSEGV).
def test_model_with_a_domain_wider_than_its_knots_is_refused(tmp_path, cli):
    cli("measure", "--distance", "1:8:1", "--reflectance", "0.05,0.5,0.9", "--out",
        tmp_path / "cal.csv")
    cli("fit", "--in", tmp_path / "cal.csv", "--surface", "bspline", "--knots", "4x4", "--out",
        tmp_path / "m.json")
    tofkit.Model.load(tmp_path / "m.json")  # as fitted: loads
    model = json.loads((tmp_path / "m.json").read_text())
    for axis, end, value in [("amplitude", 1, 1e100), ("range_m", 0, 0.01), ("range_m", 1, 100)]:
        bad = json.loads(json.dumps(model))
        bad["steps"][0]["surface"]["domain"][axis][end] = value
        path = tmp_path / "bad.json"
        path.write_text(json.dumps(bad))
        with pytest.raises(ValueError, match="exceeds the axis knots"):
            tofkit.Model.load(path)


# Class 3: 1e7 distances aborted the interpreter under a 4 GB limit; the
# CLI's row limit applies (ValueError), and under the limit no abort.
def test_measure_applies_the_row_limit():
    # In a child under a 4 GB address-space limit, as the reproducer ran it.
    child = _in_child(
        "import resource\n"
        "resource.setrlimit(resource.RLIMIT_AS, (4_000_000_000, 4_000_000_000))\n"
        "try:\n    tofkit.measure(np.ones(10**7) * 2, 0.5, shots=5)\n"
        "except (ValueError, MemoryError) as e:\n    print(type(e).__name__, e)")
    assert child.returncode == 0, child.stderr
    assert child.stdout.startswith("ValueError") and "--max-rows" in child.stdout, child.stdout
    with pytest.raises(ValueError, match="rows"):
        tofkit.measure(np.linspace(1, 2, 1000), [0.1] * 1001, shots=1)


# Class 7: scan read strided and reversed arrays as contiguous ([0,2,4,6,8]
# scanned [0,1,2,3,4]; reversed read memory before the buffer).
@pytest.mark.parametrize("azimuth", [
    np.arange(10.)[::2],
    np.arange(20.).reshape(4, 5)[:, 1],
    np.arange(10.)[::-1],
    np.arange(10, dtype=np.float32)[::3],
    np.asfortranarray(np.arange(6.)),
])
def test_scan_uses_the_values_of_any_1d_array(tmp_path, azimuth):
    scene = tmp_path / "s.toml"
    scene.write_text(PLATE)
    result = tofkit.scan(scene, "spherical", azimuth=azimuth, elevation=0, shots=5)
    scanned = np.degrees(np.arctan2(result.beams["dir_y"], result.beams["dir_x"]))
    assert sorted(set(np.round(scanned, 6))) == sorted(set(np.round(np.asarray(azimuth,
                                                                                 float), 6)))
    raster = tofkit.scan(scene, "raster", y=np.arange(0, 1, 0.1)[::3], z=0, shots=5)
    assert sorted(set(np.round(raster.beams["origin_y_m"], 6))) == [0.0, 0.3, 0.6, 0.9]


# Also: wrong kinds are refused by name, not coerced.
def test_wrong_kinds_are_refused_by_name(tmp_path, cli):
    for distances in ([True, False], ["1", "2"], np.array(["1.5"])):
        with pytest.raises(ValueError, match="distance_m"):
            tofkit.measure(distances, 0.5, shots=5)
    with pytest.raises(ValueError, match="reflectance"):
        tofkit.measure([1.0], [True], shots=5)
    raw = tofkit.measure([1, 2, 5], [0.1, 0.9], count=4, seed=1)
    with pytest.raises(TypeError, match="refine_walk"):
        tofkit.fit_chain(raw, steps="offset,grayvalue", refine_walk="False")
    model = tofkit.fit_chain(raw, steps="offset")
    columns = {name: raw[name] for name in ("tof_ns", "pulse_width_ns", "amplitude",
                                            "temperature_c", "shots_valid")}
    for bad in (np.array([-1] * len(raw)), np.array([2**40] * len(raw), dtype=np.int64),
                np.array([1.5] * len(raw))):
        with pytest.raises(ValueError, match="flags"):
            model.apply({**columns, "flags": bad})
    with pytest.raises(ValueError, match="shots_valid"):
        model.apply({**columns, "shots_valid": np.full(len(raw), -3), "flags": raw["flags"]})
    # Held out: in-range integers of any width, and the raw array itself, apply.
    distance, _, _ = model.apply({**columns, "flags": raw["flags"].astype(np.int64)})
    assert np.allclose(distance, model.apply(raw)[0], equal_nan=True)


# Held out for class 2: every model kind checks its internal consistency at
# load (array lengths, monotone knots, finite values), in Python and the CLI.
def test_every_model_kind_is_checked_at_load(tmp_path, cli):
    cal = tmp_path / "cal.csv"
    cli("measure", "--distance", "1:8:1", "--reflectance", "0.02,0.1,0.5,0.9", "--temperature",
        "10,25,40", "--out", cal)
    models = {}
    for name, spec in [("chain", ["--chain", "offset,grayvalue,temperature"]),
                       ("poly", ["--surface", "poly:3"]),
                       ("bspline", ["--surface", "bspline", "--knots", "4x4"])]:
        models[name] = tmp_path / f"{name}.json"
        cli("fit", "--in", cal, *spec, "--out", models[name])

    def gray(j):
        return j["steps"][1]["function"]

    def surface(j):
        return j["steps"][0]["surface"]

    mutations = [
        ("chain", lambda j: gray(j)["knots"].reverse()),                     # not ascending
        ("chain", lambda j: gray(j)["slopes"].append(0.1)),                  # lengths differ
        ("chain", lambda j: gray(j).__setitem__("slope0", float("nan"))),
        ("poly", lambda j: surface(j)["coefficients"].pop()),                # lengths differ
        ("poly", lambda j: surface(j)["domain"]["range_m"].reverse()),      # min > max
        ("bspline", lambda j: surface(j)["coefficients"].pop()),
        ("bspline", lambda j: surface(j)["axes"]["range_m"]["knots"].reverse()),
        ("bspline", lambda j: surface(j)["domain"]["amplitude"].__setitem__(1, 1e100)),
        ("chain", lambda j: j["confidence"]["coefficients"].pop()),
    ]
    for k, (name, mutate) in enumerate(mutations):
        model = json.loads(models[name].read_text())
        mutate(model)
        bad = tmp_path / f"bad{k}.json"
        bad.write_text(json.dumps(model).replace("NaN", "1e999"))
        with pytest.raises(ValueError, match=f"bad{k}.json"):
            tofkit.Model.load(bad)
        out = tmp_path / f"out{k}.csv"
        run = cli("correct", "--model", bad, "--in", cal, "--out", out, check=False)
        assert run.returncode == 1 and f"bad{k}.json" in run.stderr, (k, run.stderr)
        assert not out.exists()


def test_the_row_limit_can_be_set_as_with_max_rows():
    before = tofkit.set_max_rows(10)
    try:
        with pytest.raises(ValueError, match="more than 10 "):
            tofkit.measure(np.linspace(1, 2, 11), 0.5, shots=1)
        assert len(tofkit.measure(np.linspace(1, 2, 10), 0.5, shots=1)) == 10
    finally:
        assert tofkit.set_max_rows(before) == 10
    with pytest.raises(ValueError, match="max_rows"):
        tofkit.set_max_rows(0)
