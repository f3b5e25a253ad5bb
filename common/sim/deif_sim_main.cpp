// deif_sim: the in-process simulation. Runs the target and N agents, each with the protocol
// the DDS processes run, over a simulated network (network_sim:) in virtual time; writes
// the run artefacts, metrics.csv and summary.json. Also evaluates any run folder.
//
//   deif_sim --config FILE [--set KEY=VALUE ...] [--out DIR] [--seed N] [--steps N] [--quiet]
//   deif_sim --config FILE [--set ...] --check
//   deif_sim --config FILE --evaluate RUN        metrics.csv into RUN, summary metrics on stdout
//   deif_sim --config FILE --replay-ranges RUN/ranges.csv --replay-out central.csv
//
// Exit status: 0 ok, 2 bad configuration or command line (one line on stderr, nothing
// started or written), 1 any other error.
#include <CLI/CLI.hpp>
#include <nlohmann/json.hpp>

#include <chrono>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <exception>
#include <filesystem>
#include <fstream>
#include <optional>
#include <string>
#include <vector>

#include "common/artefacts/artefacts.hpp"
#include "common/config/config.hpp"
#include "common/protocol/agent_protocol.hpp"
#include "common/sim/metrics.hpp"
#include "common/sim/replay.hpp"
#include "common/sim/simulation.hpp"

namespace {

using deif::protocol::kExitBadConfig;
using deif::protocol::kExitOk;
using deif::protocol::kExitRuntimeError;

struct Options {
  std::string config_path;
  std::vector<std::string> overrides;
  std::string out_dir;
  // Kept as text and handed to the config parser as overrides, which judges them as it
  // judges the keys (a number conversion here would wrap --seed -1 to 2^64 - 1).
  std::optional<std::string> seed;
  std::optional<std::string> steps;
  bool quiet = false;
  bool verbose = false;
  bool check_only = false;
  std::string evaluate;
  std::string replay_ranges;
  std::string replay_out;
};

// A NaN is written as null (JSON has no NaN), never as 0.
nlohmann::json Number(double v) { return std::isfinite(v) ? nlohmann::json(v) : nlohmann::json(); }

nlohmann::json MetricsJson(const deif::sim::RunMetrics& m) {
  nlohmann::json j = {{"last_step", m.last_step},
                      {"rmse_m", Number(m.rmse_m)},
                      {"max_error_m", Number(m.max_error_m)},
                      {"anees", Number(m.anees)},
                      {"pcrlb_rmse_m", Number(m.pcrlb_rmse_m)},
                      {"mean_optimality_ratio", Number(m.mean_optimality_ratio)},
                      {"final_max_gap_error_rad", Number(m.final_max_gap_error_rad)},
                      {"final_agents", m.final_agents},
                      {"agreement_fraction", Number(m.agreement_fraction)},
                      {"agreement_tolerance_m", deif::sim::kAgreementToleranceM},
                      {"max_disagreement_m", Number(m.max_disagreement_m)},
                      {"longest_disagreement_steps", m.longest_disagreement_steps},
                      {"non_finite_estimates", m.any_non_finite}};
  nlohmann::json agents = nlohmann::json::object();
  for (const auto& [id, a] : m.per_agent) {
    agents[std::to_string(id)] = {{"rows", a.rows},
                                  {"first_step", a.first_step},
                                  {"last_step", a.last_step},
                                  {"missing_rows", a.missing_rows},
                                  {"rmse_m", Number(a.rmse_m)},
                                  {"max_error_m", Number(a.max_error_m)},
                                  {"rejected", a.rejected},
                                  {"dropped", a.dropped},
                                  {"late", a.late},
                                  {"deadline_misses", a.deadline_misses}};
  }
  j["per_agent"] = agents;
  return j;
}

// The output folder must be creatable and writable before anything runs.
void CheckOutDir(const std::string& dir) {
  std::error_code ec;
  std::filesystem::create_directories(dir, ec);
  const std::filesystem::path probe = std::filesystem::path(dir) / ".deif_write_test";
  std::ofstream out(probe);
  if (ec || !out) {
    throw deif::ConfigError("--out", "", 0, "cannot write to the folder '" + dir + "'");
  }
  out.close();
  std::filesystem::remove(probe, ec);
}

int Evaluate(const deif::Config& config, const Options& options) {
  const deif::sim::RunData run = deif::sim::LoadRun(options.evaluate, config.agents.count);
  const deif::sim::RunMetrics metrics = deif::sim::EvaluateRun(config, run);
  deif::sim::WriteMetricsCsv((std::filesystem::path(options.evaluate) / "metrics.csv").string(),
                             metrics);
  std::printf("%s\n", MetricsJson(metrics).dump(2).c_str());
  return kExitOk;
}

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

const char* LevelName(deif::protocol::LogLevel level) {
  switch (level) {
    case deif::protocol::LogLevel::kDebug: return "debug";
    case deif::protocol::LogLevel::kInfo: return "info";
    case deif::protocol::LogLevel::kWarn: return "warning";
    case deif::protocol::LogLevel::kError: return "error";
  }
  return "?";
}

int Simulate(const deif::Config& config, const Options& options) {
  deif::sim::SimulationOptions sim_options;
  sim_options.out_dir = options.out_dir;
  if (options.verbose) {
    sim_options.log = [](const std::string& process, deif::protocol::LogLevel level,
                         const std::string& text) {
      std::fprintf(stderr, "[%s] [%s] %s\n", process.c_str(), LevelName(level), text.c_str());
    };
  }
  const auto wall_start = std::chrono::steady_clock::now();
  const deif::sim::SimulationResult result = deif::sim::RunSimulation(config, sim_options);
  const double wall_s =
      std::chrono::duration<double>(std::chrono::steady_clock::now() - wall_start).count();
  const deif::sim::RunMetrics& m = result.metrics;

  bool ok = true;
  nlohmann::json processes = nlohmann::json::array();
  for (const auto& [name, code] : result.exit_codes) {
    bool expected = code == 0;
    if (code == -9) {  // killed by a scripted fault
      for (const deif::FaultConfig& f : config.faults) {
        expected = expected || (f.action == deif::FaultAction::kKill &&
                                name == "agent-" + std::to_string(f.agent_id));
      }
    }
    ok = ok && expected;
    processes.push_back({{"name", name}, {"exit_status", code}, {"expected", expected}});
  }
  if (!options.out_dir.empty()) {
    nlohmann::json counters = nlohmann::json::object();
    for (const auto& [id, c] : result.counters) {
      counters[std::to_string(id)] = {{"rejected", c.rejected}, {"dropped", c.dropped},
                                      {"late", c.late},         {"deadline_misses", c.deadline_misses},
                                      {"adoptions", c.adoptions}, {"merges", c.merges},
                                      {"by_reason", c.by_reason}};
    }
    nlohmann::json summary;
    summary["config"] = {{"source", config.source}, {"yaml", deif::ToYaml(config)}};
    summary["seeds"] = {{"scenario", config.scenario.seed}};
    summary["processes"] = processes;
    summary["metrics"] = MetricsJson(m);
    summary["counters"] = counters;
    summary["network"] = {{"messages_sent", result.messages_sent},
                          {"messages_lost_first_try", result.messages_lost_first_try},
                          {"virtual_time_s", result.virtual_time_s}};
    summary["wall_time_s"] = wall_s;
    summary["ok"] = ok;
    const std::filesystem::path path = std::filesystem::path(options.out_dir) / "summary.json";
    std::ofstream out(path);
    out << summary.dump(2) << "\n";
    if (!out) throw std::runtime_error("cannot write '" + path.string() + "'");
  }
  if (!options.quiet) {
    std::printf(
        "%s: %lld steps, %d agents at the end, %s\n"
        "  rmse %.4g m (PCRLB %.4g m), max error %.4g m, ANEES %.3g\n"
        "  mean optimality ratio %.4f, final max gap error %.3g rad\n"
        "  agents agree (<= %.0e m) at %.2f %% of steps; %lld messages, %lld lost on the first try\n",
        config.scenario.name.c_str(), static_cast<long long>(m.last_step), m.final_agents,
        ok ? "every process as planned" : "A PROCESS FAILED", m.rmse_m, m.pcrlb_rmse_m,
        m.max_error_m, m.anees, m.mean_optimality_ratio, m.final_max_gap_error_rad,
        deif::sim::kAgreementToleranceM, 100.0 * m.agreement_fraction,
        static_cast<long long>(result.messages_sent),
        static_cast<long long>(result.messages_lost_first_try));
  }
  return ok ? kExitOk : kExitRuntimeError;
}

int Run(const Options& options) {
  // Parse and check everything before creating or starting anything.
  deif::Config config;
  try {
    std::vector<std::string> overrides = options.overrides;
    if (options.seed) overrides.push_back("scenario.seed=" + *options.seed);
    if (options.steps) overrides.push_back("scenario.steps=" + *options.steps);
    config = deif::LoadConfig(options.config_path, overrides);
    if (!options.out_dir.empty() && !options.check_only) CheckOutDir(options.out_dir);
  } catch (const deif::ConfigError& e) {
    std::fprintf(stderr, "deif_sim: error: %s\n", e.what());
    return kExitBadConfig;
  }
  if (options.check_only) return kExitOk;
  if (!options.evaluate.empty()) return Evaluate(config, options);
  if (!options.replay_ranges.empty()) return Replay(config, options);
  return Simulate(config, options);
}

}  // namespace

int main(int argc, char** argv) {
  CLI::App app{"deif_sim: in-process simulation of the decentralized sensor network"};
  Options options;
  app.add_option("--config", options.config_path, "scenario YAML file (see configs/default.yaml)")
      ->required();
  app.add_option("--set", options.overrides,
                 "override a key: dotted.key=YAML value (repeatable), e.g. --set agents.count=6");
  app.add_option("--out", options.out_dir,
                 "folder for the artefacts, metrics.csv and summary.json (created)");
  app.add_option("--seed", options.seed, "override scenario.seed");
  app.add_option("--steps", options.steps, "override scenario.steps");
  app.add_flag("--quiet", options.quiet, "no summary on stdout");
  app.add_flag("--verbose", options.verbose, "every simulated process's log on stderr");
  app.add_flag("--check", options.check_only,
               "only parse and validate the config (exit 0 if good, 2 with the reason if not)");
  app.add_option("--evaluate", options.evaluate,
                 "compute the metrics of a run folder (writes RUN/metrics.csv, prints JSON)");
  auto* replay = app.add_option("--replay-ranges", options.replay_ranges,
                                "replay the centralized EIF over this ranges.csv instead of "
                                "simulating (the reference for a run's agents)");
  app.add_option("--replay-out", options.replay_out, "CSV written by --replay-ranges")->needs(replay);
  replay->needs("--replay-out");
  try {
    app.parse(argc, argv);
  } catch (const CLI::CallForHelp& e) {
    return app.exit(e);
  } catch (const CLI::CallForAllHelp& e) {
    return app.exit(e);
  } catch (const CLI::ParseError& e) {
    std::fprintf(stderr, "deif_sim: error: %s\n", e.what());
    return kExitBadConfig;
  }
  try {
    return Run(options);
  } catch (const std::exception& e) {
    std::fprintf(stderr, "deif_sim: error: %s\n", e.what());
    return kExitRuntimeError;
  }
}
