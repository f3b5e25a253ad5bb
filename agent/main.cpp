// deif_agent: one mobile sensor of the decentralized network (docs/RUNNING.md).
//   deif_agent --config FILE --id J [--set KEY=VALUE] [--out DIR] [--log-dir DIR]
//              [--domain D] [--seed N] [--run NAME] [--append]
// Exit codes: 0 finished (or stopped by SIGINT/SIGTERM), 1 runtime error, 2 bad config or
// arguments (nothing started), 3 the agent id is already live in the run.
#include <memory>
#include <string>

#include <CLI/CLI.hpp>

#include "agent/agent_node.hpp"
#include "dds/application.hpp"

int main(int argc, char** argv) {
  deif::AgentId id = 0;
  deif::dds::ProcessSpec spec;
  spec.program = "deif_agent";
  spec.description = "deif_agent: one DEIF sensor agent; talks to its peers and the target over DDS";
  spec.add_options = [&id](CLI::App& cli) {
    cli.add_option("--id", id, "This agent's id, 1..agents.count")->required();
  };
  spec.logger_name = [&id] { return "agent-" + std::to_string(id); };
  spec.check = [&id](const deif::Config& config) {
    if (id < 1 || id > config.agents.count) {  // ids are 1..count
      throw deif::ConfigError("--id", "agents.count", 0,
                              std::to_string(id) + " is outside 1.." +
                                  std::to_string(config.agents.count));
    }
  };
  spec.make = [&id](deif::dds::ProcessContext& context) {
    return std::make_unique<deif::agent::AgentNode>(context, id);
  };
  return deif::dds::RunMain(argc, argv, spec);
}
