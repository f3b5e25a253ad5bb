#include "common/core/fisher.hpp"

#include "common/core/check.hpp"

#include <cmath>

namespace deif {
namespace {


}  // namespace

Eigen::MatrixX2d SensitivityMatrix(const std::vector<SensorGeometry>& sensors,
                                   const Vector2& p_target, const SensingFunction& sensing) {
  Eigen::MatrixX2d G(static_cast<Eigen::Index>(sensors.size()), 2);
  for (std::size_t j = 0; j < sensors.size(); ++j) {
    RowVector2 g_j;  // d f(||q - p_j||) / dq
    MeasureRange(p_target, sensors[j].p_sensor, sensing, &g_j);
    G.row(static_cast<Eigen::Index>(j)) = g_j;
  }
  return G;
}

Matrix2 FisherInformation(const std::vector<SensorGeometry>& sensors, const Vector2& p_target,
                          const SensingFunction& sensing) {
  Matrix2 J = Matrix2::Zero();
  for (const SensorGeometry& sensor : sensors) {
    RowVector2 g;
    MeasureRange(p_target, sensor.p_sensor, sensing, &g);
    J += g.transpose() * g / sensor.variance_m2;  // eq (2.2): J = sum_j g_j g_j^T / sigma_j^2
  }
  return J;
}

double DetFisherClosedForm(const std::vector<SensorGeometry>& sensors, const Vector2& p_target,
                           const SensingFunction& sensing) {
  if (sensors.empty()) {
    return 0.0;
  }
  // Equal variances assumed (as in eq 2.6): sigma^2 is the first sensor's variance.
  const double sigma2 = sensors.front().variance_m2;
  const Eigen::MatrixX2d G = SensitivityMatrix(sensors, p_target, sensing);
  const Eigen::Index n = G.rows();
  double pair_sum = 0.0;
  for (Eigen::Index i = 0; i < n; ++i) {
    const Vector2 v_i = G.row(i).transpose();
    for (Eigen::Index j = 0; j < n; ++j) {
      const Vector2 v_j = G.row(j).transpose();
      if (v_i.squaredNorm() == 0.0 || v_j.squaredNorm() == 0.0) {
        continue;  // a zero gradient spans no area with anything
      }
      // alpha_ij, the angle between v_i and v_j.
      const double alpha_ij = std::atan2(v_j.y(), v_j.x()) - std::atan2(v_i.y(), v_i.x());
      const double sin_alpha = std::sin(alpha_ij);
      pair_sum += v_i.squaredNorm() * v_j.squaredNorm() * sin_alpha * sin_alpha;
    }
  }
  // eq (2.6): det J = 1/2 sum_{i,j} |v_i|^2 |v_j|^2 sin^2(alpha_ij) / sigma^4 (see header).
  return 0.5 * pair_sum / (sigma2 * sigma2);
}

double AngleObjective(const std::vector<double>& angles_rad) {
  double sum = 0.0;
  for (const double theta_i : angles_rad) {
    for (const double theta_j : angles_rad) {
      const double s = std::sin(theta_i - theta_j);
      sum += s * s;
    }
  }
  return 2.0 * sum;  // eq (2.7): f(theta) = 2 sum_{i,j} sin^2(theta_i - theta_j)
}

double OptimalityRatio(const Matrix2& J) {
  const double trace = J.trace();
  if (trace == 0.0) {
    return 0.0;
  }
  // det J* = (tr J / 2)^2, the largest determinant for that trace.
  return 4.0 * J.determinant() / (trace * trace);
}

double OptimalGapRad(int n) {
  if (n >= 3) {
    return 2.0 * kPi / static_cast<double>(n);  // section 2.3.1.4: theta_N = 2 pi / N
  }
  if (n == 2) {
    return kPi / 2.0;
  }
  return 0.0;
}

// ---------------------------------------------------------------------------------------
// Pcrlb

Pcrlb::Pcrlb(const MotionModel& model, const StateMatrix& P0)
    : model_(model),
      J_(P0.ldlt().solve(StateMatrix::Identity(P0.rows(), P0.cols()))) {  // J(0) = P0^-1
  DEIF_THROW_UNLESS(P0.rows() == model.StateDim() && P0.cols() == model.StateDim(),
                    "P0 must be square with the model's state dimension");
}

void Pcrlb::Step(const Vector2& p_true, const std::vector<SensorGeometry>& sensors,
                 const SensingFunction& sensing) {
  const StateMatrix F = model_.TransitionMatrix();
  const Eigen::Index n = J_.rows();
  const StateMatrix J_inv = J_.ldlt().solve(StateMatrix::Identity(n, n));
  const StateMatrix predicted_cov = model_.ProcessNoise() + F * J_inv * F.transpose();
  // J(k+1) = (Q + F J(k)^-1 F^T)^-1 + sum_j H_j^T R_j^-1 H_j, H_j = [g_j, 0] at the truth.
  StateMatrix J_next = predicted_cov.ldlt().solve(StateMatrix::Identity(n, n));
  J_next.topLeftCorner<2, 2>() += FisherInformation(sensors, p_true, sensing);
  J_ = 0.5 * (J_next + J_next.transpose());
}

Matrix2 Pcrlb::PositionBound() const {
  const Eigen::Index n = J_.rows();
  return PositionBlockOf(J_.ldlt().solve(StateMatrix::Identity(n, n)));
}

double Pcrlb::PositionRmseBound() const { return std::sqrt(PositionBound().trace()); }

}  // namespace deif
