"""tofkit from Python: the virtual pulsed time-of-flight rangefinder, the
ranging pipeline and its calibration, on NumPy arrays.

A thin layer over the C++ core (``tofkit._tofkit``)::

    import tofkit
    raw = tofkit.measure([1, 2, 5], [0.1, 0.9], count=10, seed=1)
    model = tofkit.fit_chain(raw)
    distance, sigma, flags = model.apply(raw)

Errors in keys, files or values raise ValueError (FileNotFoundError for a
missing file) with the command-line tool's message.
"""

from ._tofkit import RANGE_DTYPE, RAW_DTYPE, RECORD_DTYPE, read_raw
from .device import DeviceConfig, link_budget, measure
from .model import Model, fit_chain, fit_surface

RAW_COLUMNS = RECORD_DTYPE.names
"""The raw CSV columns, in file order (the fields of measure()'s result).
RAW_DTYPE holds the device's columns only, in the C++ RawMeasurement layout:
the fastest input of Model.apply (no gather)."""

__all__ = [
    "DeviceConfig",
    "Model",
    "RANGE_DTYPE",
    "RAW_COLUMNS",
    "RAW_DTYPE",
    "RECORD_DTYPE",
    "fit_chain",
    "fit_surface",
    "link_budget",
    "measure",
    "read_raw",
]
