#!/usr/bin/env python3
"""The link budget beside what the virtual rangefinder measures: the SNR over
distance (paper Eq. 8) for a dark plate, the share of single shots that
still give an echo, and the spread of those shots' ranges.

    PYTHONPATH=build/python /usr/bin/python3 python/examples/02_link_budget_and_noise.py [out.png]
"""

import sys

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

import tofkit  # noqa: E402

config = tofkit.DeviceConfig("paper")
distances = np.arange(1.0, 12.01, 1.0)
budget = tofkit.link_budget(distances, reflectance=0.1, config=config)

# 50 single-shot measurements per distance: their spread is the timing jitter.
raw = tofkit.measure(distances, 0.1, count=50, shots=1, seed=4, config=config)
echo = raw["shots_valid"] > 0
spread_mm, echo_share = [], []
for d in distances:
    at = (raw["distance_true_m"] == d) & echo
    echo_share.append(at.sum() / (raw["distance_true_m"] == d).sum())
    spread_mm.append(np.std(raw["distance_raw_m"][at]) * 1e3 if at.sum() > 1 else np.nan)
for d, snr, share, s in zip(distances, budget["snr"], echo_share, spread_mm):
    print(f"{d:5.1f} m  SNR {snr:6.1f}  echoes {share:4.0%}  single-shot spread {s:5.1f} mm")

out = sys.argv[1] if len(sys.argv) > 1 else "link_budget_noise.png"
fig, ax = plt.subplots(figsize=(7, 4))
ax.semilogy(distances, budget["snr"], "o-", label="SNR (link budget, rho = 0.1)")
ax.semilogy(distances, spread_mm, "s-", label="single-shot spread, mm")
ax.set_xlabel("distance, m")
ax.legend()
fig.tight_layout()
fig.savefig(out, dpi=120)
print(f"wrote {out}")
