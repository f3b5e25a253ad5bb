// deif_target: the world of the decentralized sensor network (see DESIGN.md).
//   deif_target --config FILE [--log-dir DIR] [--domain D] [--out DIR] [--seed N] [--start-step K]
// Exit codes: 0 finished (or stopped by SIGINT/SIGTERM), 1 runtime error, 2 bad
// configuration or arguments.
#include <cstdio>
#include <exception>
#include <optional>
#include <string>

#include <CLI/CLI.hpp>
#include <spdlog/spdlog.h>

#include "agent/dds_common.hpp"
#include "common/config.hpp"
#include "target/target_app.hpp"

namespace {
constexpr const char* kProgram = "deif_target";

int Fail(int code, const std::string& what) {
  std::fprintf(stderr, "%s: error: %s\n", kProgram, what.c_str());
  return code;
}
}  // namespace

int main(int argc, char** argv) {
  using namespace deif;
  deif::dds::SignalStopper signals;  // first: blocks SIGINT/SIGTERM before any thread exists

  CLI::App cli{"deif_target: moves the target and publishes truth and noisy ranges over DDS"};
  std::string config_path;
  std::string log_dir;
  std::string out_dir;
  std::optional<int> domain;
  std::optional<std::uint64_t> seed;
  std::optional<StepIndex> start_step;
  cli.add_option("--config", config_path, "Scenario YAML file (see configs/default.yaml)")
      ->required();
  cli.add_option("--log-dir", log_dir, "Also write the log to DIR/target.log")
      ->check(CLI::ExistingDirectory);
  cli.add_option("--domain", domain, "DDS domain id (0..232); overrides network.domain_id");
  cli.add_option("--out", out_dir, "Run folder for target.csv and ranges.csv (none if omitted)")
      ->check(CLI::ExistingDirectory);
  cli.add_option("--seed", seed, "Overrides scenario.seed (trajectory and range noise)");
  cli.add_option("--start-step", start_step,
                 "Resume at step K after a restart (appends to the CSVs); default: the agents' "
                 "latest step + 1")
      ->check(CLI::PositiveNumber);
  try {
    cli.parse(argc, argv);
  } catch (const CLI::CallForHelp& e) {
    return cli.exit(e);
  } catch (const CLI::ParseError& e) {
    return Fail(target::kExitBadConfig, e.what());
  }

  Config config;
  try {
    config = LoadConfig(config_path);
  } catch (const std::exception& e) {  // ConfigError names file, key and line
    return Fail(target::kExitBadConfig, e.what());
  }
  if (domain) config.network.domain_id = *domain;
  if (seed) config.scenario.seed = *seed;
  if (config.network.domain_id < 0 || config.network.domain_id > 232) {
    return Fail(target::kExitBadConfig,
                "--domain: " + std::to_string(config.network.domain_id) + " is outside 0..232");
  }

  auto log = deif::dds::MakeLogger("target", log_dir);
  try {
    target::TargetApp app(config, target::TargetOptions{out_dir, start_step}, log);
    signals.SetHandler([&app, log](int signal_number) {
      log->info("signal {}: stopping", signal_number);
      app.stop();
    });
    const int code = app.run();
    signals.SetHandler(nullptr);
    return code;
  } catch (const ConfigError& e) {
    return Fail(target::kExitBadConfig, e.what());
  } catch (const std::exception& e) {
    log->critical("{}", e.what());
    return Fail(target::kExitRuntimeError, e.what());
  }
}
