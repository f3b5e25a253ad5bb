// The agents' starting angles and the filter's initial state, from the configuration.
#pragma once

#include "common/core/types.hpp"

namespace deif {

struct Config;

// The initial angle of agent id (1-based ids 1..count) per the config: its entry of
// agents.initial_angles_rad, or evenly spaced 2 pi / N (id - 1) when the list is empty.
double InitialAngle(const Config& config, AgentId id);
// The filter's initial state and covariance for the configured motion model.
StateVector InitialState(const Config& config);
StateMatrix InitialCovariance(const Config& config);

}  // namespace deif
