// The in-process simulation: the target and N agents, each running the very protocol the
// DDS processes run (common/protocol), connected by a simulated network (sim_network.hpp)
// in virtual time, deterministic from the seed. With the default network_sim (no loss, no
// delay) it is the oracle the multi-process system is compared with, bit for bit; with
// loss, delay, duplicates, reordering and partitions it shows the protocol on a real
// network in seconds.
#pragma once

#include <cstdint>
#include <functional>
#include <map>
#include <string>

#include "common/config/config.hpp"
#include "common/protocol/agent_protocol.hpp"
#include "common/sim/metrics.hpp"
#include "common/sim/sim_network.hpp"

namespace deif::sim {

struct SimulationOptions {
  std::string out_dir;        // where the artefacts go (created); empty: none written
  DropFilter drop_filter;     // scripted drops (tests)
  // Every log line of every simulated process ("agent-3", "target"), when set.
  std::function<void(const std::string& process, protocol::LogLevel, const std::string&)> log;
};

struct SimulationResult {
  RunMetrics metrics;
  RunData run;                                       // the artefacts, in memory
  std::map<AgentId, protocol::AgentCounters> counters;
  std::map<std::string, int> exit_codes;             // "agent-1" .. "target"
  std::int64_t messages_sent = 0;
  std::int64_t messages_lost_first_try = 0;
  double virtual_time_s = 0.0;
};

SimulationResult RunSimulation(const Config& config, const SimulationOptions& options = {});

}  // namespace deif::sim
