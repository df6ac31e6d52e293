#pragma once
/// \file B-spline surfaces are evaluated by ranging/ (ranging/bspline_surface.hpp) and
/// fitted here (calib::fit_bspline_surface); these names keep calib:: spellings working.

#include "tofkit/calib/bspline_basis.hpp"
#include "tofkit/calib/correction_surface.hpp"
#include "tofkit/ranging/bspline_surface.hpp"

namespace tofkit::calib {
using ranging::BSplineSurface;
using ranging::BSplineSurfaceParams;
}  // namespace tofkit::calib
