"""measure(): the same grid, streams and numbers as `tofkit measure`."""

import numpy as np
import pytest

import tofkit
from csv_reader import read_table


def assert_same_table(raw, table):
    assert list(raw.dtype.names) == list(table.keys())
    for name in raw.dtype.names:
        np.testing.assert_array_equal(raw[name].astype(np.float64), table[name], err_msg=name)


@pytest.mark.parametrize("mode", ["analytic", "waveform"])
def test_same_seed_gives_the_cli_numbers(cli, tmp_path, mode):
    out = tmp_path / "raw.csv"
    shots = 200 if mode == "analytic" else 20
    cli("measure", "--distance", "0.5,2.5,7", "--reflectance", "0.05,0.9", "--angle", "0,40",
        "--temperature", "5,35", "--count", "2", "--shots", shots, "--seed", "7",
        "--mode", mode, "--out", out)
    raw = tofkit.measure([0.5, 2.5, 7], [0.05, 0.9], angle_deg=[0, 40], temperature_c=[5, 35],
                         count=2, shots=shots, seed=7, mode=mode)
    assert len(raw) == 3 * 2 * 2 * 2 * 2
    # Distance outermost, repeats innermost (the CLI's Cartesian product order).
    assert list(raw["distance_true_m"][::16]) == [0.5, 2.5, 7]
    assert list(raw["ambient_c"][:4]) == [5, 5, 35, 35]
    assert_same_table(raw, read_table(out))


def test_defaults_and_config_match_the_cli(cli, tmp_path):
    out = tmp_path / "raw.csv"
    cli("--preset", "accurange", "--set", "receiver.bandwidth_mhz=80", "measure", "--distance",
        "1:3:1", "--reflectance", "0.5", "--seed", "0", "--out", out)
    config = tofkit.DeviceConfig("accurange", set={"receiver.bandwidth_mhz": 80})
    raw = tofkit.measure(np.arange(1.0, 4.0), 0.5, config=config)
    assert_same_table(raw, read_table(out))
    # read_raw reads the CLI's file back bit for bit.
    np.testing.assert_array_equal(tofkit.read_raw(out), raw)


def test_seed_selects_the_run():
    a = tofkit.measure(3.0, 0.2, count=4, seed=1)
    b = tofkit.measure(3.0, 0.2, count=4, seed=1)
    c = tofkit.measure(3.0, 0.2, count=4, seed=2)
    np.testing.assert_array_equal(a, b)
    assert not np.array_equal(a["tof_ns"], c["tof_ns"])
    # Repeats of one grid point are independent draws.
    assert len(np.unique(a["tof_ns"])) == 4


@pytest.mark.parametrize("kwargs, message", [
    (dict(distance_m=0, reflectance=0.1), "distance_m: 0 is outside [0.001, 100000]"),
    (dict(distance_m=1, reflectance=1.5), "reflectance: 1.5 is outside [0, 1]"),
    (dict(distance_m=1, reflectance=0.1, angle_deg=90), "angle_deg: 90 is outside [0, 89.9]"),
    (dict(distance_m=1, reflectance=0.1, temperature_c=200),
     "temperature_c: 200 is outside [-60, 150]"),
    (dict(distance_m=1, reflectance=0.1, count=0), "count: 0 is below 1"),
    (dict(distance_m=1, reflectance=0.1, shots=0), "shots: 0 is outside [1, 10000000]"),
    (dict(distance_m=1, reflectance=0.1, shots=10**12),
     "shots: 1000000000000 is outside [1, 10000000]"),
    (dict(distance_m=1, reflectance=0.1, mode="fast"), "mode: 'fast' is not analytic or waveform"),
    (dict(distance_m=1, reflectance=0.1, shots="x"), "shots: expected an integer, got 'x'"),
    (dict(distance_m=1, reflectance=0.1, count=None), "count: expected an integer, got None"),
    (dict(distance_m=1, reflectance=0.1, seed=2.5), "seed: expected an integer, got 2.5"),
    (dict(distance_m=1, reflectance=0.1, seed=-1), "seed: -1 is outside [0, 18446744073709551615]"),
    (dict(distance_m=1, reflectance=0.1, seed=2**64),
     "seed: 18446744073709551616 is outside [0, 18446744073709551615]"),
    (dict(distance_m=1, reflectance=0.1, count=2**31),  # beyond a C int: a pybind TypeError
     "count: 2147483648 is outside [-2147483648, 2147483647]"),
    (dict(distance_m=1, reflectance=0.1, mode=None), "mode: 'None' is not analytic or waveform"),
    (dict(distance_m=[], reflectance=0.1), "distance_m: no values"),
    (dict(distance_m=np.full(10001, 1.0), reflectance=np.full(10001, 0.5)),
     "the grid has 1.0002e+08 rows, more than 1e+06 (the row limit of the CLI's --max-rows)"),
])
def test_bad_arguments_raise_value_error(kwargs, message):
    with pytest.raises(ValueError) as error:
        tofkit.measure(**kwargs)
    assert str(error.value) == message


def test_nan_is_rejected():
    with pytest.raises(ValueError, match="distance_m: nan is outside"):
        tofkit.measure(float("nan"), 0.1)


def test_a_config_that_is_not_one_is_refused_by_name():
    with pytest.raises(TypeError, match="config: expected a tofkit.DeviceConfig or None, got str"):
        tofkit.measure(1.0, 0.5, config="paper")
