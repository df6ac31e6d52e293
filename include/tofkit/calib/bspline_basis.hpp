#pragma once
/// \file The B-spline basis lives in ranging/ (ranging/bspline_basis.hpp), which evaluates
/// surfaces; these names keep calib:: spellings working for the fitter.

#include "tofkit/ranging/bspline_basis.hpp"

namespace tofkit::calib {
using ranging::BSplineAxis;
using ranging::BSplineKnots;
using ranging::BSplineSpan;
using ranging::cubic_bspline_span;
}  // namespace tofkit::calib
