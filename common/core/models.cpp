#include "common/core/models.hpp"

#include <cmath>

namespace deif {

StateMatrix MotionModel::TransitionMatrix() const {
  const int n = StateDim();
  StateMatrix F = StateMatrix::Identity(n, n);
  if (kind == MotionModelKind::kConstantVelocity) {
    F.topRightCorner<2, 2>() = dt_s * Matrix2::Identity();  // p(k+1) = p(k) + dt v(k)
  }
  // Random walk, eq (5.1): F = I2.
  return F;
}

StateMatrix MotionModel::ProcessNoise() const {
  if (kind == MotionModelKind::kRandomWalk) {
    return process_noise * StateMatrix::Identity(2, 2);  // eq (5.1): w ~ N(0, q I2)
  }
  // White-acceleration model: Q = q [dt^3/3 I, dt^2/2 I; dt^2/2 I, dt I].
  const double dt = dt_s;
  StateMatrix Q(4, 4);
  Q.topLeftCorner<2, 2>() = (dt * dt * dt / 3.0) * Matrix2::Identity();
  Q.topRightCorner<2, 2>() = (dt * dt / 2.0) * Matrix2::Identity();
  Q.bottomLeftCorner<2, 2>() = (dt * dt / 2.0) * Matrix2::Identity();
  Q.bottomRightCorner<2, 2>() = dt * Matrix2::Identity();
  return process_noise * Q;
}

Vector2 PositionOf(const StateVector& x) { return x.head<2>(); }

Matrix2 PositionBlockOf(const StateMatrix& m) { return m.topLeftCorner<2, 2>(); }

Vector2 TrajectoryPosition(const TrajectoryConfig& config, double t_s) {
  switch (config.kind) {
    case TrajectoryKind::kFigureEight:
      return Vector2(std::sin(t_s), std::sin(t_s) * std::cos(t_s));  // eq (5.3)
    case TrajectoryKind::kFigureEightShifted:
      return Vector2(std::sin(t_s), std::sin(t_s) * std::cos(t_s) - 1.0);  // eq (5.7)
    case TrajectoryKind::kCircle: {
      const double wt = config.angular_rate_radps * t_s;
      return config.start_m + config.circle_radius_m * Vector2(std::cos(wt), std::sin(wt));
    }
    case TrajectoryKind::kLine:
      return config.start_m + config.velocity_mps * t_s;
    case TrajectoryKind::kStatic:
    case TrajectoryKind::kRandomWalk:  // the walk itself is added by the caller
      return config.start_m;
  }
  return config.start_m;
}

double SensingFunction::Evaluate(double r_m, double* df_dr) const {
  if (df_dr != nullptr) {
    *df_dr = 0.0;
  }
  if (r_m <= r0_m) {
    return c0;  // eq (2.1), r <= R0
  }
  // eq (2.1): c1 = c0 - R0^beta makes f continuous at R0. For beta < 0 and R0 = 0,
  // R0^beta is infinite and no offset can make f continuous; we then take c1 = c0.
  const double r0_pow = std::pow(r0_m, beta);
  const double c1 = std::isfinite(r0_pow) ? c0 - r0_pow : c0;
  if (r_m >= r1_m) {
    return std::pow(r1_m, beta) + c1;  // eq (2.1), R1 <= r: saturated
  }
  if (df_dr != nullptr) {
    *df_dr = beta * std::pow(r_m, beta - 1.0);  // d/dr (r^beta + c1)
  }
  return std::pow(r_m, beta) + c1;  // eq (2.1), R0 < r < R1
}

double MeasureRange(const Vector2& p_target, const Vector2& p_sensor, const SensingFunction& f,
                    RowVector2* H) {
  const Vector2 d = p_target - p_sensor;
  const double r_m = d.norm();
  double df_dr = 0.0;
  const double h = f.Evaluate(r_m, &df_dr);  // eqs (2.1), (5.5): h = f(||x - p_j||)
  if (H != nullptr) {
    // dh/dx = f'(r) (x - p_j)^T / r; undefined at r = 0, where we return 0.
    *H = r_m > 0.0 ? RowVector2(df_dr * d.transpose() / r_m) : RowVector2::Zero();
  }
  return h;
}

}  // namespace deif
