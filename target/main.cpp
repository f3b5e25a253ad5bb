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

#include "dds/dds_common.hpp"
#include "dds/process_options.hpp"
#include "common/config/config.hpp"
#include "target/target_app.hpp"

namespace {
constexpr const char* kProgram = "deif_target";

int Fail(int code, const std::string& what) { return deif::dds::FailWith(kProgram, code, what); }
}  // namespace

int main(int argc, char** argv) {
  using namespace deif;
  deif::dds::SignalStopper signals;  // first: blocks SIGINT/SIGTERM before any thread exists

  CLI::App cli{"deif_target: moves the target and publishes truth and noisy ranges over DDS"};
  deif::dds::ProcessOptions options;
  std::optional<StepIndex> start_step;
  deif::dds::AddProcessOptions(cli, options, "target", "target.csv and ranges.csv");
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
    config = deif::dds::LoadProcessConfig(options);
  } catch (const std::exception& e) {  // ConfigError names file, key and line
    return Fail(target::kExitBadConfig, e.what());
  }

  auto log = deif::dds::MakeLogger("target", options.log_dir);
  try {
    target::TargetApp app(config, target::TargetOptions{options.out_dir, start_step}, log);
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
