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
#include "dds/dds_common.hpp"
#include "dds/process_options.hpp"
#include "common/config/config.hpp"

namespace {
constexpr const char* kProgram = "deif_agent";

int Fail(int code, const std::string& what) { return deif::dds::FailWith(kProgram, code, what); }
}  // namespace

int main(int argc, char** argv) {
  using namespace deif;
  deif::dds::SignalStopper signals;  // first: blocks SIGINT/SIGTERM before any thread exists

  CLI::App cli{"deif_agent: one DEIF sensor agent; talks to its peers and the target over DDS"};
  deif::dds::ProcessOptions options;
  int id = 0;
  deif::dds::AddProcessOptions(cli, options, "agent-<id>", "agent_<id>.csv");
  cli.add_option("--id", id, "This agent's id, 1..agents.count")->required();
  try {
    cli.parse(argc, argv);
  } catch (const CLI::CallForHelp& e) {
    return cli.exit(e);
  } catch (const CLI::ParseError& e) {
    return Fail(agent::kExitBadConfig, e.what());
  }

  Config config;
  try {
    config = deif::dds::LoadProcessConfig(options);
  } catch (const std::exception& e) {  // ConfigError names file, key and line
    return Fail(agent::kExitBadConfig, e.what());
  }
  if (id < 1 || id > config.agents.count) {  // the start angle exists for 1..count only
    return Fail(agent::kExitBadConfig, "--id: " + std::to_string(id) + " is outside 1.." +
                                           std::to_string(config.agents.count) + " (agents.count)");
  }

  auto log = deif::dds::MakeLogger("agent-" + std::to_string(id), options.log_dir);
  try {
    agent::AgentApp app(config, agent::AgentOptions{id, options.out_dir}, log);
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
