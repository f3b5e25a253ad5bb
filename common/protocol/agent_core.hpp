// The transport-free logic of one agent for one step, shared by the in-process simulation
// and the DDS agent executable, so both compute bit-identical results.
#pragma once

#include <map>
#include <optional>
#include <vector>

#include "common/config/config.hpp"
#include "common/core/control_law.hpp"
#include "common/core/filters.hpp"

namespace deif {

struct AgentSnapshot {
  StepIndex step = 0;
  Vector2 position_m = Vector2::Zero();
  double angle_rad = 0.0;       // about this agent's own estimate
  Vector2 estimate_m = Vector2::Zero();
  Matrix2 covariance = Matrix2::Identity();
  int alive = 0;                // members this agent believes alive (itself included)
  int fused = 0;                // contributions in this step's sum
};

class AgentCore {
 public:
  AgentCore(const Config& config, AgentId id);

  AgentId id() const { return id_; }
  // Step 0: the starting position on the configured circle, before any measurement.
  AgentSnapshot Initial() const;

  // Step k, first half: predict (eqs 4.45-4.46) and, when a range arrived, compute the local
  // contribution at the prediction (eqs 4.49-4.51). No range: no contribution.
  std::optional<Contribution> BeginStep(StepIndex k, const std::optional<RangeObservation>& z);

  // Step k, second half: fuse the contributions in ascending id (eqs 4.47-4.48); then
  // choose the next angle from the ring of member positions (each member's position from
  // step k-1, this agent's included), measured about the fused estimate; move (speed
  // limited) and return the new state.
  AgentSnapshot FinishStep(StepIndex k, const std::vector<Contribution>& contributions,
                           const std::map<AgentId, Vector2>& member_positions);

  // A (re)joining agent that missed steps adopts a peer's published estimate of the last
  // step, x(k-1|k-1) and the position block of P(k-1|k-1), instead of fusing from its own
  // stale prediction (its contributions are linearised at its prediction, eqs 4.49-4.51,
  // so a stale one would differ from every other node's). With the constant-velocity
  // model the velocity restarts from zero with the configured initial variance.
  void AdoptEstimate(const Vector2& estimate_m, const Matrix2& covariance);

  const DeifNode& node() const { return node_; }
  const Vector2& position() const { return position_m_; }

 private:
  const Config& config_;
  AgentId id_;
  DeifNode node_;
  Vector2 position_m_;
  double angle_rad_;
};

}  // namespace deif
