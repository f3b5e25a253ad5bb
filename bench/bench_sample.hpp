// The contribution the DDS floor benchmarks (dds_pingpong, dds_alltoall) send: a real
// Contribution of the run `run`, with the config's initial state as its basis, so that it
// has the size and the serialisation of an agent's.
#pragma once

#include <string>

#include "common/config/config.hpp"
#include "common/protocol/messages.hpp"

namespace deif::bench {

inline protocol::ContributionMsg Contribution(const std::string& run, AgentId id, long long step,
                                              const Config& config) {
  protocol::ContributionMsg m;
  m.run = protocol::RunTokenOf(run);
  m.agent_id = id;
  m.step = step;
  m.basis = ToInfoState(InitialState(config), InitialCovariance(config));
  return m;
}

}  // namespace deif::bench
