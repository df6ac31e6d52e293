"""An independent reader of tofkit's CSV tables (the csv module, not tofkit's
own reader) for comparing the package with the CLI's files."""

import csv
import math

import numpy as np


def read_table(path):
    """{column: float64 array}; empty fields are NaN."""
    with open(path, newline="") as f:
        rows = list(csv.reader(f))
    header, body = rows[0], rows[1:]
    return {name: np.array([float(r[i]) if r[i] != "" else math.nan for r in body])
            for i, name in enumerate(header)}
