// Target motion models, simulated trajectories and the range sensing model.
#pragma once

#include <limits>
#include <string>

#include "common/core/types.hpp"

namespace deif {

// ---------------------------------------------------------------------------------------
// Motion models for the filter.
enum class MotionModelKind {
  kRandomWalk,        // eq (5.1): x(k+1) = x(k) + w(k), w ~ N(0, q I2)
  kConstantVelocity,  // [p; v](k+1) = [I dt I; 0 I][p; v](k) + w(k), white-acceleration Q
};

struct MotionModel {
  MotionModelKind kind = MotionModelKind::kRandomWalk;
  double dt_s = 0.1;
  // Random walk: the per-step position variance q [m^2] (Q = q I2, the thesis's 0.00013).
  // Constant velocity: the white-acceleration spectral density q [m^2/s^3], giving
  // Q = q [dt^3/3 I, dt^2/2 I; dt^2/2 I, dt I].
  double process_noise = 1.3e-4;

  int StateDim() const { return kind == MotionModelKind::kRandomWalk ? 2 : 4; }
  StateMatrix TransitionMatrix() const;  // F, the Jacobian of f (linear here)
  StateMatrix ProcessNoise() const;      // Q
};

// The position block of a state vector / matrix.
Vector2 PositionOf(const StateVector& x);
Matrix2 PositionBlockOf(const StateMatrix& m);

// ---------------------------------------------------------------------------------------
// Trajectories for the simulated target. Time is t = k * dt_s.
enum class TrajectoryKind {
  kFigureEight,         // eq (5.3): [sin t, sin t cos t]
  kFigureEightShifted,  // eq (5.7): [sin t, sin t cos t - 1]
  kCircle,              // centre + radius [cos wt, sin wt]
  kLine,                // start + velocity t
  kStatic,              // start
  kRandomWalk,          // start + sum of N(0, q I2) steps (use the process noise below)
};

struct TrajectoryConfig {
  TrajectoryKind kind = TrajectoryKind::kFigureEight;
  Vector2 start_m = Vector2::Zero();         // line, static, random walk; circle centre
  Vector2 velocity_mps = Vector2(0.1, 0.0);  // line
  double circle_radius_m = 1.0;              // circle
  double angular_rate_radps = 0.5;           // circle
  // Variance [m^2] of a random-walk perturbation added to the truth every step. It is the
  // walk itself for kRandomWalk, and 0 (a smooth path) for the others by default.
  double process_noise_variance = 0.0;
};

// The deterministic part of the trajectory at time t (no process noise).
Vector2 TrajectoryPosition(const TrajectoryConfig& config, double t_s);

// ---------------------------------------------------------------------------------------
// The sensing function of eq (2.1):
//   f(r) = c0                 for r <= R0
//          r^beta + c1        for R0 <= r <= R1,   c1 = c0 - R0^beta
//          R1^beta + c1       for R1 <= r
// With the defaults (c0 = 0, R0 = 0, R1 = inf, beta = 1) f(r) = r: the plain range of eq (5.5).
struct SensingFunction {
  double c0 = 0.0;
  double r0_m = 0.0;
  double r1_m = std::numeric_limits<double>::infinity();
  double beta = 1.0;

  // f(r); when df_dr is given, also f'(r) (0 outside (R0, R1)). When R0^beta is infinite
  // (beta < 0 with R0 = 0) no c1 makes f continuous at R0, and c1 = c0 is used.
  double Evaluate(double r_m, double* df_dr = nullptr) const;
  bool InRange(double r_m) const { return r_m > r0_m && r_m < r1_m; }
};

// h_j(x) = f(||x - p_j||) (eqs 2.1, 5.5). When H is given it receives dh/dx (1x2) at x;
// at x == p_j, where the range is not differentiable, H is zero.
double MeasureRange(const Vector2& p_target, const Vector2& p_sensor, const SensingFunction& f,
                    RowVector2* H = nullptr);

}  // namespace deif
