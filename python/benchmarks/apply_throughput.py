#!/usr/bin/env python3
"""Correction throughput from Python vs the C++ batch, in the same run.

Corrects 10 M rows with a fitted chain (offset, gray value, temperature) by
Model.apply from three input layouts, each read in place through
ranging::RawColumns (a pointer and byte stride per field): RAW_DTYPE rows
(48 B, RawMeasurement's own layout), measure()'s RECORD_DTYPE records (80 B
rows: the strided case) and a dict of seven column arrays; and by
ranging::Pipeline::apply called from C++ on a std::vector of the same rows
(tofkit._tofkit._CppBaseline): the 48-byte RawMeasurement vector (the
acceptance's baseline) and a vector of 80-byte Records read through
RawColumns (as `tofkit correct` does), which shows what the wider rows cost
in memory traffic whichever language calls. Two comparisons of the same work:
  - into a reused output: Model.apply(raw, out=buffer) vs Pipeline::apply into
    a reused std::vector;
  - allocating the output per call: Model.apply(raw) vs a new std::vector per
    call (as `tofkit correct` does).
C++ and Python runs alternate and the best of REPEATS of each counts, so a
busy machine slows both alike. Not a test: speed depends on the machine.

    PYTHONPATH=build/python /usr/bin/python3 python/benchmarks/apply_throughput.py [ROWS]
"""

import sys
import time

import numpy as np

import tofkit
from tofkit import _tofkit
from tofkit.model import _columns

ROWS = int(float(sys.argv[1])) if len(sys.argv) > 1 else 10_000_000
REPEATS = 7
RAW_FIELDS = ["tof_ns", "distance_raw_m", "pulse_width_ns", "amplitude", "temperature_c",
              "shots_valid", "flags"]


def synthetic(rows):
    rng = np.random.default_rng(1)
    data = np.zeros(rows, dtype=tofkit.RECORD_DTYPE)
    data["tof_ns"] = rng.uniform(5, 60, rows)
    data["distance_raw_m"] = data["tof_ns"] * 0.15
    data["pulse_width_ns"] = rng.uniform(3, 12, rows)
    data["amplitude"] = rng.uniform(0.01, 2, rows)
    data["temperature_c"] = rng.uniform(0, 40, rows)
    data["shots_valid"] = 100
    return data


def timed(work):
    start = time.perf_counter()
    result = work()
    seconds = time.perf_counter() - start
    del result
    return seconds


def main():
    calibration = tofkit.measure(np.arange(0.5, 8.01, 0.5), [0.05, 0.2, 0.9],
                                 temperature_c=[0, 15, 25, 40], count=2, shots=100, seed=3)
    model = tofkit.fit_chain(calibration)
    records = synthetic(ROWS)
    packed = np.zeros(ROWS, dtype=tofkit.RAW_DTYPE)
    for n in RAW_FIELDS:
        packed[n] = records[n]
    columns = {n: np.ascontiguousarray(records[n]) for n in RAW_FIELDS}
    baseline = _tofkit._CppBaseline(model._model, _columns(packed))
    reused = np.zeros(ROWS, dtype=tofkit.RANGE_DTYPE)  # pages touched, as the C++ vector's

    print(f"{ROWS / 1e6:g} M rows, best of {REPEATS} alternating runs; M rows/s, and Python's "
          "ratio to C++ on 48 B rows (the acceptance: >= 0.8) and on 80 B records")
    print(f"{'input layout, output':42s} {'C++ 48 B':>9s} {'C++ 80 B':>9s} {'Python':>7s} "
          f"{'ratio':>6s} {'vs 80 B':>8s}")
    for name, data in [("RawMeasurement rows (48 B)", packed),
                       ("measure() records (80 B)", records),
                       ("dict of 7 column arrays", columns)]:
        for allocate in (False, True):
            cpp = cpp_records = py = float("inf")
            for _ in range(REPEATS):
                cpp = min(cpp, baseline.run(allocate))
                cpp_records = min(cpp_records, baseline.run(allocate, records=True))
                if allocate:
                    py = min(py, timed(lambda: model.apply(data)))
                else:
                    py = min(py, timed(lambda: model.apply(data, out=reused)))
            label = f"{name}, {'new output' if allocate else 'reused output'}"
            print(f"{label:42s} {ROWS / cpp / 1e6:9.1f} {ROWS / cpp_records / 1e6:9.1f} "
                  f"{ROWS / py / 1e6:7.1f} {cpp / py:6.2f} {cpp_records / py:8.2f}")


if __name__ == "__main__":
    main()
