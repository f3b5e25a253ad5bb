#include "common/config/initial_state.hpp"

#include <stdexcept>
#include <string>

#include "common/config/config.hpp"

namespace deif {

namespace {
constexpr double kFullTurnRad = 6.283185307179586476925286766559;
}  // namespace

double InitialAngle(const Config& config, AgentId id) {
  if (id < 1 || id > config.agents.count) {
    throw std::out_of_range("InitialAngle: agent id " + std::to_string(id) + " not in 1.." +
                            std::to_string(config.agents.count));
  }
  const auto index = static_cast<std::size_t>(id - 1);
  if (!config.agents.initial_angles_rad.empty()) return config.agents.initial_angles_rad[index];
  return kFullTurnRad / static_cast<double>(config.agents.count) * static_cast<double>(id - 1);
}

StateVector InitialState(const Config& config) {
  StateVector x0 = StateVector::Zero(config.filter.motion_model.StateDim());
  x0.head<2>() = config.filter.initial_estimate_m;  // velocity (if any) starts at 0
  return x0;
}

StateMatrix InitialCovariance(const Config& config) {
  const int n = config.filter.motion_model.StateDim();
  StateMatrix P0 = StateMatrix::Zero(n, n);
  P0.topLeftCorner<2, 2>() = config.filter.initial_position_variance_m2 * Matrix2::Identity();
  if (n == 4) {
    P0.bottomRightCorner<2, 2>() =
        config.filter.initial_velocity_variance_m2ps2 * Matrix2::Identity();
  }
  return P0;
}

}  // namespace deif
