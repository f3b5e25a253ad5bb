// The simulated world: the true target path and the noisy ranges the sensors measure.
#include "common/protocol/target_core.hpp"

#include <cmath>
#include <cstdint>

#include "common/core/random.hpp"

namespace deif {

TargetCore::TargetCore(const Config& config) : config_(config), dt_s_(config.scenario.dt_s) {}

Vector2 TargetCore::TruthAt(StepIndex k) {
  // The random-walk perturbation is a pure function of the seed: offset(k) = sum_{i=1..k}
  // sqrt(q) w(i), w(i) ~ N(0, I2). Asking for an earlier step re-accumulates from 0, which
  // gives the same sum in the same order, hence the same bits.
  const double q = config_.target.trajectory.process_noise_variance;
  if (k < last_step_) {
    last_step_ = 0;
    offset_m_ = Vector2::Zero();
  }
  if (q > 0.0) {
    const double sigma = std::sqrt(q);
    for (StepIndex i = last_step_ + 1; i <= k; ++i) {
      offset_m_ += sigma * Vector2(StandardNormalDraw(config_.scenario.seed,
                                                      NoiseStream::kTargetProcess, i, 0),
                                   StandardNormalDraw(config_.scenario.seed,
                                                      NoiseStream::kTargetProcess, i, 1));
    }
  }
  if (k > last_step_) last_step_ = k;
  return TrajectoryPosition(config_.target.trajectory, TimeAt(k)) + offset_m_;
}

double TargetCore::NoisyRange(StepIndex k, AgentId agent_id, const Vector2& p_true,
                              const Vector2& p_sensor) const {
  // eqs (2.1), (5.5): z_j = f(||x - p_j||) + v_j, v_j ~ N(0, R).
  const double noise = std::sqrt(config_.target.range_noise_variance_m2) *
                       StandardNormalDraw(config_.scenario.seed, NoiseStream::kRangeNoise, k,
                                          static_cast<std::uint64_t>(agent_id));
  return config_.sensing.Evaluate((p_true - p_sensor).norm()) + noise;
}

}  // namespace deif
