// The Fisher information of a sensor geometry (chapter 2), its closed forms and bounds,
// and the posterior Cramer-Rao bound recursion.
#pragma once

#include <vector>

#include "common/core/models.hpp"
#include "common/core/types.hpp"

namespace deif {

struct SensorGeometry {
  Vector2 p_sensor = Vector2::Zero();
  double variance_m2 = 1.0;  // sigma_j^2
};

// The sensitivity matrix G (N x 2), row j = d f(||q - p_j||) / dq at q (section 2.2.1).
Eigen::MatrixX2d SensitivityMatrix(const std::vector<SensorGeometry>& sensors,
                                   const Vector2& p_target, const SensingFunction& sensing);

// eq (2.2): J = sum_j g_j g_j^T / sigma_j^2 (= G^T G / sigma^2 for equal variances).
Matrix2 FisherInformation(const std::vector<SensorGeometry>& sensors, const Vector2& p_target,
                          const SensingFunction& sensing);

// eq (2.6) for equal variances sigma^2: the sum over ordered pairs
//   1/2 sum_{i,j} |v_i|^2 |v_j|^2 sin^2(alpha_ij) = det(G^T G),
// divided by sigma^4. (The thesis writes 1/(2 sigma^2); det(G^T G / sigma^2) in 2-D is
// det(G^T G) / sigma^4, and that is what this returns so that it equals det of eq (2.2).)
// sigma^2 is taken from the FIRST sensor; the result is 0 for no sensors.
double DetFisherClosedForm(const std::vector<SensorGeometry>& sensors, const Vector2& p_target,
                           const SensingFunction& sensing);

// eq (2.7): f(theta) = 2 sum_{i,j} sin^2(theta_i - theta_j) = 4 sigma^4 det J for unit
// gradients (beta = 1). Bounded by N^2 (section 2.3.1.3).
double AngleObjective(const std::vector<double>& angles_rad);

// How close a geometry is to the best one with the same sensor distances and noise:
// det J / det J*, where det J* = (tr J / 2)^2 is the largest determinant a 2x2 PSD matrix
// of that trace can have. For equal weights this is f(theta) / N^2. In [0, 1]; 0 if J = 0.
double OptimalityRatio(const Matrix2& J);

// The gap between ring neighbours at the optimum for n sensors (section 2.3.1.4):
// 2 pi / n for n >= 3 and pi / 2 for n = 2 (2 pi / 2 would put both sensors on one line
// through the target, det J = 0). 0 for n < 2.
double OptimalGapRad(int n);

// ---------------------------------------------------------------------------------------
// Posterior Cramer-Rao bound for the filter's motion model (Tichavsky et al. 1998):
//   J(k+1) = (Q + F J(k)^-1 F^T)^-1 + sum_j H_j^T R_j^-1 H_j,  H_j at the TRUE state.
class Pcrlb {
 public:
  Pcrlb(const MotionModel& model, const StateMatrix& P0);  // J(0) = P0^-1
  void Step(const Vector2& p_true, const std::vector<SensorGeometry>& sensors,
            const SensingFunction& sensing);
  const StateMatrix& information() const { return J_; }
  Matrix2 PositionBound() const;   // the position block of J^-1
  double PositionRmseBound() const;  // sqrt(trace(PositionBound()))

 private:
  MotionModel model_;
  StateMatrix J_;
};

}  // namespace deif
