// tofkit sweep --plan sweep.toml [--shard K/N] --out DIR: a plan's points
// (axes of device keys and conditions) measured into DIR/sweep.csv, a row
// per point, with plots; resumable; shards joined by tofkit merge.

#include <fmt/format.h>

#include <chrono>
#include <memory>
#include <nlohmann/json.hpp>
#include <string>

#include "app.hpp"
#include "mpi_world.hpp"
#include "scan_shard.hpp"
#include "sweep_run.hpp"

namespace tofkit::app {
namespace {

struct SweepOptions {
  std::string plan, out, shard;
};

void run_sweep_command(const SweepOptions& o, const AppContext& ctx) {
  const io::SweepPlan plan = io::load_sweep_plan(o.plan, sweep_base(ctx));
  const Shard shard = o.shard.empty() ? Shard{} : parse_shard(o.shard, "--shard");
  const auto [first, last] = shard.range(plan.points());
  std::string record;
  if (!shard.whole()) {
    record = nlohmann::json{{"kind", "tofkit sweep shard"},
                            {"version", 1},
                            {"shard", shard.index},
                            {"shards", shard.count},
                            {"first_point", first},
                            {"last_point", last},
                            {"points", plan.points()},
                            {"fingerprint", fmt::format("{:016x}", plan.fingerprint)},
                            {"header", io::sweep_header(plan)},
                            {"axes", plan.axes.size()}}
                 .dump(1) +
             "\n";
  }
  const auto start = std::chrono::steady_clock::now();
  const SweepRunSummary s = run_sweep(plan, ctx, o.out, first, last, shard.whole(), record);
  mpi_done();
  if (mpi_world().rank != 0) return;
  const double seconds =
      std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  fmt::print(stderr, "tofkit sweep: {} points ({} run, {} resumed{}) in {:.2f} s -> {}/sweep.csv\n",
             s.points, s.run, s.resumed,
             shard.whole() ? ""
                           : fmt::format("; shard {}/{}: points {}..{}", shard.index, shard.count,
                                         first, last),
             seconds, o.out);
}

const bool registered = register_command("sweep", [](CLI::App& sub, AppContext& ctx) {
  sub.description("measure a plan's grid of device keys and conditions into one table");
  auto o = std::make_shared<SweepOptions>();
  sub.add_option("--plan", o->plan, "sweep plan (TOML: [axes], [measure], [budget])")->required();
  sub.add_option("--shard", o->shard, "K/N: only points [K n/N, (K+1) n/N), for tofkit merge");
  sub.add_option("--out", o->out, "output directory (made if missing)")->required();
  sub.callback([o, &ctx] { run_sweep_command(*o, ctx); });
});

}  // namespace
}  // namespace tofkit::app
