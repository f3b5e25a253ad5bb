#include "common/core/filters.hpp"

#include "common/core/check.hpp"

#include <algorithm>
#include <cmath>
#include <limits>
#include <string>
#include <utility>

namespace deif {
namespace {

StateMatrix Symmetrized(const StateMatrix& m) { return 0.5 * (m + m.transpose()); }

// The inverse of a symmetric positive definite matrix by an LDLT solve.
StateMatrix SpdInverse(const StateMatrix& m) {
  return Symmetrized(m.ldlt().solve(StateMatrix::Identity(m.rows(), m.cols())));
}

}  // namespace

// ---------------------------------------------------------------------------------------
// Ekf

Ekf::Ekf(const MotionModel& model, const StateVector& x0, const StateMatrix& P0)
    : model_(model), x_(x0), P_(P0) {
  DEIF_THROW_UNLESS(x0.size() == model.StateDim(), "x0 must have the model's state dimension");
  DEIF_THROW_UNLESS(P0.rows() == model.StateDim() && P0.cols() == model.StateDim(),
                    "P0 must be square with the model's state dimension");
}

void Ekf::Predict() {
  const StateMatrix F = model_.TransitionMatrix();
  x_ = F * x_;                                                   // eq (4.32): x(k|k-1) = f(x(k-1|k-1))
  P_ = Symmetrized(F * P_ * F.transpose() + model_.ProcessNoise());  // eq (4.33)
}

void Ekf::Update(const std::vector<RangeObservation>& observations,
                 const SensingFunction& sensing) {
  if (observations.empty()) {
    return;
  }
  const Eigen::Index m = static_cast<Eigen::Index>(observations.size());
  const Eigen::Index n = x_.size();
  const Vector2 p_pred = PositionOf(x_);

  // All ranges stacked and linearised at the prediction; H = [dh/dp, 0].
  Eigen::MatrixXd H = Eigen::MatrixXd::Zero(m, n);
  Eigen::VectorXd innovation(m);  // z - h(x(k|k-1))
  Eigen::VectorXd R_diag(m);
  for (Eigen::Index j = 0; j < m; ++j) {
    const RangeObservation& z = observations[static_cast<std::size_t>(j)];
    RowVector2 H_j;
    innovation(j) = z.range_m - MeasureRange(p_pred, z.p_sensor, sensing, &H_j);
    H.block<1, 2>(j, 0) = H_j;
    R_diag(j) = z.variance_m2;
  }

  Eigen::MatrixXd S = H * P_ * H.transpose();  // eq (4.37): S = H P H^T + R
  S.diagonal() += R_diag;
  const auto S_ldlt = S.ldlt();
  // eq (4.36): W = P H^T S^-1, computed as (S^-1 H P)^T since S and P are symmetric.
  const Eigen::MatrixXd W = S_ldlt.solve(H * P_).transpose();
  x_ += W * innovation;                                      // eq (4.34)
  P_ = Symmetrized(P_ - W * S * W.transpose());              // eq (4.35)
}

// ---------------------------------------------------------------------------------------
// Eif

Eif::Eif(const MotionModel& model, const StateVector& x0, const StateMatrix& P0)
    : model_(model), y_(), Y_() {
  DEIF_THROW_UNLESS(x0.size() == model.StateDim(), "x0 must have the model's state dimension");
  DEIF_THROW_UNLESS(P0.rows() == model.StateDim() && P0.cols() == model.StateDim(),
                    "P0 must be square with the model's state dimension");
  Y_ = SpdInverse(P0);
  y_ = Y_ * x0;  // y = Y x
}

Eif::Eif(const MotionModel& model, InfoState state)
    : model_(model), y_(std::move(state.y)), Y_(std::move(state.Y)) {
  DEIF_THROW_UNLESS(y_.size() == model.StateDim() && Y_.rows() == model.StateDim() &&
                        Y_.cols() == model.StateDim(),
                    "the information state must have the model's state dimension");
}

void Eif::Predict() {
  InfoState predicted = deif::Predict(model_, {y_, Y_});
  y_ = std::move(predicted.y);
  Y_ = std::move(predicted.Y);
}

InfoState ToInfoState(const StateVector& x, const StateMatrix& P) {
  InfoState s;
  s.Y = SpdInverse(P);  // Y = P^-1
  s.y = s.Y * x;        // y = Y x
  return s;
}

InfoState Predict(const MotionModel& model, const InfoState& posterior) {
  const StateMatrix F = model.TransitionMatrix();
  const auto Y_ldlt = posterior.Y.ldlt();
  const StateVector x = Y_ldlt.solve(posterior.y);  // x(k-1|k-1) = Y^-1 y
  const StateMatrix P =
      Symmetrized(Y_ldlt.solve(StateMatrix::Identity(posterior.Y.rows(), posterior.Y.cols())));
  const StateMatrix P_pred = F * P * F.transpose() + model.ProcessNoise();
  InfoState predicted;
  predicted.Y = SpdInverse(P_pred);  // eq (4.39)/(4.46): Y(k|k-1) = [F Y^-1 F^T + Q]^-1
  predicted.y = predicted.Y * (F * x);  // eq (4.38)/(4.45): y(k|k-1) = Y(k|k-1) f(x(k-1|k-1))
  return predicted;
}

bool IsValidInfoState(const InfoState& s, int state_dim) {
  if (s.y.size() != state_dim || s.Y.rows() != state_dim || s.Y.cols() != state_dim) {
    return false;
  }
  if (!s.y.allFinite() || !s.Y.allFinite()) return false;
  const double scale = std::max(1.0, s.Y.cwiseAbs().maxCoeff());
  if ((s.Y - s.Y.transpose()).cwiseAbs().maxCoeff() > 1e-9 * scale) return false;
  const Eigen::LLT<StateMatrix> llt(Symmetrized(s.Y));
  return llt.info() == Eigen::Success;
}

namespace {

// log det of w Y_a + (1 - w) Y_b; -inf when not positive definite.
double LogDetOfBlend(const StateMatrix& Y_a, const StateMatrix& Y_b, double w) {
  const Eigen::LLT<StateMatrix> llt(Symmetrized(w * Y_a + (1.0 - w) * Y_b));
  if (llt.info() != Eigen::Success) return -std::numeric_limits<double>::infinity();
  return 2.0 * llt.matrixLLT().diagonal().array().log().sum();
}

}  // namespace

InfoState CovarianceIntersection(const InfoState& a, const InfoState& b) {
  // log det is concave in w (Y_ci is affine in w), so golden-section search finds the
  // maximum on [0, 1]. 60 steps shrink the bracket below 1e-12.
  constexpr double kInvPhi = 0.6180339887498948482;
  double lo = 0.0;
  double hi = 1.0;
  double x1 = hi - kInvPhi * (hi - lo);
  double x2 = lo + kInvPhi * (hi - lo);
  double f1 = LogDetOfBlend(a.Y, b.Y, x1);
  double f2 = LogDetOfBlend(a.Y, b.Y, x2);
  for (int i = 0; i < 60; ++i) {
    if (f1 < f2) {
      lo = x1;
      x1 = x2;
      f1 = f2;
      x2 = lo + kInvPhi * (hi - lo);
      f2 = LogDetOfBlend(a.Y, b.Y, x2);
    } else {
      hi = x2;
      x2 = x1;
      f2 = f1;
      x1 = hi - kInvPhi * (hi - lo);
      f1 = LogDetOfBlend(a.Y, b.Y, x1);
    }
  }
  double w = 0.5 * (lo + hi);
  // The ends are candidates too (one estimate may dominate the other entirely).
  const double f_mid = LogDetOfBlend(a.Y, b.Y, w);
  if (LogDetOfBlend(a.Y, b.Y, 1.0) >= f_mid) w = 1.0;
  if (LogDetOfBlend(a.Y, b.Y, 0.0) > std::max(f_mid, LogDetOfBlend(a.Y, b.Y, 1.0))) w = 0.0;
  InfoState out;
  out.Y = Symmetrized(w * a.Y + (1.0 - w) * b.Y);
  out.y = w * a.y + (1.0 - w) * b.y;
  return out;
}

void Eif::AddInformation(const InfoVector& info_vector, const InfoMatrix& info_matrix) {
  y_.head<2>() += info_vector;                // eq (4.40)/(4.47): y(k|k) = y(k|k-1) + i
  Y_.topLeftCorner<2, 2>() += info_matrix;    // eq (4.41)/(4.48): Y(k|k) = Y(k|k-1) + I
}

StateVector Eif::State() const { return Y_.ldlt().solve(y_); }

StateMatrix Eif::Covariance() const { return SpdInverse(Y_); }

// ---------------------------------------------------------------------------------------
// Contributions

Contribution ComputeContribution(StepIndex step, const RangeObservation& z, const Vector2& p_pred,
                                 const SensingFunction& sensing) {
  RowVector2 H;
  const double h_pred = MeasureRange(p_pred, z.p_sensor, sensing, &H);
  const double innovation = z.range_m - h_pred;  // eq (4.51): v_j = z_j - h_j(x(k|k-1))
  const double inv_R = 1.0 / z.variance_m2;
  Contribution c;
  c.agent_id = z.agent_id;
  c.step = step;
  c.info_matrix = H.transpose() * inv_R * H;  // eq (4.49): I_j = H^T R^-1 H
  c.info_vector = H.transpose() * (inv_R * (innovation + H.dot(p_pred)));  // eq (4.50)
  return c;
}

InformationSum SumContributions(std::vector<Contribution> contributions) {
  std::stable_sort(contributions.begin(), contributions.end(),
                   [](const Contribution& a, const Contribution& b) {
                     return a.agent_id < b.agent_id;
                   });
  InformationSum sum;
  for (std::size_t k = 0; k < contributions.size(); ++k) {
    DEIF_THROW_UNLESS(k == 0 || contributions[k - 1].agent_id != contributions[k].agent_id,
                      "two contributions from agent " + std::to_string(contributions[k].agent_id));
    // eqs (4.47)-(4.48): sum_j i_j, sum_j I_j, in ascending id for bit-identical results.
    sum.info_vector += contributions[k].info_vector;
    sum.info_matrix += contributions[k].info_matrix;
    ++sum.count;
  }
  return sum;
}

// ---------------------------------------------------------------------------------------
// DeifNode

DeifNode::DeifNode(AgentId id, const MotionModel& model, const StateVector& x0,
                   const StateMatrix& P0, const SensingFunction& sensing)
    : id_(id), filter_(model, x0, P0), sensing_(sensing) {}

void DeifNode::Predict() { filter_.Predict(); }

Contribution DeifNode::LocalContribution(StepIndex step, const RangeObservation& z) const {
  return ComputeContribution(step, z, filter_.PositionEstimate(), sensing_);
}

void DeifNode::Reset(const StateVector& x, const StateMatrix& P) {
  filter_ = Eif(filter_.model(), x, P);
}

int DeifNode::Fuse(const std::vector<Contribution>& contributions) {
  const InformationSum sum = SumContributions(contributions);
  filter_.AddInformation(sum.info_vector, sum.info_matrix);
  return sum.count;
}

// ---------------------------------------------------------------------------------------
// CentralizedEif

CentralizedEif::CentralizedEif(const MotionModel& model, const StateVector& x0,
                               const StateMatrix& P0, const SensingFunction& sensing)
    : filter_(model, x0, P0), sensing_(sensing) {}

void CentralizedEif::Step(StepIndex step, const std::vector<RangeObservation>& observations) {
  filter_.Predict();
  const Vector2 p_pred = filter_.PositionEstimate();
  std::vector<Contribution> contributions;
  contributions.reserve(observations.size());
  for (const RangeObservation& z : observations) {
    contributions.push_back(ComputeContribution(step, z, p_pred, sensing_));
  }
  const InformationSum sum = SumContributions(std::move(contributions));
  filter_.AddInformation(sum.info_vector, sum.info_matrix);
}

// ---------------------------------------------------------------------------------------
// Validation

const char* ToString(RejectReason reason) {
  switch (reason) {
    case RejectReason::kNone:
      return "none";
    case RejectReason::kNonFinite:
      return "non_finite";
    case RejectReason::kNotSymmetric:
      return "not_symmetric";
    case RejectReason::kNotPsd:
      return "not_psd";
    case RejectReason::kAbsurdMagnitude:
      return "absurd_magnitude";
  }
  return "unknown";
}

RejectReason ValidateContribution(const Contribution& c, const ContributionLimits& limits) {
  if (!c.info_vector.allFinite() || !c.info_matrix.allFinite()) {
    return RejectReason::kNonFinite;
  }
  const double max_abs_matrix = c.info_matrix.cwiseAbs().maxCoeff();
  const double max_abs = std::max(max_abs_matrix, c.info_vector.cwiseAbs().maxCoeff());
  if (max_abs > limits.max_abs_entry) {
    return RejectReason::kAbsurdMagnitude;
  }
  const double scale = std::max(1.0, max_abs_matrix);
  const InfoMatrix& I = c.info_matrix;
  if (std::abs(I(0, 1) - I(1, 0)) > limits.symmetry_rel_tol * scale) {
    return RejectReason::kNotSymmetric;
  }
  // The smaller eigenvalue of the symmetric part [a b; b d]: (a+d)/2 - sqrt(((a-d)/2)^2 + b^2).
  const double a = I(0, 0);
  const double d = I(1, 1);
  const double b = 0.5 * (I(0, 1) + I(1, 0));
  const double min_eigenvalue = 0.5 * (a + d) - std::hypot(0.5 * (a - d), b);
  if (min_eigenvalue < -limits.psd_rel_tol * scale) {
    return RejectReason::kNotPsd;
  }
  return RejectReason::kNone;
}

}  // namespace deif
