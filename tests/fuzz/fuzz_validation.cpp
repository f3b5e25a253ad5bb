// libFuzzer harness of the validators of peer data (common/protocol/validation.hpp;
// docs/ARCHITECTURE.md, "Peer data is untrusted"; docs/TESTING.md, "Fuzzing").
//
// Every input builds one RangeMsg, one ContributionMsg and one StateMsg from fuzz bytes
// (NaN, infinities, huge and tiny values, odd roll calls, bases of the wrong size) and runs
// ValidateRange, ValidateContributionMsg and ValidateState on them under one of a few small
// configs. Besides never crashing, what a validator accepts must be what its contract says:
// finite, within the plausibility limits, ids and steps of the run.
#include <cmath>
#include <cstddef>
#include <cstdint>
#include <string>
#include <vector>

#include "common/config/config.hpp"
#include "common/core/filters.hpp"
#include "common/protocol/messages.hpp"
#include "common/protocol/validation.hpp"
#include "tests/fuzz/fuzz_input.hpp"

namespace {

using deif::AgentId;
using deif::Config;
using deif::Vector2;
using deif::fuzz::FuzzInput;
using deif::fuzz::Violation;
namespace protocol = deif::protocol;

const std::vector<Config>& Configs() {
  static const std::vector<Config> configs = [] {
    std::vector<Config> out;
    out.push_back(deif::ParseConfig("agents: {count: 3}\nscenario: {steps: 10}\n", "fuzz-a"));
    out.push_back(deif::ParseConfig(
        "agents: {count: 2}\nscenario: {steps: 1}\nfilter: {motion_model: constant_velocity}\n",
        "fuzz-b"));
    out.push_back(deif::ParseConfig("agents: {count: 8}\nscenario: {steps: 300}\n", "fuzz-c"));
    return out;
  }();
  return configs;
}

std::vector<AgentId> RollCall(FuzzInput& in) {
  std::vector<AgentId> ids;
  const std::size_t n = in.Byte() % 12;
  for (std::size_t i = 0; i < n; ++i) ids.push_back(in.SmallInt());
  return ids;
}

deif::InfoState Basis(FuzzInput& in, int dim) {
  // Mostly the model's dimension; sometimes another (a peer with another model), 0 to 4:
  // what the state types (and the wire, 2 or 4) can hold at all (common/core/types.hpp).
  const std::uint8_t shape = in.Byte();
  constexpr int kDims = deif::kMaxStateDim + 1;
  const int ny = shape < 200 ? dim : shape % kDims;
  const int nY = shape < 200 ? dim : (shape / kDims) % kDims;
  deif::InfoState s;
  s.y = deif::StateVector::Zero(ny);
  s.Y = deif::StateMatrix::Identity(nY, nY);
  for (int i = 0; i < ny; ++i) s.y(i) = in.Double();
  const std::uint8_t fill = in.Byte();
  for (int r = 0; r < nY; ++r) {
    for (int c = 0; c < nY; ++c) {
      if ((fill & 1u) != 0 || (r == c && (fill & 2u) != 0)) s.Y(r, c) = in.Double();
    }
  }
  if ((fill & 4u) != 0) s.Y = (0.5 * (s.Y + s.Y.transpose())).eval();
  return s;
}

bool WithinRun(deif::StepIndex step, const Config& config, deif::StepIndex first) {
  return step >= first && step <= config.scenario.steps;
}

bool StrictRollCall(const std::vector<AgentId>& ids, const Config& config) {
  for (std::size_t i = 0; i < ids.size(); ++i) {
    if (!protocol::ValidAgentId(ids[i], config)) return false;
    if (i > 0 && ids[i] <= ids[i - 1]) return false;
  }
  return ids.size() <= static_cast<std::size_t>(config.agents.count);
}

bool Bounded(const Vector2& p) {
  return std::isfinite(p.x()) && std::isfinite(p.y()) && std::abs(p.x()) <= protocol::kMaxCoordinateM &&
         std::abs(p.y()) <= protocol::kMaxCoordinateM;
}

void CheckRange(FuzzInput& in, const Config& config) {
  protocol::RangeMsg msg;
  msg.run = in.U64();
  const AgentId self = 1 + static_cast<AgentId>(in.Byte() % config.agents.count);
  msg.agent_id = in.Bool() ? self : in.SmallInt();
  msg.step = in.Int();
  msg.t_s = in.Double();
  msg.measured = in.Bool();
  msg.range_m = in.Double();
  msg.variance_m2 = in.Double();
  msg.p_sensor = in.Vec2();
  msg.roll_call = RollCall(in);
  const char* reason = protocol::ValidateRange(msg, config, self);
  if (reason != nullptr) {
    (void)protocol::IsMeasurementReason(reason);
    return;
  }
  if (msg.agent_id != self || !WithinRun(msg.step, config, 1) || !std::isfinite(msg.t_s) ||
      !StrictRollCall(msg.roll_call, config)) {
    Violation("ValidateRange accepted a range of another agent, step or roll call");
  }
  if (!msg.measured) return;
  bool listed = false;
  for (AgentId id : msg.roll_call) listed = listed || id == self;
  if (!std::isfinite(msg.range_m) || std::abs(msg.range_m) > protocol::kMaxRangeM ||
      !(msg.variance_m2 >= protocol::kMinVarianceM2 && msg.variance_m2 <= protocol::kMaxVarianceM2) ||
      !Bounded(msg.p_sensor) || !listed) {
    Violation("ValidateRange accepted an implausible measurement");
  }
}

void CheckContribution(FuzzInput& in, const Config& config) {
  protocol::ContributionMsg msg;
  msg.run = in.U64();
  msg.agent_id = in.SmallInt();
  msg.instance_token = in.U64();
  msg.step = in.Int();
  msg.info_vector = in.Vec2();
  msg.info_matrix(0, 0) = in.Double();
  msg.info_matrix(1, 1) = in.Double();
  msg.info_matrix(0, 1) = in.Double();
  msg.info_matrix(1, 0) = in.Bool() ? msg.info_matrix(0, 1) : in.Double();
  msg.p_sensor = in.Vec2();
  msg.basis = Basis(in, config.filter.motion_model.StateDim());
  msg.merge_request = in.Bool();
  if (protocol::ValidateContributionMsg(msg, config) != nullptr) return;
  const deif::InfoMatrix& I = msg.info_matrix;
  const double max_entry = std::max(I.cwiseAbs().maxCoeff(), msg.info_vector.cwiseAbs().maxCoeff());
  if (!WithinRun(msg.step, config, 1) || !msg.info_vector.allFinite() || !I.allFinite() ||
      max_entry > deif::ContributionLimits{}.max_abs_entry || !Bounded(msg.p_sensor) ||
      !deif::IsValidInfoState(msg.basis, config.filter.motion_model.StateDim())) {
    Violation("ValidateContributionMsg accepted an implausible contribution");
  }
  // What the receiver does with it: the sum with a valid prior is finite.
  deif::InfoState prior = msg.basis;
  prior.y.head<2>() += msg.info_vector;
  prior.Y.topLeftCorner<2, 2>() += I;
  if (!prior.y.allFinite() || !prior.Y.allFinite()) {
    Violation("an accepted contribution makes a valid posterior non-finite");
  }
}

void CheckState(FuzzInput& in, const Config& config) {
  protocol::StateMsg msg;
  msg.run = in.U64();
  msg.agent_id = in.SmallInt();
  msg.instance_token = in.U64();
  msg.step = in.Int();
  msg.position_m = in.Vec2();
  msg.angle_rad = in.Double();
  msg.estimate_m = in.Vec2();
  msg.covariance(0, 0) = in.Double();
  msg.covariance(1, 1) = in.Double();
  msg.covariance(0, 1) = msg.covariance(1, 0) = in.Double();
  msg.alive = in.SmallInt();
  msg.fused = in.SmallInt();
  msg.complete = in.Bool();
  msg.deadline_misses = in.Int();
  msg.rejected = in.Int();
  msg.dropped = in.Int();
  msg.matched = in.SmallInt();
  if (protocol::ValidateState(msg, config) != nullptr) return;
  if (!protocol::ValidAgentId(msg.agent_id, config) || !WithinRun(msg.step, config, 0) ||
      !Bounded(msg.position_m) || !std::isfinite(msg.angle_rad)) {
    Violation("ValidateState accepted an implausible state");
  }
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  FuzzInput in(data, size);
  const std::vector<Config>& configs = Configs();
  const Config& config = configs[in.Byte() % configs.size()];
  CheckRange(in, config);
  CheckContribution(in, config);
  CheckState(in, config);
  return 0;
}
