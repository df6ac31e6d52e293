"""Model.apply reads a 10 M-row input in place: the process grows by the
output array, not by a copy of the input."""

import gc

import numpy as np
import pytest

import tofkit
from conftest import pauses_of_another_thread

ROWS = 10_000_000


def status_kb(field):
    with open("/proc/self/status") as f:
        for line in f:
            if line.startswith(field + ":"):
                return int(line.split()[1])
    pytest.skip(f"/proc/self/status has no {field}")


def peak_growth_bytes(work):
    """Peak resident memory growth while work() runs (Linux: VmHWM reset via clear_refs)."""
    gc.collect()
    try:
        with open("/proc/self/clear_refs", "w") as f:
            f.write("5")
    except OSError:
        pytest.skip("cannot reset the peak RSS")
    before = status_kb("VmRSS")
    result = work()
    return (status_kb("VmHWM") - before) * 1024, result


@pytest.fixture(scope="module")
def model():
    records = tofkit.measure(np.arange(1.0, 8.0, 0.5), [0.05, 0.3, 0.9],
                             temperature_c=[0, 20, 40], count=2, shots=100, seed=5)
    return tofkit.fit_chain(records)


def synthetic(rows, dtype):
    rng = np.random.default_rng(1)
    data = np.empty(rows, dtype=dtype)
    for name in data.dtype.names:
        data[name] = 0
    data["tof_ns"] = rng.uniform(5, 60, rows)
    data["distance_raw_m"] = data["tof_ns"] * 0.15
    data["pulse_width_ns"] = rng.uniform(3, 12, rows)
    data["amplitude"] = rng.uniform(0.01, 2, rows)
    data["temperature_c"] = rng.uniform(0, 40, rows)
    data["shots_valid"] = 100
    return data


@pytest.mark.parametrize("layout", ["records", "raw_columns"])
def test_ten_million_rows_are_not_copied(model, layout):
    data = synthetic(ROWS, tofkit.RECORD_DTYPE)  # 800 MB, measure()'s layout
    if layout == "raw_columns":
        # Separate columns of mixed dtypes: read through their strides.
        data = {"tof_ns": data["tof_ns"], "pulse_width_ns": data["pulse_width_ns"],
                "amplitude": data["amplitude"],
                "temperature_c": data["temperature_c"].astype(np.float32),
                "shots_valid": data["shots_valid"].astype(np.int16)}
    head = ({k: v[:1000].copy() for k, v in data.items()} if isinstance(data, dict)
            else data[:1000].copy())
    expected = [a.copy() for a in model.apply(head)]
    growth, (distance, sigma, flags) = peak_growth_bytes(lambda: model.apply(data))
    output_bytes = ROWS * tofkit.RANGE_DTYPE.itemsize  # one allocation out: 240 MB
    input_bytes = sum(a.nbytes for a in data.values()) if isinstance(data, dict) else data.nbytes
    print(f"\n{layout}: input {input_bytes / 1e6:.0f} MB, output {output_bytes / 1e6:.0f} MB, "
          f"peak growth {growth / 1e6:.1f} MB")
    assert distance.base is sigma.base is flags.base  # views of the one output array
    assert growth < output_bytes + 16e6  # a copy of the input would add >= 240 MB
    # The same ranges as for a small copy of the first rows.
    for got, want in zip((distance, sigma, flags), expected):
        np.testing.assert_array_equal(got[:1000], want)


def test_the_gil_is_released_while_correcting(model):
    """Another Python thread keeps running during a long Model.apply: the
    largest pause it sees is well below the call's duration."""
    data = synthetic(ROWS, tofkit.RAW_DTYPE)
    out = np.empty(len(data), dtype=tofkit.RANGE_DTYPE)
    model.apply(data, out=out)  # the first call also faults in out's pages
    gaps, ran = pauses_of_another_thread(lambda: model.apply(data, out=out))
    gaps = np.array(gaps)
    print(f"\napply {ran * 1e3:.0f} ms; longest pause of the other thread "
          f"{gaps.max() * 1e3:.1f} ms over {len(gaps)} ticks")
    assert len(gaps) > 100
    assert gaps.max() < 0.5 * ran
