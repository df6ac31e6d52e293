"""The device side: configurations, the virtual rangefinder, the link budget."""

import numpy as np

from . import _tofkit


DeviceConfig = _tofkit.DeviceConfig
"""DeviceConfig(preset=None, file=None, set=None): a device configuration, as
the CLI's --preset, --config and --set (``set``: a dict {"receiver.bandwidth_mhz":
120} or "section.key=value" strings, applied after the file). Raises ValueError
(FileNotFoundError for a missing file) with the CLI's message. Has ``dump()``
(TOML), ``config["section.key"]``, ``to_dict()``, ``name`` and the static
``presets()``."""


def _values(x, name):
    given = np.atleast_1d(np.asarray(x))
    if given.dtype.kind not in "iuf":
        # (np.asarray(..., float64) would read "2" and True as numbers)
        raise ValueError(f"{name}: expected numbers, got {given.dtype} values")
    values = given.astype(np.float64)
    if values.ndim != 1:
        raise ValueError(f"{name}: expected a number or a 1-D list")
    return [float(v) for v in values]


def _config(config):
    """The device of a call: a DeviceConfig, or None for the default one."""
    if config is None:
        return DeviceConfig()
    if not isinstance(config, DeviceConfig):
        raise TypeError(f"config: expected a tofkit.DeviceConfig or None, got "
                        f"{type(config).__name__}")
    return config


def _float(value, name):
    """A real argument; anything else (a string, None, a bool) is refused by
    name. NaN and infinities pass: the C++ side checks every range."""
    try:
        # (float('0.05') would read a string: refused, as the docstring says)
        as_float = None if isinstance(value, (str, bytes)) else float(value)
    except (TypeError, ValueError):
        as_float = None
    if as_float is None or isinstance(value, bool):
        raise ValueError(f"{name}: expected a number, got {value!r}")
    return as_float


def measure(distance_m, reflectance, angle_deg=None, temperature_c=None, shots=None, count=1,
            seed=0, mode="analytic", config=None):
    """Measure plates with the virtual rangefinder, as ``tofkit measure``.

    Each of distance_m, reflectance, angle_deg (default 0) and temperature_c
    (default 20 C ambient) is a number or a list; the rows are their Cartesian
    product, distance outermost, repeats (count) innermost, and row i uses
    random stream i: the same arguments and seed give the same numbers as
    ``tofkit measure``. shots: shots averaged per row (None: the config's).
    mode: "analytic" or "waveform".

    Returns a structured array with the raw CSV columns (RAW_COLUMNS).
    """
    grid = _tofkit._PlateGrid()
    grid.distances_m = _values(distance_m, "distance_m")
    grid.reflectances = _values(reflectance, "reflectance")
    if angle_deg is not None:
        grid.angles_deg = _values(angle_deg, "angle_deg")
    if temperature_c is not None:
        grid.ambient_c = _values(temperature_c, "temperature_c")
    grid.count = _int(count, "count")
    # (None: the config's; else as tofkit measure --shots)
    grid.shots = 0 if shots is None else _int(shots, "shots", 1, 10_000_000)
    return _tofkit._measure(_config(config), grid, _seed(seed), str(mode))


def _int(value, name, lo=-2**31, hi=2**31 - 1):
    """An integral argument in [lo, hi] (by default a C int's range: the C++
    side checks the argument's own range); anything else (a fraction, a
    string, None, 2**40) is refused by name."""
    try:
        as_int = None if isinstance(value, (str, bytes)) else int(value)
    except (TypeError, ValueError):
        as_int = None
    if as_int is None or isinstance(value, bool) or as_int != value:
        raise ValueError(f"{name}: expected an integer, got {value!r}")
    if not lo <= as_int <= hi:
        raise ValueError(f"{name}: {as_int} is outside [{lo}, {hi}]")
    return as_int


def _seed(value):
    """A random seed: a whole number in [0, 2**64 - 1], as the CLI's --seed."""
    return _int(value, "seed", 0, 2**64 - 1)


def link_budget(distance_m, reflectance=0.1, angle_deg=0.0, temperature_c=None, config=None):
    """The optical link budget at each distance (paper Eqs. 4-9), as ``tofkit budget``.

    Returns a dict of arrays: distance_m, received_power_w, background_power_w,
    signal_current_a, noise_{signal_shot,background_shot,dark_shot,thermal,total}_a
    and snr. temperature_c: APD temperature (None: the receiver's nominal one).
    Raises ValueError for a value outside measure()'s ranges (distance
    0.001-1e5 m, reflectance 0-1, angle 0-89.9 degrees, -60-150 C).
    """
    distances = np.atleast_1d(np.asarray(distance_m, dtype=np.float64))
    if distances.ndim != 1:
        raise ValueError("distance_m: expected a number or a 1-D array")
    return _tofkit._link_budget(_config(config), distances, _float(reflectance, "reflectance"),
                                _float(angle_deg, "angle_deg"),
                                None if temperature_c is None else _float(temperature_c,
                                                                          "temperature_c"))
