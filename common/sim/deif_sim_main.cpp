// deif_sim: the in-process simulation. Reads a scenario, runs the target and N DEIF agents
// in one loop (no transport), writes the run artefacts and summary.json.
//
//   deif_sim --config FILE [--out DIR] [--seed N] [--steps N] [--quiet]
//   deif_sim --config FILE --check
//   deif_sim --config FILE --replay-ranges RUN/ranges.csv --replay-out central.csv
//
// Exit status: 0 ok, 2 bad configuration or command line (one line on stderr, nothing
// written), 1 any other error.
#include <CLI/CLI.hpp>
#include <nlohmann/json.hpp>
#include <spdlog/sinks/stdout_color_sinks.h>
#include <spdlog/spdlog.h>

#include <cstdint>
#include <cstdio>
#include <exception>
#include <filesystem>
#include <fstream>
#include <iostream>
#include <optional>
#include <string>

#include "common/artefacts/artefacts.hpp"
#include "common/config/config.hpp"
#include "common/sim/replay.hpp"
#include "common/sim/simulation.hpp"

namespace {

constexpr int kExitOk = 0;
constexpr int kExitRuntimeError = 1;
constexpr int kExitConfigError = 2;

struct Options {
  std::string config_path;
  std::string out_dir;
  std::optional<std::uint64_t> seed;
  std::optional<deif::StepIndex> steps;
  bool quiet = false;
  bool check_only = false;
  std::string replay_ranges;
  std::string replay_out;
};

// The centralized EIF over a run's ranges.csv, written as step,x_est,y_est,p_xx,p_xy,p_yy,ranges.
int Replay(const deif::Config& config, const Options& options) {
  const std::vector<deif::ReplayRow> rows = deif::ReplayCentralized(config, options.replay_ranges);
  deif::CsvWriter out(options.replay_out, "step,x_est,y_est,p_xx,p_xy,p_yy,ranges");
  for (const deif::ReplayRow& r : rows) {
    out.WriteLine(std::to_string(r.step) + "," + deif::FormatDouble(r.estimate_m.x()) + "," +
                  deif::FormatDouble(r.estimate_m.y()) + "," +
                  deif::FormatDouble(r.covariance(0, 0)) + "," +
                  deif::FormatDouble(r.covariance(0, 1)) + "," +
                  deif::FormatDouble(r.covariance(1, 1)) + "," + std::to_string(r.ranges));
  }
  if (!options.quiet) std::printf("replayed %zu steps into %s\n", rows.size(), options.replay_out.c_str());
  return kExitOk;
}

// Command-line overrides, checked like the file's own keys.
void ApplyOverrides(const Options& options, deif::Config& config) {
  if (options.seed) config.scenario.seed = *options.seed;
  if (options.steps) {
    if (*options.steps < 1) {
      throw deif::ConfigError("--steps", "scenario.steps", 0,
                              "must be >= 1 (got " + std::to_string(*options.steps) + ")");
    }
    config.scenario.steps = *options.steps;
    for (const deif::FaultConfig& fault : config.faults) {
      if (fault.step > config.scenario.steps) {
        throw deif::ConfigError("--steps", "scenario.steps", 0,
                                "a fault at step " + std::to_string(fault.step) +
                                    " in " + config.source + " lies beyond --steps " +
                                    std::to_string(config.scenario.steps));
      }
    }
  }
}

nlohmann::json Summary(const deif::Config& config, const deif::SimulationMetrics& metrics) {
  nlohmann::json summary;
  summary["config"] = {{"source", config.source}, {"yaml", deif::ToYaml(config)}};
  summary["seed"] = config.scenario.seed;
  summary["processes"] = nlohmann::json::array({{{"name", "deif_sim"}, {"exit_status", 0}}});
  summary["metrics"] = {{"rmse_m", metrics.rmse_m},
                        {"max_error_m", metrics.max_error_m},
                        {"final_max_gap_error_rad", metrics.final_max_gap_error_rad},
                        {"mean_optimality_ratio", metrics.mean_optimality_ratio},
                        {"pcrlb_rmse_m", metrics.pcrlb_rmse_m},
                        {"anees", metrics.anees},
                        {"final_alive", metrics.final_alive},
                        {"steps", metrics.steps}};
  return summary;
}

int Run(const Options& options) {
  // Parse and check everything before creating or starting anything.
  deif::Config config;
  try {
    config = deif::LoadConfig(options.config_path);
    ApplyOverrides(options, config);
  } catch (const deif::ConfigError& e) {
    std::fprintf(stderr, "deif_sim: error: %s\n", e.what());
    return kExitConfigError;
  }
  if (options.check_only) return kExitOk;
  if (!options.replay_ranges.empty()) return Replay(config, options);

  auto logger = spdlog::stderr_color_mt("sim");
  logger->set_level(options.quiet ? spdlog::level::warn : spdlog::level::info);
  logger->info("scenario '{}' from {}: {} agents, {} steps, seed {}", config.scenario.name,
               config.source, config.agents.count, config.scenario.steps,
               config.scenario.seed);

  if (!options.out_dir.empty()) std::filesystem::create_directories(options.out_dir);
  const deif::SimulationMetrics metrics = deif::RunSimulation(config, options.out_dir);

  if (!options.out_dir.empty()) {
    const std::filesystem::path summary_path =
        std::filesystem::path(options.out_dir) / "summary.json";
    std::ofstream out(summary_path);
    out << Summary(config, metrics).dump(2) << "\n";
    if (!out) throw std::runtime_error("cannot write '" + summary_path.string() + "'");
    logger->info("artefacts written to {}", options.out_dir);
  }

  if (!options.quiet) {
    std::printf(
        "%s: %lld steps, %d agents alive at the end\n"
        "  rmse %.4g m (PCRLB %.4g m), max error %.4g m, ANEES %.3g\n"
        "  mean optimality ratio %.4f, final max gap error %.3g rad\n",
        config.scenario.name.c_str(), static_cast<long long>(metrics.steps),
        metrics.final_alive, metrics.rmse_m, metrics.pcrlb_rmse_m, metrics.max_error_m,
        metrics.anees, metrics.mean_optimality_ratio, metrics.final_max_gap_error_rad);
  }
  return kExitOk;
}

}  // namespace

int main(int argc, char** argv) {
  CLI::App app{"deif_sim: in-process simulation of the decentralized sensor network"};
  Options options;
  app.add_option("--config", options.config_path, "scenario YAML file (see configs/default.yaml)")
      ->required();
  app.add_option("--out", options.out_dir,
                 "folder for target.csv, ranges.csv, agent_<id>.csv and summary.json "
                 "(created; nothing is written without it)");
  app.add_option("--seed", options.seed, "override scenario.seed");
  app.add_option("--steps", options.steps, "override scenario.steps");
  app.add_flag("--quiet", options.quiet, "no log lines and no summary on stdout");
  app.add_flag("--check", options.check_only,
               "only parse and validate the config (exit 0 if good, 2 with the reason if not)");
  auto* replay = app.add_option("--replay-ranges", options.replay_ranges,
                                "replay the centralized EIF over this ranges.csv instead of "
                                "simulating (the reference for a run's agents)");
  app.add_option("--replay-out", options.replay_out, "CSV written by --replay-ranges")
      ->needs(replay);
  replay->needs("--replay-out");
  try {
    app.parse(argc, argv);
  } catch (const CLI::CallForHelp& e) {
    return app.exit(e);
  } catch (const CLI::CallForAllHelp& e) {
    return app.exit(e);
  } catch (const CLI::ParseError& e) {
    std::fprintf(stderr, "deif_sim: error: %s\n", e.what());
    return kExitConfigError;
  }

  try {
    return Run(options);
  } catch (const std::exception& e) {
    std::fprintf(stderr, "deif_sim: error: %s\n", e.what());
    return kExitRuntimeError;
  }
}
