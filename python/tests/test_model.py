"""Models: the CLI's JSON in and out, fits equal to `tofkit fit`, apply equal
to `tofkit correct`, whatever the layout of the input."""

import json

import numpy as np
import pytest

import tofkit
from conftest import cli_error
from csv_reader import read_table


@pytest.fixture(scope="module")
def calibration(tmp_path_factory, cli):
    """A calibration CSV written by the CLI, and the same records from measure()."""
    path = tmp_path_factory.mktemp("calib") / "calib.csv"
    args = dict(distance="0.5:8:0.5", reflectance="0.05,0.2,0.9", temperature="0,15,25,40")
    cli("measure", "--distance", args["distance"], "--reflectance", args["reflectance"],
        "--temperature", args["temperature"], "--count", "2", "--shots", "100", "--seed", "3",
        "--out", path)
    return path, tofkit.read_raw(path)


def model_core(j):
    """The model file without the free-form fit statistics."""
    return {k: v for k, v in j.items() if k != "fit"}


def test_fit_chain_equals_tofkit_fit(cli, tmp_path, calibration):
    path, records = calibration
    cli_model = tmp_path / "cli.json"
    cli("fit", "--confidence", "none", "--in", path, "--chain", "offset,grayvalue,temperature", "--out", cli_model)
    model = tofkit.fit_chain(records)
    ours = tmp_path / "py.json"
    model.save(ours)
    theirs = json.loads(cli_model.read_text())
    assert model_core(json.loads(ours.read_text())) == model_core(theirs)
    assert model.fit["chain"] == theirs["fit"]["chain"]
    assert "chain fit" in model.report


def test_fit_surface_equals_tofkit_fit(cli, tmp_path, calibration):
    path, records = calibration
    cli_model = tmp_path / "cli.json"
    cli("fit", "--confidence", "none", "--in", path, "--chain", "offset,grayvalue", "--surface", "poly:3", "--rcond",
        "0.05", "--out", cli_model)
    chain = tofkit.fit_chain(records, steps="offset,grayvalue")
    model = tofkit.fit_surface(records, "poly:3", rcond=0.05, chain=chain)
    theirs = json.loads(cli_model.read_text())
    assert model_core(model.to_json()) == model_core(theirs)
    # A surface alone, with a temperature axis.
    cli("fit", "--confidence", "none", "--in", path, "--surface", "poly:2", "--temperature", "--out", cli_model)
    alone = tofkit.fit_surface(records, "poly:2", temperature=True)
    assert model_core(alone.to_json()) == model_core(json.loads(cli_model.read_text()))
    cli("fit", "--confidence", "none", "--in", path, "--surface", "bspline", "--out", cli_model)
    spline = tofkit.fit_surface(records, "bspline")
    assert model_core(spline.to_json()) == model_core(json.loads(cli_model.read_text()))


def test_refined_walk_and_confidence_equal_tofkit_fit(cli, tmp_path, calibration):
    path, records = calibration
    cli_model = tmp_path / "cli.json"
    cli("fit", "--in", path, "--chain", "offset,grayvalue,temperature", "--refine-walk", "--out",
        cli_model)
    model = tofkit.fit_chain(records, confidence="calibrated", refine_walk=True)
    theirs = json.loads(cli_model.read_text())
    assert model_core(model.to_json()) == model_core(theirs)
    assert "walk_refinement" in theirs["fit"] and "confidence" in theirs
    with pytest.raises(ValueError, match="refine_walk refines"):
        tofkit.fit_chain(records, steps="offset,temperature", refine_walk=True)


def test_apply_equals_tofkit_correct(cli, tmp_path, calibration):
    path, records = calibration
    model_path = tmp_path / "model.json"
    cli("fit", "--confidence", "none", "--in", path, "--chain", "offset,grayvalue,temperature", "--out", model_path)
    probe = tmp_path / "probe.csv"
    cli("measure", "--distance", "0.3,3,9,20", "--reflectance", "0.02,0.5", "--temperature",
        "-10,20", "--count", "3", "--shots", "50", "--seed", "9", "--out", probe)
    corrected = tmp_path / "corrected.csv"
    cli("correct", "--model", model_path, "--in", probe, "--out", corrected)
    expected = read_table(corrected)
    model = tofkit.Model.load(model_path)
    distance, sigma, flags = model.apply(tofkit.read_raw(probe))
    np.testing.assert_array_equal(distance, expected["distance_m"])
    np.testing.assert_array_equal(sigma, expected["sigma_m"])
    np.testing.assert_array_equal(flags, expected["correction_flags"])
    assert (flags != 0).any()  # the probe leaves the fitted domain and loses echoes


def test_every_input_layout_gives_the_same_ranges(calibration):
    _, records = calibration
    model = tofkit.fit_chain(records)
    expected = [a.copy() for a in model.apply(records)]  # RECORD_DTYPE rows (80 bytes)
    raw_fields = ["tof_ns", "distance_raw_m", "pulse_width_ns", "amplitude", "temperature_c",
                  "shots_valid", "flags"]
    packed = np.empty(len(records), dtype=tofkit.RAW_DTYPE)
    for n in raw_fields:
        packed[n] = records[n]
    assert packed.dtype.itemsize == 48  # RawMeasurement's layout: handed over as is
    assert packed.dtype == np.dtype([(n, records.dtype[n]) for n in raw_fields])
    native_columns = {n: records[n].copy() for n in raw_fields}  # read in place
    columns = dict(native_columns)
    columns["shots_valid"] = columns["shots_valid"].astype(np.int64)  # gathered
    # The other byte order is read too, as the README's "any numeric dtype"
    # says (it had been refused, as float16 below).
    swapped = {n: c.astype(c.dtype.newbyteorder(">")) for n, c in native_columns.items()}
    reversed_view = records[::-1]
    for layout in (packed, native_columns, columns, records[raw_fields], swapped):
        for got, want in zip(model.apply(layout), expected):
            np.testing.assert_array_equal(got, want)
    for got, want in zip(model.apply(reversed_view), expected):
        np.testing.assert_array_equal(got, want[::-1])
    half = dict(native_columns, tof_ns=native_columns["tof_ns"].astype(np.float16))
    distance, _, _ = model.apply(half)
    np.testing.assert_allclose(distance, expected[0], atol=0.02)  # float16: 3 digits of tof


def test_missing_columns_take_the_csv_readers_defaults(calibration):
    _, records = calibration
    model = tofkit.fit_chain(records, steps="offset")
    distance, _, flags = model.apply({"distance_raw_m": records["distance_raw_m"]})
    has_echo = records["shots_valid"] > 0
    np.testing.assert_array_equal(np.isfinite(distance), has_echo)
    np.testing.assert_array_equal(flags[~has_echo], 1)  # kCorrNoEcho


def test_save_load_round_trip(tmp_path, calibration):
    _, records = calibration
    model = tofkit.fit_chain(records)
    first, second = tmp_path / "a.json", tmp_path / "b.json"
    model.save(first)
    tofkit.Model.load(first).save(second)
    assert first.read_bytes() == second.read_bytes()


def test_load_errors_carry_the_cli_message(cli, tmp_path, calibration):
    path, _ = calibration
    missing = tmp_path / "missing.json"
    expected = cli_error(cli("correct", "--model", missing, "--in", path, "--out",
                             tmp_path / "o.csv", check=False))
    with pytest.raises(FileNotFoundError) as error:
        tofkit.Model.load(missing)
    assert str(error.value) == expected
    bad = tmp_path / "bad.json"
    bad.write_text('{"kind": "tofkit.pipeline", "version": 1, "steps": [{"kind": "hinge"}]}')
    expected = cli_error(cli("correct", "--model", bad, "--in", path, "--out",
                             tmp_path / "o.csv", check=False))
    with pytest.raises(ValueError) as error:
        tofkit.Model.load(bad)
    assert str(error.value) == expected


def test_one_target_is_refused_as_by_tofkit_fit(cli, tmp_path):
    """12 repeats of one plate (one distance, reflectance and ambient): the
    pulse width and the temperature reading spread by noise only, so each step
    that would model them is refused with the CLI's message, naming the column."""
    path = tmp_path / "one.csv"
    cli("measure", "--distance", "2", "--reflectance", "0.3", "--temperature", "20", "--count",
        "12", "--shots", "200", "--out", path)
    records = tofkit.read_raw(path)
    out = tmp_path / "model.json"
    for steps, column in [("offset,walk", "pulse_width_ns"), ("offset,grayvalue", "pulse_width_ns"),
                          ("offset,temperature", "temperature_c")]:
        expected = cli_error(cli("fit", "--confidence", "none", "--in", path, "--chain", steps,
                                 "--out", out, check=False))
        with pytest.raises(ValueError, match=f"no spread in {column} between") as error:
            tofkit.fit_chain(records, steps=steps)
        assert expected == f"{path}: {error.value}"
        assert "is noise" in str(error.value)
        assert not out.exists()


def test_bad_inputs_raise(calibration):
    _, records = calibration
    model = tofkit.fit_chain(records)
    with pytest.raises(ValueError, match="needs tof_ns or distance_raw_m"):
        model.apply({"amplitude": records["amplitude"]})
    with pytest.raises(ValueError, match="rows"):
        model.apply({"tof_ns": records["tof_ns"], "amplitude": records["amplitude"][:5]})
    with pytest.raises(TypeError, match="tof_ns"):
        model.apply({"tof_ns": np.array(["a", "b"])})
    with pytest.raises(ValueError, match="1-D"):
        model.apply({"tof_ns": np.zeros((2, 2))})
    with pytest.raises(TypeError):
        model.apply(np.zeros(3))
    with pytest.raises(ValueError, match="steps offset,gray"):
        tofkit.fit_chain(records, steps="offset,gray")
    with pytest.raises(ValueError, match="too few rows"):
        tofkit.fit_chain(records[:5])
    with pytest.raises(ValueError, match="surface poly:x: expected poly:N"):
        tofkit.fit_surface(records, "poly:x")
    with pytest.raises(ValueError, match="rcond applies"):
        tofkit.fit_surface(records, "bspline", rcond=0.1)
    # Arguments of the wrong kind are refused by name (they had surfaced
    # pybind's "incompatible function arguments", or an AttributeError).
    with pytest.raises(ValueError, match="rcond: expected a number, got 'small'"):
        tofkit.fit_surface(records, rcond="small")
    with pytest.raises(TypeError, match="chain: expected a tofkit.Model or None, got int"):
        tofkit.fit_surface(records, chain=3)
    # A string is not a number nor a flag ('0.1' had been read, 'False' was true).
    with pytest.raises(ValueError, match="rcond: expected a number, got '0.1'"):
        tofkit.fit_surface(records, rcond="0.1")
    with pytest.raises(TypeError, match="temperature: expected True or False, got 'False'"):
        tofkit.fit_surface(records, "poly:3", temperature="False")
    with pytest.raises(TypeError, match="config: expected a tofkit.DeviceConfig or None, got str"):
        tofkit.fit_chain(records, config="paper")
    empty_distance, _, _ = model.apply(records[:0])
    assert empty_distance.shape == (0,)


def test_chain_steps_as_a_list_are_the_cli_s_list(calibration):
    _, records = calibration
    as_list = tofkit.fit_chain(records, ["offset", "grayvalue"])
    as_text = tofkit.fit_chain(records, "offset,grayvalue")
    assert as_list.to_json() == as_text.to_json()


def test_apply_into_a_reused_output(calibration):
    _, records = calibration
    model = tofkit.fit_chain(records)
    expected = [a.copy() for a in model.apply(records)]
    out = np.zeros(len(records), dtype=tofkit.RANGE_DTYPE)
    result = model.apply(records, out=out)
    for got, want in zip(result, expected):
        np.testing.assert_array_equal(got, want)
    assert result[0].base is out or result[0].base is out.base
    np.testing.assert_array_equal(out["distance_m"], expected[0])
    with pytest.raises(ValueError, match="rows"):
        model.apply(records, out=out[:-1])
    with pytest.raises(TypeError, match="RANGE_DTYPE"):
        model.apply(records, out=np.zeros(len(records)))
    with pytest.raises(TypeError, match="RANGE_DTYPE"):
        model.apply(records[::2], out=np.zeros(2 * len(records[::2]), tofkit.RANGE_DTYPE)[::2])


def test_budget_travels_and_sets_sigma_as_tofkit_correct(cli, tmp_path, calibration):
    """A model fitted with `tofkit fit --budget`: Python reads its budget, keeps
    it on save, and applies it as `tofkit correct --since-calibration` does."""
    path, records = calibration
    model_path = tmp_path / "budget.json"
    cli("fit", "--in", path, "--chain", "offset,grayvalue,temperature", "--budget", "--out",
        model_path)
    model = tofkit.Model.load(model_path)
    names = [c["name"] for c in model.budget["components"]]
    assert "repeatability (one row)" in names and "drift since calibration" in names
    # One power-on, no stability record: named as unobserved.
    assert any("power-on" in u for u in model.budget["unobserved"])
    resaved = tmp_path / "resaved.json"
    model.save(resaved)
    assert json.loads(resaved.read_text())["uncertainty_budget"] == \
        json.loads(model_path.read_text())["uncertainty_budget"]
    for since in (None, 600.0):
        corrected = tmp_path / "corrected.csv"
        extra = [] if since is None else ["--since-calibration", str(since)]
        cli("correct", "--model", model_path, "--in", path, *extra, "--out", corrected)
        theirs = read_table(corrected)
        _, sigma, _ = model.apply(records, since_calibration_s=since)
        assert np.allclose(sigma, theirs["sigma_m"], rtol=1e-12, atol=0, equal_nan=True)
