#pragma once
/// \file Polynomial surfaces are evaluated by ranging/ (ranging/polynomial_surface.hpp)
/// and fitted here (calib::fit_polynomial_surface); these names keep calib:: spellings working.

#include "tofkit/calib/correction_surface.hpp"
#include "tofkit/ranging/polynomial_surface.hpp"

namespace tofkit::calib {
using ranging::MonomialExponents;
using ranging::polynomial_exponents;
using ranging::PolynomialSurface;
using ranging::PolynomialSurfaceParams;
}  // namespace tofkit::calib
