// The transport-free world: true target motion and noisy ranges, shared by the in-process
// simulation and the DDS target executable.
#pragma once

#include "common/config/config.hpp"

namespace deif {

class TargetCore {
 public:
  explicit TargetCore(const Config& config);

  // The true position at step k (k = 0 is the start). Steps must be asked in increasing
  // order when the trajectory has process noise (the random-walk offset accumulates).
  Vector2 TruthAt(StepIndex k);
  double TimeAt(StepIndex k) const { return static_cast<double>(k) * dt_s_; }

  // The range agent_id measures at step k from p_sensor to p_true: f(||x - p||) + v with
  // v ~ N(0, range_noise_variance), drawn from (seed, step, agent id) alone.
  double NoisyRange(StepIndex k, AgentId agent_id, const Vector2& p_true,
                    const Vector2& p_sensor) const;

 private:
  const Config& config_;
  double dt_s_;
  StepIndex last_step_ = 0;
  Vector2 offset_m_ = Vector2::Zero();  // accumulated random-walk perturbation
};

}  // namespace deif
