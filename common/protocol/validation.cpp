#include "common/protocol/validation.hpp"

#include <cmath>
#include <string>

namespace deif::protocol {

bool IsFinitePosition(const Vector2& p) {
  return p.allFinite() && p.cwiseAbs().maxCoeff() <= kMaxCoordinateM;
}

bool ValidAgentId(AgentId id, const Config& config) { return id >= 1 && id <= config.agents.count; }

namespace {

bool ValidStep(StepIndex step, const Config& config, StepIndex first) {
  return step >= first && step <= config.scenario.steps;
}

// Strictly ascending ids in 1..count.
bool ValidRollCall(const std::vector<AgentId>& roll_call, const Config& config) {
  if (roll_call.size() > static_cast<std::size_t>(config.agents.count)) return false;
  for (std::size_t i = 0; i < roll_call.size(); ++i) {
    if (!ValidAgentId(roll_call[i], config)) return false;
    if (i > 0 && roll_call[i] <= roll_call[i - 1]) return false;
  }
  return true;
}

}  // namespace

const char* ValidateRange(const RangeMsg& msg, const Config& config, AgentId self) {
  if (msg.agent_id != self) return "range_for_another_agent";
  if (!ValidStep(msg.step, config, 1)) return "step_outside_run";
  if (!std::isfinite(msg.t_s)) return "non_finite";
  if (!ValidRollCall(msg.roll_call, config)) return "bad_roll_call";
  if (!msg.measured) return nullptr;
  if (!std::isfinite(msg.range_m) || !std::isfinite(msg.variance_m2) || !msg.p_sensor.allFinite()) {
    return "non_finite";
  }
  if (std::abs(msg.range_m) > kMaxRangeM) return "range_out_of_bounds";
  if (msg.variance_m2 < kMinVarianceM2 || msg.variance_m2 > kMaxVarianceM2) {
    return "variance_out_of_bounds";
  }
  if (!IsFinitePosition(msg.p_sensor)) return "position_out_of_bounds";
  bool listed = false;
  for (AgentId id : msg.roll_call) listed = listed || id == self;
  if (!listed) return "measured_but_not_in_roll_call";
  return nullptr;
}

bool IsMeasurementReason(const char* reason) {
  const std::string r = reason;
  return r == "non_finite" || r == "range_out_of_bounds" || r == "variance_out_of_bounds" ||
         r == "position_out_of_bounds";
}

const char* ValidateContributionMsg(const ContributionMsg& msg, const Config& config) {
  if (!ValidStep(msg.step, config, 1)) return "step_outside_run";
  Contribution c;
  c.agent_id = msg.agent_id;
  c.step = msg.step;
  c.info_vector = msg.info_vector;
  c.info_matrix = msg.info_matrix;
  const RejectReason reason = ValidateContribution(c);
  if (reason != RejectReason::kNone) return ToString(reason);
  if (!msg.p_sensor.allFinite()) return "non_finite";
  if (!IsFinitePosition(msg.p_sensor)) return "position_out_of_bounds";
  if (!IsValidInfoState(msg.basis, config.filter.motion_model.StateDim())) return "bad_basis";
  return nullptr;
}

const char* ValidateState(const StateMsg& msg, const Config& config) {
  if (!ValidAgentId(msg.agent_id, config)) return "unknown_agent_id";
  if (!ValidStep(msg.step, config, 0)) return "step_outside_run";
  if (!msg.position_m.allFinite() || !std::isfinite(msg.angle_rad)) return "non_finite";
  if (!IsFinitePosition(msg.position_m)) return "position_out_of_bounds";
  return nullptr;
}

}  // namespace deif::protocol
