// One agent's step, free of transport: DEIF predict / contribute / fuse (section 4.5) and
// the ring control law (chapter 3). See DESIGN.md "One step" for the protocol.
#include "common/protocol/agent_core.hpp"

#include <cmath>
#include <vector>

namespace deif {

namespace {

// The angle of a position about a centre, as atan2 gives it: (-pi, pi].
double AngleAbout(const Vector2& centre, const Vector2& p) {
  const Vector2 d = p - centre;
  return std::atan2(d.y(), d.x());
}

}  // namespace

AgentCore::AgentCore(const Config& config, AgentId id)
    : config_(config),
      id_(id),
      node_(id, config.filter.motion_model, InitialState(config), InitialCovariance(config),
            config.sensing),
      position_m_(PointOnCircle(config.agents.initial_centre_m, config.agents.radius_m,
                                InitialAngle(config, id))),
      angle_rad_(InitialAngle(config, id)) {}

AgentSnapshot AgentCore::Initial() const {
  AgentSnapshot snapshot;
  snapshot.step = 0;
  snapshot.position_m = position_m_;
  snapshot.angle_rad = angle_rad_;  // about the initial centre
  snapshot.estimate_m = node_.filter().PositionEstimate();
  snapshot.covariance = node_.filter().PositionCovariance();
  snapshot.alive = config_.agents.count;
  snapshot.fused = 0;
  return snapshot;
}

std::optional<Contribution> AgentCore::BeginStep(StepIndex k,
                                                 const std::optional<RangeObservation>& z) {
  node_.Predict();  // eqs (4.45)-(4.46): y(k|k-1), Y(k|k-1)
  if (!z) return std::nullopt;
  return node_.LocalContribution(k, *z);  // eqs (4.49)-(4.51) at x(k|k-1)
}

void AgentCore::AdoptEstimate(const Vector2& estimate_m, const Matrix2& covariance) {
  StateVector x = InitialState(config_);  // velocity (constant-velocity model): the prior
  StateMatrix P = InitialCovariance(config_);
  x.head<2>() = estimate_m;
  P.topLeftCorner<2, 2>() = covariance;
  P.topRightCorner(2, P.cols() - 2).setZero();
  P.bottomLeftCorner(P.rows() - 2, 2).setZero();
  node_.Reset(x, P);
}

AgentSnapshot AgentCore::FinishStep(StepIndex k, const std::vector<Contribution>& contributions,
                                    const std::map<AgentId, Vector2>& member_positions) {
  // eqs (4.47)-(4.48): y(k|k) = y(k|k-1) + sum_j i_j(k), Y(k|k) = Y(k|k-1) + sum_j I_j(k).
  const int fused = node_.Fuse(contributions);
  const Vector2 p_estimate = node_.filter().PositionEstimate();  // x(k|k)

  // The ring: every member's position at step k-1 (the positions the ranges were measured
  // from), as angles about this agent's own estimate. This agent is always a member.
  std::vector<RingMember> ring;
  ring.reserve(member_positions.size() + 1);
  for (const auto& [member_id, p_member] : member_positions) {
    ring.push_back({member_id, AngleAbout(p_estimate, p_member)});
  }
  if (member_positions.find(id_) == member_positions.end()) {
    ring.push_back({id_, AngleAbout(p_estimate, position_m_)});
  }

  if (config_.agents.control_law != ControlLawKind::kStationary) {
    // eq (3.2) / (3.6): the next angle; the goal lies on the circle about the estimate.
    const double next_angle_rad = NextAngle(config_.agents.control_law, id_, ring);
    const Vector2 p_goal = PointOnCircle(p_estimate, config_.agents.radius_m, next_angle_rad);
    position_m_ = MoveToward(position_m_, p_goal,
                             config_.agents.max_speed_mps * config_.scenario.dt_s);
  }
  angle_rad_ = AngleAbout(p_estimate, position_m_);

  AgentSnapshot snapshot;
  snapshot.step = k;
  snapshot.position_m = position_m_;
  snapshot.angle_rad = angle_rad_;
  snapshot.estimate_m = p_estimate;
  snapshot.covariance = node_.filter().PositionCovariance();
  snapshot.alive = static_cast<int>(ring.size());
  snapshot.fused = fused;
  return snapshot;
}

}  // namespace deif
