"""The correction side: ranging models (the CLI's model JSON), their batch
application to NumPy data without copying it, and the fitters."""

import json
import os

import numpy as np

from . import _tofkit
from .device import _config, _float

_COLUMNS = _tofkit.RECORD_DTYPE.names


def _columns(raw):
    """The raw columns of a structured array, a dict of columns or a DataFrame,
    as views (no copy): a tuple in RECORD_DTYPE order, None where absent."""
    if isinstance(raw, np.ndarray):
        if raw.dtype.names is None:
            raise TypeError("raw: expected a structured array (fields named as the raw CSV "
                            "columns) or a mapping of columns")
        names = raw.dtype.names
        return tuple(raw[name] if name in names else None for name in _COLUMNS)
    if hasattr(raw, "keys"):
        keys = set(raw.keys())
        return tuple(np.asarray(raw[name]) if name in keys else None for name in _COLUMNS)
    raise TypeError("raw: expected a structured array or a mapping of columns, got "
                    f"{type(raw).__name__}")


class Model:
    """A ranging pipeline: the start distance c_air t / 2 plus fitted
    correction steps and an expected error (a ``tofkit fit`` model file)."""

    def __init__(self, _model):
        self._model = _model

    @classmethod
    def load(cls, path):
        """Read a model file (``tofkit fit --out``). Raises FileNotFoundError /
        ValueError with the CLI's message."""
        return cls(_tofkit._Model.load(os.fspath(path)))

    def save(self, path):
        """Write the model file (the same JSON as ``tofkit fit``), atomically."""
        self._model.save(os.fspath(path))

    def to_json(self):
        """The model file's content as a dict."""
        return json.loads(self._model.to_json())

    @property
    def fit(self):
        """Fit statistics stored with the model (a dict, or None)."""
        return json.loads(self._model.fit_json)

    @property
    def report(self):
        """The fitter's summary (empty for a loaded model)."""
        return self._model.report

    @property
    def budget(self):
        """The model's uncertainty budget (``tofkit fit --budget``) as a dict
        ({"components": [...], "unobserved": [...]}), or None."""
        return json.loads(self._model.budget_json)

    @property
    def residual_rms_m(self):
        return self._model.residual_rms_m

    def summary(self):
        return self._model.summary()

    def __repr__(self):
        return f"<tofkit.Model\n{self.summary()}>"

    def apply(self, raw, out=None, since_calibration_s=None):
        """Correct raw measurements: returns (distance_m, sigma_m, correction_flags).

        With an uncertainty budget in the model, sigma_m is its combined
        standard uncertainty: since_calibration_s (seconds after the calibration,
        on its power-on) sets its drift term; None: another power-on.

        raw: a structured array with the raw CSV columns (measure(), read_raw())
        or a mapping of 1-D columns (tof_ns and/or distance_raw_m; pulse_width_ns,
        amplitude, temperature_c, shots_valid, flags as the model needs). The
        input is read in place (no copy, any numeric dtype and stride); the three
        results are views of one new RANGE_DTYPE array, or of ``out`` when given
        (a RANGE_DTYPE array of the same length, reused across batches); the
        GIL is released meanwhile.
        """
        since = float("nan") if since_calibration_s is None else float(since_calibration_s)
        out = self._model.apply(_columns(raw), out, since)
        return out["distance_m"], out["sigma_m"], out["correction_flags"]


def fit_chain(records, steps="offset,grayvalue,temperature", config=None, confidence="none",
              refine_walk=False):
    """Fit the paper's correction chain, as ``tofkit fit --chain STEPS
    --confidence CONFIDENCE [--refine-walk]`` (the same C++ function,
    calib::fit_model).

    records: measurements with truth (measure(), read_raw(), or a mapping of
    columns with distance_true_m). config: the device (its wavelength and
    reference air set c_air; None: the paper's). confidence: "none",
    "calibrated" (sigma fitted on out-of-fold residuals) or "thesis".
    refine_walk: add a dense penalized correction in pulse width to the
    grayvalue step (nodes and smoothing by grouped cross-validation).
    steps: the CLI's LIST ("offset,grayvalue") or a list of step names.
    """
    if isinstance(steps, (list, tuple)):
        steps = ",".join(str(step) for step in steps)
    return Model(_tofkit._fit_chain(_columns(records), str(steps), _config(config),
                                    str(confidence), _flag(refine_walk, "refine_walk")))


def _flag(value, name):
    """A yes/no argument: a bool (or NumPy's), not a string ('False' is truthy)."""
    if not isinstance(value, (bool, np.bool_)):
        raise TypeError(f"{name}: expected True or False, got {value!r}")
    return bool(value)


def fit_surface(records, surface="poly:4", temperature=False, rcond=None, chain=None,
                config=None, confidence="none"):
    """Fit a correction surface over (range, amplitude[, temperature]), as
    ``tofkit fit --surface SPEC [--temperature] [--rcond R]``; with ``chain``
    (a Model) the surface fits the chain's residual and is appended to it, as
    ``--chain ... --surface ...``. A B-spline's knots and smoothing are chosen
    by cross-validation over whole truth groups, as the CLI does.
    """
    cols = dict(zip(_COLUMNS, _columns(records)))
    if cols["distance_true_m"] is None:
        raise ValueError("records: a surface fit needs the distance_true_m column")
    if chain is not None and not isinstance(chain, Model):
        raise TypeError(f"chain: expected a tofkit.Model or None, got {type(chain).__name__}")
    base = chain._model if chain is not None else None
    return Model(_tofkit._fit_surface(base, _config(config), _columns(records), str(surface),
                                      _flag(temperature, "temperature"),
                                      None if rcond is None else _float(rcond, "rcond"),
                                      str(confidence)))
