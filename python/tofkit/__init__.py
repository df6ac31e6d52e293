"""tofkit from Python: the virtual pulsed time-of-flight rangefinder, the
ranging pipeline and its calibration, on NumPy arrays.

A thin layer over the C++ core (``tofkit._tofkit``)::

    import tofkit
    raw = tofkit.measure([1, 2, 5], [0.1, 0.9], count=10, seed=1)
    model = tofkit.fit_chain(raw)
    distance, sigma, flags = model.apply(raw)
    blocks = tofkit.scan("examples/scenes/blocks.toml", "spherical",
                         azimuth="-15:15:0.5", elevation="-15:15:0.5", shots=10)
    blocks.range  # a 2-D image, m; blocks.points: (N, 10)

Errors in keys, files or values raise ValueError (FileNotFoundError for a
missing file) with the command-line tool's message.
"""

from ._tofkit import RANGE_DTYPE, RAW_DTYPE, RECORD_DTYPE, read_raw, set_max_rows
from .device import DeviceConfig, link_budget, measure
from .model import Model, fit_chain, fit_surface
from .scanning import BEAM_DTYPE, POINT_COLUMNS, ScanResult, scan
from .sweeping import SweepPlan, sweep

RAW_COLUMNS = RECORD_DTYPE.names
"""The raw CSV columns, in file order (the fields of measure()'s result).
RAW_DTYPE holds the device's columns only, in the C++ RawMeasurement layout.
Model.apply reads either, or float64/uint32 columns, in place."""

__all__ = [
    "BEAM_DTYPE",
    "DeviceConfig",
    "Model",
    "POINT_COLUMNS",
    "RANGE_DTYPE",
    "RAW_COLUMNS",
    "RAW_DTYPE",
    "RECORD_DTYPE",
    "ScanResult",
    "SweepPlan",
    "fit_chain",
    "fit_surface",
    "link_budget",
    "sweep",
    "measure",
    "read_raw",
    "scan",
    "set_max_rows",
]
