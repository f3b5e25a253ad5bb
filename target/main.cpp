// deif_target: the world of the decentralized sensor network (docs/RUNNING.md).
//   deif_target --config FILE [--set KEY=VALUE] [--out DIR] [--log-dir DIR] [--domain D]
//               [--seed N] [--run NAME] [--start-step K] [--hold-for-faults] [--append]
// Exit codes: 0 finished (or stopped by SIGINT/SIGTERM), 1 runtime error (e.g. no agent
// appeared), 2 bad config or arguments (nothing started), 3 the run already has a target.
#include <memory>
#include <optional>
#include <string>

#include <CLI/CLI.hpp>

#include "dds/application.hpp"
#include "target/target_node.hpp"

int main(int argc, char** argv) {
  deif::target::TargetOptions options;
  deif::StepIndex start_step = 0;
  deif::dds::ProcessSpec spec;
  spec.program = "deif_target";
  spec.description = "deif_target: moves the target and publishes truth and noisy ranges over DDS";
  spec.add_options = [&](CLI::App& cli) {
    cli.add_option("--start-step", start_step,
                   "Resume after a restart at step K, or after the agents' latest step if "
                   "that is later (appends to the CSVs); default: the agents' latest step + 1")
        ->check(CLI::PositiveNumber);
    cli.add_flag("--hold-for-faults", options.hold_for_faults,
                 "At a step with scripted faults print 'hold K' and, in lock-step, wait for "
                 "'go K' on stdin");
  };
  // Restarted in place, it resumes after the agents' newest step, and never before the step
  // it had reached (TargetNode::RestartOptionsOf gives that as the new --start-step).
  spec.logger_name = [] { return std::string("target"); };
  spec.check = [&](const deif::Config& config) {
    if (start_step > config.scenario.steps) {
      throw deif::ConfigError("--start-step", "scenario.steps", 0,
                              std::to_string(start_step) + " is beyond the last step " +
                                  std::to_string(config.scenario.steps));
    }
    if (start_step > 0) options.start_step = start_step;
  };
  spec.make = [&](deif::dds::ProcessContext& context) {
    return std::make_unique<deif::target::TargetNode>(context, options);
  };
  return deif::dds::RunMain(argc, argv, spec);
}
