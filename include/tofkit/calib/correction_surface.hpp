#pragma once
/// \file Correction surfaces are evaluated by ranging/ (ranging/correction_surface.hpp)
/// and fitted here (calib/surface_fit.hpp); these names keep calib:: spellings working.

#include "tofkit/ranging/correction_surface.hpp"

namespace tofkit::calib {
using ranging::AxisScaling;
using ranging::CorrectionSurface;
using ranging::SurfaceDomain;
using ranging::SurfaceFitStats;
using ranging::SurfaceInputs;
}  // namespace tofkit::calib
