#pragma once
/// \file `tofkit sweep`: a plan (TOML) of parameter axes and the measurements
/// to take at each point of their Cartesian product; one table, a row per
/// point (the axes' values first, first axis slowest), plots of the figures
/// over the first axis; resumable; shardable (`--shard K/N`: a fixed range of
/// points) with `tofkit merge` joining the shards' tables into the bytes of
/// the one-process run.
///
///     [axes]                               # any device key (as --set) or a condition
///     "laser.pulse_width_ns" = [1.0, 2.0, 4.0]
///     distance_m = [1.0, 4.0]              # conditions: distance_m, reflectance,
///     reflectance = [0.1, 0.9]             #   angle_deg, ambient_c, seed
///     [measure]                            # count measurements of `shots` shots
///     shots = 1000                         #   (a condition not on an axis may be
///     count = 3                            #   given here: distance_m = 2)
///     mode = "analytic"
///     [budget]                             # optional: link-budget figures too

#include <cstdint>
#include <filesystem>
#include <functional>
#include <string>
#include <vector>

#include "app.hpp"
#include "tofkit/io/sweep_plan.hpp"

namespace tofkit::app {

/// The base configuration of a sweep's points: the global options.
[[nodiscard]] io::SweepBase sweep_base(const AppContext& ctx);

struct SweepRunSummary {
  std::uint64_t points = 0, resumed = 0, run = 0;
};

/// Runs points [first, last) into `out`/sweep.csv (rows in order), resuming
/// from `out`/.sweep.journal; `plots`: also the plots. Progress on stderr.
SweepRunSummary run_sweep(const io::SweepPlan& plan, const AppContext& ctx,
                          const std::filesystem::path& out, std::uint64_t first, std::uint64_t last,
                          bool plots, const std::string& shard_record_json = "");

/// Is `directory` a sweep shard's?
[[nodiscard]] bool is_sweep_shard(const std::filesystem::path& directory);

/// Joins sweep shards' tables into `out`/sweep.csv with the plots; returns the rows.
std::uint64_t merge_sweep_shards(const std::filesystem::path& out,
                                 const std::vector<std::filesystem::path>& shards);

/// The plots of a sweep table's figures over its first axis.
void write_sweep_plots(const std::filesystem::path& out, const std::string& table,
                       std::size_t axis_count);

}  // namespace tofkit::app
