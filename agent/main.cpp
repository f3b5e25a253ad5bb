// deif_agent: one mobile sensor of the decentralized network (see DESIGN.md).
//   deif_agent --config FILE --id J [--log-dir DIR] [--domain D] [--out DIR] [--seed N]
// Exit codes: 0 finished (or stopped by SIGINT/SIGTERM), 1 runtime error, 2 bad
// configuration or arguments, 3 the agent id is already live.
#include <cstdio>
#include <exception>
#include <optional>
#include <string>

#include <CLI/CLI.hpp>
#include <spdlog/spdlog.h>

#include "agent/agent_app.hpp"
#include "agent/dds_common.hpp"
#include "common/config.hpp"

namespace {
constexpr const char* kProgram = "deif_agent";

int Fail(int code, const std::string& what) {
  std::fprintf(stderr, "%s: error: %s\n", kProgram, what.c_str());
  return code;
}
}  // namespace

int main(int argc, char** argv) {
  using namespace deif;
  deif::dds::SignalStopper signals;  // first: blocks SIGINT/SIGTERM before any thread exists

  CLI::App cli{"deif_agent: one DEIF sensor agent; talks to its peers and the target over DDS"};
  std::string config_path;
  int id = 0;
  std::string log_dir;
  std::string out_dir;
  std::optional<int> domain;
  std::optional<std::uint64_t> seed;
  cli.add_option("--config", config_path, "Scenario YAML file (see configs/default.yaml)")
      ->required();
  cli.add_option("--id", id, "This agent's id, 1..agents.count")
      ->required();
  cli.add_option("--log-dir", log_dir, "Also write the log to DIR/agent-<id>.log")
      ->check(CLI::ExistingDirectory);
  cli.add_option("--domain", domain, "DDS domain id (0..232); overrides network.domain_id");
  cli.add_option("--out", out_dir, "Run folder for agent_<id>.csv (none written if omitted)")
      ->check(CLI::ExistingDirectory);
  cli.add_option("--seed", seed, "Overrides scenario.seed");
  try {
    cli.parse(argc, argv);
  } catch (const CLI::CallForHelp& e) {
    return cli.exit(e);
  } catch (const CLI::ParseError& e) {
    return Fail(agent::kExitBadConfig, e.what());
  }

  Config config;
  try {
    config = LoadConfig(config_path);
  } catch (const std::exception& e) {  // ConfigError names file, key and line
    return Fail(agent::kExitBadConfig, e.what());
  }
  if (domain) config.network.domain_id = *domain;
  if (seed) config.scenario.seed = *seed;
  if (config.network.domain_id < 0 || config.network.domain_id > 232) {
    return Fail(agent::kExitBadConfig,
                "--domain: " + std::to_string(config.network.domain_id) + " is outside 0..232");
  }
  if (id < 1 || id > config.agents.count) {  // the start angle exists for 1..count only
    return Fail(agent::kExitBadConfig, "--id: " + std::to_string(id) + " is outside 1.." +
                                           std::to_string(config.agents.count) + " (agents.count)");
  }

  auto log = deif::dds::MakeLogger("agent-" + std::to_string(id), log_dir);
  try {
    agent::AgentApp app(config, agent::AgentOptions{id, out_dir}, log);
    signals.SetHandler([&app, log](int signal_number) {
      log->info("signal {}: stopping", signal_number);
      app.stop();
    });
    const int code = app.run();
    signals.SetHandler(nullptr);
    return code;
  } catch (const ConfigError& e) {
    return Fail(agent::kExitBadConfig, e.what());
  } catch (const std::exception& e) {
    log->critical("{}", e.what());
    return Fail(agent::kExitRuntimeError, e.what());
  }
}
