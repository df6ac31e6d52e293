#!/usr/bin/env python3
"""Calibrate the virtual rangefinder and plot its range error against the echo
pulse width (the paper's "gray value", Section 5.1), before and after the
fitted correction chain.

    PYTHONPATH=build/python /usr/bin/python3 python/examples/01_calibrate_gray_value.py [out.png]
"""

import sys

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

import tofkit  # noqa: E402

# Plates from 0.5 m to 8 m, dark to white, at three temperatures: the pulse
# width spans weak (narrow) to saturated (wide) echoes.
calibration = tofkit.measure(np.arange(0.5, 8.01, 0.25), [0.05, 0.2, 0.5, 0.9],
                             temperature_c=[10, 25, 40], count=3, shots=200, seed=1)
model = tofkit.fit_chain(calibration, steps="offset,grayvalue,temperature")
print(model.report)

# An independent check set (another seed, other distances).
check = tofkit.measure(np.arange(0.6, 8.0, 0.4), [0.1, 0.3, 0.8], temperature_c=[15, 30],
                       count=2, shots=200, seed=2)
distance, sigma, flags = model.apply(check)
ok = check["shots_valid"] > 0
before = (check["distance_true_m"] - check["distance_raw_m"])[ok]
after = (check["distance_true_m"] - distance)[ok]
print(f"check set: {ok.sum()} rows, RMS error {np.sqrt(np.mean(before**2)) * 1e3:.1f} mm before, "
      f"{np.sqrt(np.mean(after**2)) * 1e3:.1f} mm after (sigma {sigma[ok].mean() * 1e3:.1f} mm)")

out = sys.argv[1] if len(sys.argv) > 1 else "gray_value_calibration.png"
fig, ax = plt.subplots(figsize=(7, 4))
ax.scatter(check["pulse_width_ns"][ok], before * 1e3, s=6, label="before (true - raw)")
ax.scatter(check["pulse_width_ns"][ok], after * 1e3, s=6, label="after the chain")
ax.set_xlabel("echo pulse width, ns")
ax.set_ylabel("range error, mm")
ax.legend()
fig.tight_layout()
fig.savefig(out, dpi=120)
print(f"wrote {out}")
