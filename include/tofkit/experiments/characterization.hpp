#pragma once
/// \file The thesis's characterization protocols (reference/characterization_thesis.md,
/// Chapter 4), each run on a virtual rangefinder: cold-start warm-up, laser
/// turn-on transient, sampling rate vs resolution, environmental temperature,
/// mixed pixels, reflectance x distance, incidence angle. Each takes the device,
/// an options struct whose defaults follow the thesis, and a seed; each returns
/// the records, its finding as numbers (findings()), a table and a summary().
/// The end-to-end correction study is experiments/thesis_protocol.hpp.

#include "tofkit/experiments/characterization_angle.hpp"
#include "tofkit/experiments/characterization_common.hpp"
#include "tofkit/experiments/characterization_mixed_pixel.hpp"
#include "tofkit/experiments/characterization_reflectance.hpp"
#include "tofkit/experiments/characterization_sampling.hpp"
#include "tofkit/experiments/characterization_temperature.hpp"
#include "tofkit/experiments/characterization_turn_on.hpp"
#include "tofkit/experiments/characterization_warmup.hpp"
#include "tofkit/experiments/thesis_grey_chart.hpp"
