#include "tofkit/calib/surface_fit.hpp"

#include <tbb/parallel_for.h>

#include <Eigen/Dense>
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <limits>
#include <stdexcept>
#include <string>
#include <vector>

#include "tofkit/calib/bspline_surface.hpp"
#include "tofkit/calib/polynomial_surface.hpp"
#include "tofkit/calib/statistics.hpp"

namespace tofkit::calib {

namespace {

using Eigen::Index;
using Eigen::MatrixXd;
using Eigen::VectorXd;

/// Validated column pointers of the training data and their bounding box.
struct Columns {
  const double* range = nullptr;
  const double* amplitude = nullptr;
  const double* temperature = nullptr;  // null without a temperature axis
  const double* error = nullptr;
  const std::uint32_t* group = nullptr;  // null: no groups (GCV instead of k-fold)
  std::size_t rows = 0;
  SurfaceDomain domain;
};

void check_column(std::span<const double> column, const std::string& who, const char* name,
                  double& lo, double& hi) {
  lo = std::numeric_limits<double>::infinity();
  hi = -lo;
  for (std::size_t k = 0; k < column.size(); ++k) {
    const double v = column[k];
    if (!std::isfinite(v)) {
      throw std::invalid_argument(who + ": non-finite " + name + " at row " + std::to_string(k));
    }
    lo = std::min(lo, v);
    hi = std::max(hi, v);
  }
}

Columns validate_data(const SurfaceFitData& data, bool use_temperature, const std::string& who) {
  const std::size_t n = data.error_m.size();
  if (data.inputs.range_m.size() != n || data.inputs.amplitude.size() != n ||
      (use_temperature && data.inputs.temperature_c.size() != n)) {
    throw std::invalid_argument(who + ": range_m, amplitude, " +
                                (use_temperature ? "temperature_c, " : "") +
                                "error_m must have the same length");
  }
  if (n == 0) throw std::invalid_argument(who + ": no rows");
  Columns c;
  c.range = data.inputs.range_m.data();
  c.amplitude = data.inputs.amplitude.data();
  c.temperature = use_temperature ? data.inputs.temperature_c.data() : nullptr;
  c.error = data.error_m.data();
  c.rows = n;
  if (!data.group.empty()) {
    if (data.group.size() != n) {
      throw std::invalid_argument(who + ": group must have one entry per row");
    }
    c.group = data.group.data();
  }
  double lo = 0, hi = 0;
  check_column(data.error_m, who, "error_m", lo, hi);
  auto& d = c.domain;
  check_column(data.inputs.range_m, who, "range_m", d.range_min_m, d.range_max_m);
  check_column(data.inputs.amplitude, who, "amplitude", d.amplitude_min, d.amplitude_max);
  if (use_temperature) {
    check_column(data.inputs.temperature_c, who, "temperature_c", d.temperature_min_c,
                 d.temperature_max_c);
  }
  auto spread = [&](double min, double max, const char* name) {
    if (!(min < max)) {
      char value[64];
      std::snprintf(value, sizeof value, "%.9g", min);
      throw std::invalid_argument(who + ": no spread in " + name + " (every row at " + value +
                                  "); a surface over it is undetermined");
    }
  };
  spread(d.range_min_m, d.range_max_m, "range_m");
  spread(d.amplitude_min, d.amplitude_max, "amplitude");
  if (use_temperature) spread(d.temperature_min_c, d.temperature_max_c, "temperature_c");
  return c;
}

void require_rows(const Columns& c, std::size_t parameters, const std::string& who) {
  if (c.rows < parameters) {
    throw std::invalid_argument(who + ": " + std::to_string(c.rows) + " rows for " +
                                std::to_string(parameters) +
                                " parameters (fewer rows than parameters)");
  }
}

double residual_rms(const CorrectionSurface& surface, const SurfaceFitData& data) {
  const std::size_t n = data.error_m.size();
  std::vector<double> fitted(n);
  std::vector<std::uint8_t> flags(n);
  SurfaceInputs inputs = data.inputs;
  if (!surface.uses_temperature()) inputs.temperature_c = {};
  surface.evaluate(inputs, fitted, flags);
  double sum = 0;
  for (std::size_t k = 0; k < n; ++k) {
    const double e = data.error_m[k] - fitted[k];
    sum += e * e;
  }
  return std::sqrt(sum / static_cast<double>(n));
}

SurfaceFitResult make_result(std::shared_ptr<const CorrectionSurface> surface,
                             const SurfaceFitStats& s) {
  SurfaceFitResult r;
  r.surface = std::move(surface);
  r.rows = s.rows;
  r.parameters = s.parameters;
  r.rank = s.rank;
  r.residual_rms_m = s.residual_rms_m;
  r.condition_number = s.condition_number;
  r.smoothing = s.smoothing;
  r.effective_parameters = s.effective_parameters;
  r.cv_rms_m = s.cv_rms_m;
  return r;
}

// ---------------------------------------------------------------- polynomial

/// Upper-triangular factor R of the augmented design [A | y] by a streaming
/// (tall-skinny) Householder QR: R_k = qr([R_{k-1}; rows of chunk k]). Then
/// A = Q R11 and Q^T y = R12, so the SVD of R11 is the SVD of A itself (the
/// route LAPACK's xGESVD takes for tall matrices) and A^T A is never formed.
MatrixXd streaming_qr_factor(const Columns& c, const std::vector<MonomialExponents>& exps,
                             int order, const PolynomialSurfaceParams& p) {
  const Index params = static_cast<Index>(exps.size());
  const Index cols = params + 1;
  constexpr Index kChunk = 2048;
  MatrixXd r_factor = MatrixXd::Zero(cols, cols);
  MatrixXd stack(cols + kChunk, cols);
  std::vector<double> pr(static_cast<std::size_t>(order) + 1);
  std::vector<double> pa(pr.size()), pt(pr.size(), 1.0);
  for (std::size_t start = 0; start < c.rows; start += kChunk) {
    const Index m = static_cast<Index>(std::min<std::size_t>(kChunk, c.rows - start));
    stack.topRows(cols) = r_factor;
    for (Index j = 0; j < m; ++j) {
      const std::size_t row = start + static_cast<std::size_t>(j);
      const double r = p.range_scaling.apply(c.range[row]);
      const double a = p.amplitude_scaling.apply(c.amplitude[row]);
      const double t = c.temperature ? p.temperature_scaling.apply(c.temperature[row]) : 0.0;
      pr[0] = pa[0] = pt[0] = 1.0;
      for (int k = 1; k <= order; ++k) {
        pr[k] = pr[k - 1] * r;
        pa[k] = pa[k - 1] * a;
        if (c.temperature) pt[k] = pt[k - 1] * t;
      }
      for (Index k = 0; k < params; ++k) {
        const auto& e = exps[static_cast<std::size_t>(k)];
        stack(cols + j, k) = pr[e[0]] * pa[e[1]] * pt[e[2]];
      }
      stack(cols + j, params) = c.error[row];
    }
    Eigen::HouseholderQR<MatrixXd> qr(stack.topRows(cols + m));
    r_factor = qr.matrixQR().topRows(cols).triangularView<Eigen::Upper>();
  }
  return r_factor;
}

// ------------------------------------------------------------------ B-spline

struct Grid {
  BSplineAxis axes[3];
  std::vector<BSplineKnots> knots;  // the axes prepared for evaluation
  int dims = 2;
  std::size_t extent[3] = {1, 1, 1};
  std::size_t parameters = 0;
  [[nodiscard]] std::size_t index(std::size_t ir, std::size_t ia, std::size_t it) const {
    return (ir * extent[1] + ia) * extent[2] + it;
  }
};

/// Basis functions touching one point (given in axis coordinates): their
/// weights and first coefficient index along each axis, i.e. the point's cell.
struct PointBasis {
  BSplineSpan span[3];
  [[nodiscard]] std::size_t cell(const Grid& grid) const {
    const auto ir = static_cast<std::size_t>(span[0].first);
    const auto ia = static_cast<std::size_t>(span[1].first);
    const auto it = static_cast<std::size_t>(span[2].first);
    const std::size_t nt = grid.dims == 3 ? static_cast<std::size_t>(grid.axes[2].intervals()) : 1;
    return (ir * static_cast<std::size_t>(grid.axes[1].intervals()) + ia) * nt + it;
  }
};

PointBasis point_basis(const Grid& grid, const double* u) {
  PointBasis b;
  for (int k = 0; k < grid.dims; ++k) b.span[k] = grid.knots[k].span(u[k]);
  if (grid.dims == 2) b.span[2].weight[0] = 1.0;
  return b;
}

/// Normal equations G = B^T B, g = B^T y of the tensor-product basis. Every row
/// touches only the 4 x 4 (x 4) basis functions of its cell, so rows are
/// grouped by cell (a counting sort that also copies their axis coordinates
/// into cell order) and each cell's local K x K block is a symmetric rank-m
/// update W W^T of its rows' weights (a BLAS-3 product), added into G once per
/// cell. Cells are processed in parallel in fixed groups and added in cell
/// order, so the result does not depend on the thread count.
void accumulate_normal_equations(const Columns& c, const Grid& grid, MatrixXd& gram,
                                 VectorXd& rhs) {
  const Index p = static_cast<Index>(grid.parameters);
  const int dims = grid.dims;
  const int per_axis[3] = {4, 4, dims == 3 ? 4 : 1};
  const Index local = per_axis[0] * per_axis[1] * per_axis[2];
  std::size_t cells = 1;
  for (int k = 0; k < dims; ++k) cells *= static_cast<std::size_t>(grid.axes[k].intervals());

  // Axis coordinates (log taken once) and cell of every row, then a counting
  // sort that lays coordinates and errors out cell by cell.
  const std::size_t stride = static_cast<std::size_t>(dims);
  std::vector<double> coordinate(c.rows * stride);
  std::vector<std::uint32_t> cell_of(c.rows);
  std::vector<std::size_t> start(cells + 1, 0);
  for (std::size_t row = 0; row < c.rows; ++row) {
    double* u = coordinate.data() + row * stride;
    u[0] = grid.axes[0].coordinate(c.range[row]);
    u[1] = grid.axes[1].coordinate(c.amplitude[row]);
    if (dims == 3) u[2] = grid.axes[2].coordinate(c.temperature[row]);
    // The cell needs only each axis's knot interval, not the weights.
    PointBasis cell;
    for (int k = 0; k < dims; ++k) cell.span[k].first = grid.knots[k].interval(u[k]);
    cell_of[row] = static_cast<std::uint32_t>(cell.cell(grid));
    ++start[cell_of[row] + 1];
  }
  for (std::size_t k = 0; k < cells; ++k) start[k + 1] += start[k];
  std::vector<double> sorted_coordinate(c.rows * stride), sorted_error(c.rows);
  {
    std::vector<std::size_t> next(start.begin(), start.end() - 1);
    for (std::size_t row = 0; row < c.rows; ++row) {
      const std::size_t to = next[cell_of[row]]++;
      std::copy_n(coordinate.data() + row * stride, stride, sorted_coordinate.data() + to * stride);
      sorted_error[to] = c.error[row];
    }
  }
  coordinate = {};
  cell_of = {};

  gram = MatrixXd::Zero(p, p);
  rhs = VectorXd::Zero(p);
  constexpr std::size_t kGroup = 64;  // cells per parallel group (bounds memory)
  constexpr Index kBatch = 256;       // rows per rank update
  std::vector<MatrixXd> blocks(std::min(kGroup, cells), MatrixXd(local, local));
  std::vector<VectorXd> block_rhs(blocks.size(), VectorXd(local));
  for (std::size_t group = 0; group < cells; group += kGroup) {
    const std::size_t group_end = std::min(cells, group + kGroup);
    tbb::parallel_for(group, group_end, [&](std::size_t cell) {
      MatrixXd& block = blocks[cell - group];
      VectorXd& b = block_rhs[cell - group];
      block.setZero();
      b.setZero();
      MatrixXd weights(local, kBatch);  // one column per row
      for (std::size_t k = start[cell]; k < start[cell + 1]; k += kBatch) {
        const Index m = static_cast<Index>(std::min<std::size_t>(kBatch, start[cell + 1] - k));
        for (Index j = 0; j < m; ++j) {
          const std::size_t row = k + static_cast<std::size_t>(j);
          const PointBasis pb = point_basis(grid, sorted_coordinate.data() + row * stride);
          Index u = 0;
          for (int i0 = 0; i0 < per_axis[0]; ++i0) {
            for (int i1 = 0; i1 < per_axis[1]; ++i1) {
              const double w01 = pb.span[0].weight[i0] * pb.span[1].weight[i1];
              for (int i2 = 0; i2 < per_axis[2]; ++i2)
                weights(u++, j) = w01 * pb.span[2].weight[i2];
            }
          }
        }
        block.selfadjointView<Eigen::Lower>().rankUpdate(weights.leftCols(m));
        b.noalias() += weights.leftCols(m) * Eigen::Map<const VectorXd>(sorted_error.data() + k, m);
      }
    });
    // Scatter each cell's block into G, in cell order.
    for (std::size_t cell = group; cell < group_end; ++cell) {
      if (start[cell] == start[cell + 1]) continue;
      const PointBasis pb = point_basis(grid, sorted_coordinate.data() + start[cell] * stride);
      std::size_t index[64];
      Index u = 0;
      for (int i0 = 0; i0 < per_axis[0]; ++i0) {
        for (int i1 = 0; i1 < per_axis[1]; ++i1) {
          for (int i2 = 0; i2 < per_axis[2]; ++i2) {
            index[u++] = grid.index(static_cast<std::size_t>(pb.span[0].first + i0),
                                    static_cast<std::size_t>(pb.span[1].first + i1),
                                    static_cast<std::size_t>(pb.span[2].first + i2));
          }
        }
      }
      const MatrixXd& block = blocks[cell - group];
      for (Index v = 0; v < local; ++v) {
        rhs(static_cast<Index>(index[v])) += block_rhs[cell - group](v);
        for (Index w = v; w < local; ++w) {
          // index[] is ascending, so (w, v) with w >= v lands in G's lower triangle.
          gram(static_cast<Index>(index[w]), static_cast<Index>(index[v])) += block(w, v);
        }
      }
    }
  }
  gram.triangularView<Eigen::StrictlyUpper>() = gram.transpose();
}

/// D^T W D of the second divided differences of the coefficients of one axis
/// at their Greville abscissae xi_i (the mean of each basis function's three
/// inner knots):
///   (D c)_i = [(c_{i+1} - c_i) / (xi_{i+1} - xi_i) - (c_i - c_{i-1}) / (xi_i - xi_{i-1})]
///             / ((xi_{i+1} - xi_{i-1}) / 2),
/// weighted by w_i = (xi_{i+1} - xi_{i-1}) / 2, the share of the axis each one
/// stands for, so that c'D'WDc approximates the integral of the squared second
/// derivative (O'Sullivan 1986) with any knot spacing. Chosen over the exact
/// O'Sullivan integral because on uniform knots it is exactly Eilers & Marx's
/// second-difference penalty (rows [1 -2 1]; made so by the factors h^2 and
/// 1 / h below, h the mean Greville spacing), so uniform knots stay the special
/// case they are in the basis and keep the fits and the cross-validation
/// ladder they had; and its null space is exactly the straight lines (a
/// spline with c_i = a + b xi_i is the line a + b u), which the P-spline's
/// continuation beyond the data relies on. Dimensionless, like [1 -2 1].
MatrixXd second_difference_gram(const BSplineAxis& axis) {
  const int n = axis.basis_count();
  std::vector<double> xi(static_cast<std::size_t>(n));
  for (int i = 0; i < n; ++i) xi[static_cast<std::size_t>(i)] = axis.greville(i);
  const double h = (xi.back() - xi.front()) / (n - 1);
  MatrixXd d = MatrixXd::Zero(n - 2, n);
  for (int k = 0; k + 2 < n; ++k) {
    const auto at = [&](int i) { return xi[static_cast<std::size_t>(i)]; };
    const double left = at(k + 1) - at(k);
    const double right = at(k + 2) - at(k + 1);
    const double half_width = 0.5 * (left + right);
    // Row scaled by h^2 / half_width (divided difference) times sqrt(half_width / h)
    // (the weight): on uniform knots, [1 -2 1].
    const double scale = h * h / half_width * std::sqrt(half_width / h);
    d(k, k) = scale / left;
    d(k, k + 1) = -scale * (1.0 / left + 1.0 / right);
    d(k, k + 2) = scale / right;
  }
  return d.transpose() * d;
}

/// The second-difference penalty on the coefficient grid along one axis
/// (Eilers & Marx 1996; D_r'D_r (x) I, I (x) D_a'D_a ...); their sum over the
/// axes, each with its own weight, is the surface's penalty.
MatrixXd penalty_matrix(const Grid& grid, int axis) {
  const Index p = static_cast<Index>(grid.parameters);
  MatrixXd penalty = MatrixXd::Zero(p, p);
  {
    const MatrixXd dtd = second_difference_gram(grid.axes[axis]);
    for (std::size_t i0 = 0; i0 < grid.extent[0]; ++i0) {
      for (std::size_t i1 = 0; i1 < grid.extent[1]; ++i1) {
        for (std::size_t i2 = 0; i2 < grid.extent[2]; ++i2) {
          const std::size_t from[3] = {i0, i1, i2};
          const std::size_t row = grid.index(i0, i1, i2);
          for (std::size_t j = 0; j < grid.extent[axis]; ++j) {
            std::size_t to[3] = {i0, i1, i2};
            to[axis] = j;
            const double v = dtd(static_cast<Index>(from[axis]), static_cast<Index>(j));
            if (v != 0)
              penalty(static_cast<Index>(row),
                      static_cast<Index>(grid.index(to[0], to[1], to[2]))) += v;
          }
        }
      }
    }
  }
  return penalty;
}

struct PenalizedSolution {
  VectorXd coefficients;
  double effective_parameters = 0;  // trace((G + lambda P)^-1 G)
  double rss = 0;                   // from the normal equations
  double condition_number = 0;      // of [B; sqrt(lambda) D], i.e. sqrt(cond(G + lambda P))
};

PenalizedSolution solve_penalized(const MatrixXd& gram, const VectorXd& rhs, double yy,
                                  const MatrixXd& penalty, double lambda, bool with_condition,
                                  bool with_edf = true) {
  const Index p = gram.rows();
  // A tiny ridge keeps the system positive definite when the data leave part of
  // the penalty's null space (planes) undetermined.
  const double ridge = 1e-12 * gram.trace() / static_cast<double>(p);
  MatrixXd system = gram + lambda * penalty;
  system.diagonal().array() += ridge;
  Eigen::LLT<MatrixXd> llt(system);
  if (llt.info() != Eigen::Success) {
    throw std::runtime_error(
        "fit_bspline_surface: penalized normal equations are not positive definite");
  }
  PenalizedSolution s;
  s.coefficients = llt.solve(rhs);
  if (with_edf) s.effective_parameters = llt.solve(gram).trace();
  // RSS = y'y - 2 c'B'y + c'B'Bc.
  s.rss =
      std::max(0.0, yy - 2.0 * s.coefficients.dot(rhs) + s.coefficients.dot(gram * s.coefficients));
  if (with_condition) {
    Eigen::SelfAdjointEigenSolver<MatrixXd> eig(system, Eigen::EigenvaluesOnly);
    const double lo = eig.eigenvalues().minCoeff();
    const double hi = eig.eigenvalues().maxCoeff();
    s.condition_number = lo > 0 ? std::sqrt(hi / lo) : std::numeric_limits<double>::infinity();
  }
  return s;
}

std::string format_number(double v) {
  char buffer[64];
  std::snprintf(buffer, sizeof buffer, "%.4g", v);
  return buffer;
}

}  // namespace

const char* to_string(KnotPlacement placement) {
  return placement == KnotPlacement::quantile ? "quantile" : "uniform";
}

void PolynomialFitOptions::validate() const {
  if (order < 0 || order > 12)
    throw std::invalid_argument("PolynomialFitOptions.order must be in [0, 12]");
  if (!(rcond >= 0 && rcond < 1))
    throw std::invalid_argument("PolynomialFitOptions.rcond must be in [0, 1)");
}

void BSplineFitOptions::validate() const {
  auto check = [](int v, const char* name) {
    if (v < 1 || v > 200) {
      throw std::invalid_argument(std::string("BSplineFitOptions.") + name +
                                  " must be in [1, 200]");
    }
  };
  check(intervals_range, "intervals_range");
  check(intervals_amplitude, "intervals_amplitude");
  if (use_temperature) check(intervals_temperature, "intervals_temperature");
  // Relative to the data term: beyond 1e6 the fit is the penalty's null space
  // (planes) to rounding, and the normal equations stop being positive definite.
  if (!(smoothing >= 0) || !(smoothing <= kMaxBSplineSmoothing)) {
    throw std::invalid_argument("BSplineFitOptions.smoothing must be in [0, 1e6]");
  }
  if (!(shrink_to_zero >= 0) || !(shrink_to_zero <= 1e3))
    throw std::invalid_argument("BSplineFitOptions.shrink_to_zero must be in [0, 1000]");
  for (int k = 0; k < 3; ++k) {
    if (!(axis_weight[k] > 0) || !std::isfinite(axis_weight[k])) {
      throw std::invalid_argument("BSplineFitOptions.axis_weight[" + std::to_string(k) +
                                  "] must be finite and > 0");
    }
  }
}

std::string SurfaceFitResult::summary() const {
  std::string s = (surface ? surface->kind() : std::string("(no surface)")) + ": " +
                  std::to_string(rows) + " rows, " + std::to_string(parameters) +
                  " parameters, rank " + std::to_string(rank);
  if (effective_parameters > 0)
    s += ", effective parameters " + format_number(effective_parameters);
  if (intervals[0] > 0) {
    s += ", knot intervals " + std::to_string(intervals[0]) + " x " + std::to_string(intervals[1]);
    if (intervals[2] > 0) s += " x " + std::to_string(intervals[2]);
    // The breakpoints per axis: "knots range uniform [0.5 3.33 6.17 9], ...".
    static const char* const kAxis[3] = {"range", "intensity", "temperature"};
    const char* separator = ", knots ";
    for (int k = 0; k < 3; ++k) {
      if (knots[k].empty()) continue;
      s += std::string(separator) + kAxis[k] + " " + to_string(placement[k]) + " [";
      for (std::size_t i = 0; i < knots[k].size(); ++i) {
        if (i > 0) s += ' ';
        s += format_number(knots[k][i]);
      }
      s += "]";
      separator = ", ";
    }
  }
  if (smoothing > 0) {
    s += ", smoothing " + format_number(smoothing);
    if (intervals[0] > 0) {
      s += " (axis weights " + format_number(axis_weight[0]) + ", " + format_number(axis_weight[1]);
      if (intervals[2] > 0) s += ", " + format_number(axis_weight[2]);
      s += ")";
    }
  }
  if (cv_rms_m > 0) s += ", cross-validated RMS " + format_number(cv_rms_m * 1e3) + " mm";
  s += ", residual RMS " + format_number(residual_rms_m * 1e3) + " mm, condition number " +
       format_number(condition_number);
  return s;
}

SurfaceFitResult fit_polynomial_surface(const SurfaceFitData& data,
                                        const PolynomialFitOptions& options) {
  options.validate();
  const std::string who = "fit_polynomial_surface (order " + std::to_string(options.order) + ")";
  const Columns c = validate_data(data, options.use_temperature, who);
  PolynomialSurfaceParams p;
  p.order = options.order;
  p.use_temperature = options.use_temperature;
  p.exponents = polynomial_exponents(options.order, options.use_temperature);
  p.domain = c.domain;
  // Affine scaling to [-1, 1] over the training domain, for conditioning.
  p.range_scaling = AxisScaling::over(c.domain.range_min_m, c.domain.range_max_m);
  p.amplitude_scaling = AxisScaling::over(c.domain.amplitude_min, c.domain.amplitude_max);
  if (options.use_temperature) {
    p.temperature_scaling =
        AxisScaling::over(c.domain.temperature_min_c, c.domain.temperature_max_c);
  }
  const std::size_t params = p.exponents.size();
  require_rows(c, params, who);

  const MatrixXd r_aug = streaming_qr_factor(c, p.exponents, p.order, p);
  const Index np = static_cast<Index>(params);
  const MatrixXd r11 = r_aug.topLeftCorner(np, np);
  const VectorXd qty = r_aug.col(np).head(np);
  Eigen::JacobiSVD<MatrixXd> svd(r11, Eigen::ComputeFullU | Eigen::ComputeFullV);
  const VectorXd& sv = svd.singularValues();
  // Thesis Section 4.6: singular values below rcond * s_max are treated as zero
  // (the pseudo-inverse drops them) instead of being inverted.
  const double cutoff = options.rcond * sv(0);
  VectorXd x = VectorXd::Zero(np);
  std::size_t rank = 0;
  for (Index k = 0; k < np; ++k) {
    if (sv(k) > 0 && sv(k) >= cutoff) {
      x += svd.matrixV().col(k) * (svd.matrixU().col(k).dot(qty) / sv(k));
      ++rank;
    }
  }
  p.coefficients.assign(x.data(), x.data() + np);
  auto& s = p.fit;
  s.rows = c.rows;
  s.parameters = params;
  s.rank = rank;
  s.rcond = options.rcond;
  s.effective_parameters = static_cast<double>(rank);
  const double smin = sv(np - 1);
  s.condition_number = smin > 0 ? sv(0) / smin : std::numeric_limits<double>::infinity();
  // Residual on the training data by evaluating the surface, so it reflects
  // exactly what the model will return.
  PolynomialSurface probe(p);
  s.residual_rms_m = residual_rms(probe, data);
  p.fit = s;
  return make_result(std::make_shared<const PolynomialSurface>(std::move(p)), s);
}

namespace {

/// Rows of one cross-validation fold, owned, viewable as Columns.
struct Fold {
  std::vector<double> range, amplitude, temperature, error;
  Columns columns;
  /// The rows it is scored on (inside its training domain).
  std::vector<double> scored_range, scored_amplitude, scored_temperature, scored_error;
  Columns scored;
};

/// K folds of whole groups (fold_of: shuffled); empty when the data carry no groups
/// or fewer than K distinct groups (GCV is used then).
std::vector<Fold> make_folds(const Columns& c) {
  constexpr std::uint32_t kFolds = 5;
  std::vector<Fold> folds;
  if (c.group == nullptr) return folds;
  std::vector<std::uint32_t> distinct(c.group, c.group + c.rows);
  std::sort(distinct.begin(), distinct.end());
  if (std::unique(distinct.begin(), distinct.end()) - distinct.begin() < kFolds) return folds;
  folds.resize(kFolds);
  // Each fold is scored only on its rows inside the bounding box of the other
  // folds' rows (the domain its training surface would have): outside, the
  // surface is flagged out of domain, and scoring its extrapolation there
  // would choose knots and smoothing for the edges instead of the interior.
  struct Box {
    double lo[3] = {std::numeric_limits<double>::infinity(),
                    std::numeric_limits<double>::infinity(),
                    std::numeric_limits<double>::infinity()};
    double hi[3] = {-lo[0], -lo[1], -lo[2]};
  };
  std::vector<Box> trained(kFolds);
  const auto values = [&](std::size_t k, double* v) {
    v[0] = c.range[k];
    v[1] = c.amplitude[k];
    v[2] = c.temperature ? c.temperature[k] : 0.0;
  };
  for (std::size_t k = 0; k < c.rows; ++k) {
    const std::size_t own = fold_of(c.group[k], kFolds);
    double v[3];
    values(k, v);
    for (std::size_t f = 0; f < kFolds; ++f) {
      if (f == own) continue;
      for (int a = 0; a < 3; ++a) {
        trained[f].lo[a] = std::min(trained[f].lo[a], v[a]);
        trained[f].hi[a] = std::max(trained[f].hi[a], v[a]);
      }
    }
  }
  for (std::size_t k = 0; k < c.rows; ++k) {
    const std::size_t own = fold_of(c.group[k], kFolds);
    Fold& f = folds[own];
    double v[3];
    values(k, v);
    bool inside = true;
    for (int a = 0; a < 3; ++a) {
      inside = inside && v[a] >= trained[own].lo[a] && v[a] <= trained[own].hi[a];
    }
    if (inside) {
      f.scored_range.push_back(c.range[k]);
      f.scored_amplitude.push_back(c.amplitude[k]);
      if (c.temperature) f.scored_temperature.push_back(c.temperature[k]);
      f.scored_error.push_back(c.error[k]);
    }
    f.range.push_back(c.range[k]);
    f.amplitude.push_back(c.amplitude[k]);
    if (c.temperature) f.temperature.push_back(c.temperature[k]);
    f.error.push_back(c.error[k]);
  }
  for (Fold& f : folds) {
    f.columns = c;
    f.columns.range = f.range.data();
    f.columns.amplitude = f.amplitude.data();
    f.columns.temperature = c.temperature ? f.temperature.data() : nullptr;
    f.columns.error = f.error.data();
    f.columns.group = nullptr;
    f.columns.rows = f.error.size();
    f.scored = f.columns;
    f.scored.range = f.scored_range.data();
    f.scored.amplitude = f.scored_amplitude.data();
    f.scored.temperature = c.temperature ? f.scored_temperature.data() : nullptr;
    f.scored.error = f.scored_error.data();
    f.scored.rows = f.scored_error.size();
  }
  return folds;
}

/// Normal equations of one fold.
struct FoldSystem {
  MatrixXd gram, scored_gram;
  VectorXd rhs, scored_rhs;
  double yy = 0, scored_yy = 0;
  bool empty = true;
};

/// One penalized fit on a given knot grid; with `choose_smoothing` the
/// smoothing is chosen over decades 1e-7 .. 1e1 by k-fold cross-validation
/// over whole groups when the data carry groups (repeats of one target are
/// not independent: GCV would let the spline chase them), else by GCV.
struct GridFit {
  Grid grid;
  PenalizedSolution solution;
  double smoothing = 0;
  /// Relative weight of each axis's penalty (1: the common smoothing).
  double axis_weight[3] = {1, 1, 1};
  double score = std::numeric_limits<double>::infinity();  // predicted mean squared error
};

GridFit fit_on_grid(const Columns& c, const std::vector<Fold>& folds, const Grid& grid,
                    double smoothing, const double* axis_weight, bool choose_smoothing,
                    bool with_condition, double shrink_to_zero) {
  MatrixXd gram;
  VectorXd rhs;
  accumulate_normal_equations(c, grid, gram, rhs);
  double yy = 0;
  for (std::size_t k = 0; k < c.rows; ++k) yy += c.error[k] * c.error[k];
  std::vector<MatrixXd> axis_penalty;
  double penalty_trace = 0;
  for (int axis = 0; axis < grid.dims; ++axis) {
    axis_penalty.push_back(penalty_matrix(grid, axis));
    penalty_trace += axis_penalty.back().trace();
  }
  const auto penalty_of = [&](const double* w) {
    MatrixXd penalty = w[0] * axis_penalty[0];
    for (int axis = 1; axis < grid.dims; ++axis) penalty += w[axis] * axis_penalty[axis];
    // The ridge toward zero (BSplineFitOptions::shrink_to_zero), scaled with
    // the penalty so the smoothing's choice by cross-validation sees it.
    if (shrink_to_zero > 0)
      penalty.diagonal().array() +=
          shrink_to_zero * penalty_trace / static_cast<double>(penalty.rows());
    return penalty;
  };
  // Penalty weight relative to the data term, so `smoothing` does not depend
  // on the number of rows or the grid size.
  const double scale = gram.trace() / penalty_trace;
  const double n = static_cast<double>(c.rows);
  std::vector<FoldSystem> systems(folds.size());
  double scored_rows = 0;
  for (std::size_t f = 0; f < folds.size(); ++f) {
    if (folds[f].columns.rows == 0) continue;
    accumulate_normal_equations(folds[f].columns, grid, systems[f].gram, systems[f].rhs);
    for (double e : folds[f].error) systems[f].yy += e * e;
    accumulate_normal_equations(folds[f].scored, grid, systems[f].scored_gram,
                                systems[f].scored_rhs);
    for (double e : folds[f].scored_error) systems[f].scored_yy += e * e;
    scored_rows += static_cast<double>(folds[f].scored.rows);
    systems[f].empty = false;
  }
  // Predicted mean squared error of a smoothing weight: k-fold (held-out
  // SSE = yy_f - 2 c'r_f + c'G_f c with c fitted without fold f) or GCV,
  // n RSS / (n - edf)^2 (Craven & Wahba 1979).
  const auto score_of = [&](double lambda, const double* w) {
    const MatrixXd penalty = penalty_of(w);
    if (systems.empty()) {
      const PenalizedSolution all = solve_penalized(gram, rhs, yy, penalty, lambda, false);
      const double dof = n - all.effective_parameters;
      return dof > 0.5 ? n * all.rss / (dof * dof) : std::numeric_limits<double>::infinity();
    }
    double sse = 0;
    for (const FoldSystem& f : systems) {
      if (f.empty) continue;
      const PenalizedSolution train =
          solve_penalized(gram - f.gram, rhs - f.rhs, yy - f.yy, penalty, lambda, false, false);
      const VectorXd& b = train.coefficients;
      sse += std::max(0.0, f.scored_yy - 2.0 * b.dot(f.scored_rhs) + b.dot(f.scored_gram * b));
    }
    return scored_rows > 0 ? sse / scored_rows : std::numeric_limits<double>::infinity();
  };
  GridFit fit;
  fit.grid = grid;
  fit.smoothing = smoothing;
  for (int axis = 0; axis < 3; ++axis) fit.axis_weight[axis] = axis_weight[axis];
  if (choose_smoothing) {
    // The common smoothing over decades, then each axis's own weight relative
    // to it (decades 1e-3 .. 1e3, one pass per axis): the surface may need to
    // bend along one axis (the walk's knee in intensity) and stay straight
    // along the other.
    const double ones[3] = {1, 1, 1};
    for (int e = -7; e <= 1; ++e) {
      const double candidate = std::pow(10.0, e);
      const double g = score_of(candidate * scale, ones);
      if (g < fit.score) {
        fit.score = g;
        fit.smoothing = candidate;
        for (double& w : fit.axis_weight) w = 1;
      }
    }
    for (int axis = 0; axis < grid.dims; ++axis) {
      double w[3] = {fit.axis_weight[0], fit.axis_weight[1], fit.axis_weight[2]};
      for (int e = -3; e <= 3; ++e) {
        if (e == 0) continue;
        w[axis] = std::pow(10.0, e);
        const double g = score_of(fit.smoothing * scale, w);
        if (g < fit.score * (1.0 - 1e-9)) {
          fit.score = g;
          fit.axis_weight[axis] = w[axis];
        }
      }
    }
  }
  fit.solution = solve_penalized(gram, rhs, yy, penalty_of(fit.axis_weight), fit.smoothing * scale,
                                 with_condition);
  fit.score = score_of(fit.smoothing * scale, fit.axis_weight);
  return fit;
}

Grid make_grid(const BSplineSurfaceParams& p, int dims) {
  Grid grid;
  grid.dims = dims;
  grid.axes[0] = p.range;
  grid.axes[1] = p.amplitude;
  grid.axes[2] = p.temperature;
  for (int k = 0; k < grid.dims; ++k) {
    grid.extent[k] = static_cast<std::size_t>(grid.axes[k].basis_count());
    grid.knots.emplace_back(grid.axes[k]);
  }
  grid.parameters = grid.extent[0] * grid.extent[1] * grid.extent[2];
  return grid;
}

}  // namespace

SurfaceFitResult fit_bspline_surface(const SurfaceFitData& data, const BSplineFitOptions& options) {
  options.validate();
  const std::string who = "fit_bspline_surface";
  const Columns c = validate_data(data, options.use_temperature, who);
  if (options.log_amplitude && !(c.domain.amplitude_min > 0)) {
    throw std::invalid_argument(who +
                                ": amplitude must be positive for a log-scale amplitude axis"
                                " (log_amplitude = true)");
  }
  BSplineSurfaceParams p;
  p.use_temperature = options.use_temperature;
  p.intensity = options.intensity;
  p.domain = c.domain;
  const int dims = options.use_temperature ? 3 : 2;
  const bool log_scale[3] = {false, options.log_amplitude, false};
  const double* column[3] = {c.range, c.amplitude, c.temperature};
  const double lo[3] = {c.domain.range_min_m, c.domain.amplitude_min, c.domain.temperature_min_c};
  const double hi[3] = {c.domain.range_max_m, c.domain.amplitude_max, c.domain.temperature_max_c};
  // Each axis's distinct coordinates, sorted (quantile knots are drawn from
  // them; the ladder's counts are capped by them); not needed (nor sorted)
  // for given uniform knots.
  std::vector<double> distinct[3];
  const bool need_distinct = options.choose_intervals_by_gcv ||
                             std::ranges::find(options.knot_placement, KnotPlacement::quantile) !=
                                 options.knot_placement.end();
  for (int k = 0; k < (need_distinct ? dims : 0); ++k) {
    distinct[k].resize(c.rows);
    for (std::size_t row = 0; row < c.rows; ++row) {
      distinct[k][row] = log_scale[k] ? std::log(column[k][row]) : column[k][row];
    }
    std::sort(distinct[k].begin(), distinct[k].end());
    distinct[k].erase(std::unique(distinct[k].begin(), distinct[k].end()), distinct[k].end());
  }
  // One axis's knots. Quantile knots are quantiles of the distinct coordinates,
  // not of the rows (Ruppert 2002): repeats of one target, and the rows a
  // saturating reading piles at a few values, would otherwise pull knots onto
  // one point; the cross-validation is over targets, so the knots follow
  // where the targets lie. Breakpoint k of m is the distinct value of rank
  // round(k (D - 1) / m), so m <= D - 1 keeps them strictly increasing and the
  // ends at the data's extremes (as with uniform knots).
  const auto make_axis = [&](int k, int intervals, KnotPlacement placement) {
    if (placement == KnotPlacement::uniform) {
      const auto coordinate = [&](double x) { return log_scale[k] ? std::log(x) : x; };
      return BSplineAxis::uniform(coordinate(lo[k]), coordinate(hi[k]), intervals, log_scale[k]);
    }
    const std::vector<double>& v = distinct[k];
    const int m = std::max(1, std::min(intervals, static_cast<int>(v.size()) - 1));
    BSplineAxis a;
    a.log_scale = log_scale[k];
    a.breakpoints.resize(static_cast<std::size_t>(m) + 1);
    for (int i = 0; i <= m; ++i) {
      const double rank = static_cast<double>(i) * static_cast<double>(v.size() - 1) / m;
      a.breakpoints[static_cast<std::size_t>(i)] = v[static_cast<std::size_t>(std::lround(rank))];
    }
    return a;
  };
  struct AxisChoice {
    int intervals = 1;
    KnotPlacement placement = KnotPlacement::uniform;
  };
  const auto set_axes = [&](const AxisChoice* choice) {
    p.range = make_axis(0, choice[0].intervals, choice[0].placement);
    p.amplitude = make_axis(1, choice[1].intervals, choice[1].placement);
    if (options.use_temperature) {
      p.temperature = make_axis(2, choice[2].intervals, choice[2].placement);
    }
  };
  // No row-count requirement: the second-difference penalty determines every
  // coefficient the data leave free (its null space, planes, needs only the
  // spread checked above).
  const bool choose_smoothing = options.choose_smoothing_by_gcv ||
                                (options.choose_intervals_by_gcv && !options.keep_smoothing);
  const std::size_t coefficient_limit = bspline_coefficient_limit(choose_smoothing);
  const std::vector<Fold> folds = make_folds(c);
  const double ones[3] = {1, 1, 1};
  GridFit best;
  AxisChoice chosen[3];
  if (options.choose_intervals_by_gcv) {
    // Per axis: a ladder of interval counts, capped so an axis never has more
    // intervals than distinct values minus one. Every combination of counts
    // with uniform knots first (as before knots could be placed), then, one
    // axis at a time with the others kept, each count with quantile knots: a
    // coordinate step that costs a few fits more per axis instead of
    // doubling the whole product. A quantile grid within a tenth of an
    // interval of the uniform one (data spread evenly, as on a grid of
    // distances) is not tried. On a tie the earlier (uniform) fit is kept.
    const auto ladder = [&](int k, std::initializer_list<int> counts) {
      const auto d = static_cast<int>(std::min<std::size_t>(distinct[k].size(), 1000));
      std::vector<int> out;
      for (int n : counts) {
        const int capped = std::max(1, std::min(n, d - 1));
        if (std::find(out.begin(), out.end(), capped) == out.end()) out.push_back(capped);
      }
      return out;
    };
    const std::vector<int> counts[3] = {
        ladder(0, {3, 5, 8, 12}), ladder(1, {3, 5, 8, 12}),
        options.use_temperature ? ladder(2, {2, 3, 5}) : std::vector<int>{1}};
    const auto try_grid = [&](const AxisChoice* choice) {
      set_axes(choice);
      GridFit fit = fit_on_grid(c, folds, make_grid(p, dims), options.smoothing, ones,
                                choose_smoothing, false, options.shrink_to_zero);
      if (fit.score < best.score * (1.0 - 1e-9)) {
        best = std::move(fit);
        std::copy_n(choice, 3, chosen);
      }
    };
    // Grids sized to the data and to the solve's cost: at most
    // kMaxBSplineCoefficientsPerRow per row and the coefficient limit (a
    // 15 x 15 x 8 grid of 180 rows had taken over 600 s); the smallest grid
    // is always tried.
    const std::size_t grid_limit = std::min<std::size_t>(
        coefficient_limit,
        static_cast<std::size_t>(kMaxBSplineCoefficientsPerRow * static_cast<double>(c.rows)));
    const auto within_limit = [&](const AxisChoice* choice) {
      std::size_t coefficients = 1;
      for (int k = 0; k < dims; ++k)
        coefficients *= static_cast<std::size_t>(choice[k].intervals + 3);
      const bool smallest = choice[0].intervals == counts[0].front() &&
                            choice[1].intervals == counts[1].front() &&
                            choice[2].intervals == counts[2].front();
      return smallest || coefficients <= grid_limit;
    };
    for (int ir : counts[0]) {
      for (int ia : counts[1]) {
        for (int it : counts[2]) {
          const AxisChoice choice[3] = {{ir, KnotPlacement::uniform},
                                        {ia, KnotPlacement::uniform},
                                        {it, KnotPlacement::uniform}};
          if (within_limit(choice)) try_grid(choice);
        }
      }
    }
    if (std::isfinite(best.score)) {
      for (int k = 0; k < dims; ++k) {
        const AxisChoice kept[3] = {chosen[0], chosen[1], chosen[2]};
        for (int n : counts[k]) {
          if (make_axis(k, n, KnotPlacement::quantile).is_uniform(0.1)) continue;
          AxisChoice choice[3] = {kept[0], kept[1], kept[2]};
          choice[k] = {n, KnotPlacement::quantile};
          if (within_limit(choice)) try_grid(choice);
        }
      }
    }
    if (!std::isfinite(best.score)) {
      for (int k = 0; k < 3; ++k) chosen[k] = {counts[k].front(), KnotPlacement::uniform};
      set_axes(chosen);
      best = fit_on_grid(c, folds, make_grid(p, dims), options.smoothing, ones, choose_smoothing,
                         false, options.shrink_to_zero);
    }
    set_axes(chosen);
    best = fit_on_grid(c, folds, make_grid(p, dims), best.smoothing, best.axis_weight, false, true,
                       options.shrink_to_zero);
  } else {
    chosen[0] = {options.intervals_range, options.knot_placement[0]};
    chosen[1] = {options.intervals_amplitude, options.knot_placement[1]};
    chosen[2] = {options.intervals_temperature, options.knot_placement[2]};
    set_axes(chosen);
    const Grid grid = make_grid(p, dims);
    if (grid.parameters > coefficient_limit) {
      std::string intervals = std::to_string(options.intervals_range) + " x " +
                              std::to_string(options.intervals_amplitude);
      if (dims == 3) intervals += " x " + std::to_string(options.intervals_temperature);
      throw std::invalid_argument(
          who + ": " + intervals + " knot intervals make " + std::to_string(grid.parameters) +
          " coefficients, more than the " + std::to_string(coefficient_limit) + " a fit with " +
          (choose_smoothing ? "cross-validated" : "fixed") +
          " smoothing solves in bounded time; use fewer knot intervals");
    }
    best = fit_on_grid(c, folds, make_grid(p, dims), options.smoothing,
                       choose_smoothing ? ones : options.axis_weight, choose_smoothing, true,
                       options.shrink_to_zero);
  }
  const PenalizedSolution& sol = best.solution;
  p.coefficients.assign(sol.coefficients.data(), sol.coefficients.data() + sol.coefficients.size());
  auto& s = p.fit;
  s.rows = c.rows;
  s.parameters = best.grid.parameters;
  s.rank = best.grid.parameters;
  s.smoothing = best.smoothing;
  s.effective_parameters = sol.effective_parameters;
  s.condition_number = sol.condition_number;
  s.cv_rms_m = std::isfinite(best.score) ? std::sqrt(best.score) : 0.0;
  BSplineSurface probe(p);
  s.residual_rms_m = residual_rms(probe, data);
  p.fit = s;
  SurfaceFitResult result = make_result(std::make_shared<const BSplineSurface>(std::move(p)), s);
  for (int k = 0; k < dims; ++k) {
    const BSplineAxis& axis = best.grid.axes[k];
    result.intervals[k] = axis.intervals();
    result.placement[k] = chosen[k].placement;
    result.axis_weight[k] = best.axis_weight[k];
    for (double t : axis.breakpoints) result.knots[k].push_back(axis.log_scale ? std::exp(t) : t);
  }
  return result;
}

}  // namespace tofkit::calib
