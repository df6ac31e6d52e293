"""link_budget(): the CLI's numbers, and the closed-form scaling laws."""

import json

import numpy as np
import pytest

import tofkit


def test_matches_tofkit_budget(cli):
    printed = json.loads(cli("budget", "--json", "--reflectance", "0.3", "--angle", "20").stdout)
    rows = printed["rows"]
    distances = [r["distance_m"] for r in rows]
    budget = tofkit.link_budget(distances, reflectance=0.3, angle_deg=20)
    names = {"received_power_w": "received_power_w", "background_power_w": "background_power_w",
             "signal_current_a": "signal_current_a", "noise_signal_shot_a": "signal_shot_a",
             "noise_dark_shot_a": "dark_shot_a", "noise_thermal_a": "thermal_a",
             "noise_total_a": "total_noise_a", "snr": "snr"}
    for ours, theirs in names.items():
        np.testing.assert_array_equal(budget[ours], [r[theirs] for r in rows], err_msg=ours)


def test_extended_target_power_falls_as_inverse_square():
    # Beyond a few metres the footprint is inside the plate: Pr ~ rho cos(phi) / R^2 (paper Eq. 6).
    b = tofkit.link_budget([10.0, 20.0], reflectance=0.2)
    np.testing.assert_allclose(b["received_power_w"][1] / b["received_power_w"][0], 0.25,
                               rtol=1e-3)
    doubled = tofkit.link_budget([10.0], reflectance=0.4)
    np.testing.assert_allclose(doubled["received_power_w"][0] / b["received_power_w"][0], 2.0,
                               rtol=1e-12)


@pytest.mark.parametrize("kwargs, message", [
    (dict(distance_m=[-1.0]), "distance_m: -1 is outside [0.001, 100000]"),
    (dict(distance_m=[0.0]), "distance_m: 0 is outside [0.001, 100000]"),
    (dict(distance_m=[1.0, float("nan")]), "distance_m: nan is outside [0.001, 100000]"),
    (dict(distance_m=[1e300]), "distance_m: 1e+300 is outside [0.001, 100000]"),
    (dict(distance_m=[1.0], reflectance=2), "reflectance: 2 is outside [0, 1]"),
    (dict(distance_m=[1.0], angle_deg=90), "angle_deg: 90 is outside [0, 89.9]"),
    (dict(distance_m=[1.0], temperature_c=1e9), "temperature_c: 1000000000 is outside [-60, 150]"),
    (dict(distance_m=[1.0], reflectance="a"), "reflectance: expected a number, got 'a'"),
    (dict(distance_m=[1.0], angle_deg=None), "angle_deg: expected a number, got None"),
])
def test_arguments_outside_measure_s_ranges_raise(kwargs, message):
    # A negative distance had given a positive power, 0 m an infinite SNR,
    # without a word: the ranges are measure()'s (one check, PlateGrid's).
    with pytest.raises(ValueError) as error:
        tofkit.link_budget(**kwargs)
    assert str(error.value) == message
