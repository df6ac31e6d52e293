#!/usr/bin/env python3
"""Scan the "blocks" scene (examples/scenes/blocks.toml: step edges, a roof
edge, a cylinder and a ball in front of a wall) with a spherical pattern and
show the range and intensity images; mixed pixels at the edges show as range
values between foreground and background.

    PYTHONPATH=build/python /usr/bin/python3 python/examples/03_scan_blocks.py [out.png [STEP_DEG]]

Saves the figure (default blocks_range.png) and shows it when there is a
display (Matplotlib's Agg backend otherwise). STEP_DEG: the angular step of
the 30 x 30 degree grid (default 0.1: 301 x 301 beams).
"""

import os
import pathlib
import sys
import time

import matplotlib

if not (os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY")):
    matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

import tofkit  # noqa: E402

SCENE = pathlib.Path(__file__).resolve().parents[2] / "examples" / "scenes" / "blocks.toml"

out = sys.argv[1] if len(sys.argv) > 1 else "blocks_range.png"
step = float(sys.argv[2]) if len(sys.argv) > 2 else 0.1
grid = f"-15:15:{step}"  # the CLI's list syntax, expanded as `tofkit scan` does

# 16 rays over each beam's footprint (the default config casts its axis only):
# a footprint across an edge sees two surfaces and reports a mixed range.
config = tofkit.DeviceConfig(set={"scan.rays_per_beam": 16})
start = time.perf_counter()
scan = tofkit.scan(SCENE, "spherical", azimuth=grid, elevation=grid, shots=10, seed=1,
                   config=config)
seconds = time.perf_counter() - start
mixed = scan.beams[scan.beams["surfaces"] > 1]  # one beam per pixel in a spherical scan
print(f"{scan}: {seconds:.2f} s; {len(mixed)} mixed pixels, "
      f"{np.isnan(scan.range).sum()} pixels without echo")

# The error against the true range of each beam's axis (uncorrected: the
# device's offsets remain); a mixed pixel's range lies between its surfaces'.
error = scan.range - scan.truth
median = np.nanmedian(error)
mixed_error = error[mixed["row"], mixed["column"]] - median
print(f"range - truth: median {median * 1e3:.0f} mm; beyond that median, "
      f"{np.nanmedian(np.abs(error - median)) * 1e3:.1f} mm typical, "
      f"{np.nanmedian(np.abs(mixed_error)) * 1e3:.0f} mm at mixed pixels")

fig, (ax_range, ax_intensity) = plt.subplots(1, 2, figsize=(11, 4.8))
extent = (15, -15, -15, 15)  # column 0 is the left (largest azimuth), row 0 the top
image = ax_range.imshow(scan.range, cmap="turbo", extent=extent)
fig.colorbar(image, ax=ax_range, label="range, m")
ax_range.set_title("range")
image = ax_intensity.imshow(scan.intensity, cmap="gray", extent=extent)
fig.colorbar(image, ax=ax_intensity, label="echo amplitude, V")
ax_intensity.set_title("intensity")
for ax in (ax_range, ax_intensity):
    ax.set_xlabel("azimuth, degrees")
    ax.set_ylabel("elevation, degrees")
fig.tight_layout()
fig.savefig(out, dpi=110)
print(f"wrote {out}")
if matplotlib.get_backend().lower() != "agg":
    plt.show()
