// EKF (eqs 4.32-4.37), EIF (eqs 4.38-4.44), the DEIF node (eqs 4.45-4.51) and peer-data
// validation. Pure maths: no logging, no transport.
#pragma once

#include <optional>
#include <string>
#include <vector>

#include "common/core/models.hpp"
#include "common/core/types.hpp"

namespace deif {

// One range measurement z_j(k) with the sensor position it was taken from.
struct RangeObservation {
  AgentId agent_id = 0;
  double range_m = 0.0;        // z_j
  double variance_m2 = 1.0;    // R_j used by the filter
  Vector2 p_sensor = Vector2::Zero();
};

// The information contribution (i_j(k), I_j(k)) of one sensor for one step (eqs 4.49-4.50).
struct Contribution {
  AgentId agent_id = 0;
  StepIndex step = 0;
  InfoVector info_vector = InfoVector::Zero();  // i_j
  InfoMatrix info_matrix = InfoMatrix::Zero();  // I_j
};

// ---------------------------------------------------------------------------------------
// Extended Kalman filter. Update() processes a batch of ranges jointly, linearised at the
// prediction, which is the form that the EIF reproduces exactly.
class Ekf {
 public:
  Ekf(const MotionModel& model, const StateVector& x0, const StateMatrix& P0);

  void Predict();  // eqs (4.32)-(4.33)
  void Update(const std::vector<RangeObservation>& observations,
              const SensingFunction& sensing);  // eqs (4.34)-(4.37)

  const StateVector& state() const { return x_; }
  const StateMatrix& covariance() const { return P_; }

 private:
  MotionModel model_;
  StateVector x_;  // x(k|k)
  StateMatrix P_;  // P(k|k)
};

// ---------------------------------------------------------------------------------------
// An estimate in information form: y = Y x (the information vector) and Y = P^-1 (the
// information matrix), of the model's state dimension.
struct InfoState {
  StateVector y;  // y
  StateMatrix Y;  // Y
};

// The state of a moment-form prior (x, P) in information form.
InfoState ToInfoState(const StateVector& x, const StateMatrix& P);
// eqs (4.38)-(4.39) / (4.45)-(4.46) as a pure function: the prediction of `posterior`.
InfoState Predict(const MotionModel& model, const InfoState& posterior);
// True when y and Y are finite, Y is symmetric (to a relative 1e-9) and positive definite.
bool IsValidInfoState(const InfoState& s, int state_dim);

// Covariance intersection of information states (Julier and Uhlmann 1997):
//   Y = w Y_a + (1 - w) Y_b,  y = w y_a + (1 - w) y_b,
// with w in [0, 1] chosen to maximise det Y (the smallest covariance determinant). Whatever
// the correlation between a and b, the result never claims more information than either
// (P_ci is consistent). The weight is found by a fixed number of golden-section steps, so
// the result is a deterministic function of its inputs (bit-identical at every node).
InfoState CovarianceIntersection(const InfoState& a, const InfoState& b);

// ---------------------------------------------------------------------------------------
// Extended information filter in information form (y, Y).
class Eif {
 public:
  Eif(const MotionModel& model, const StateVector& x0, const StateMatrix& P0);
  Eif(const MotionModel& model, InfoState state);

  void Predict();  // eqs (4.38)-(4.39) / (4.45)-(4.46)
  // eqs (4.40)-(4.41) / (4.47)-(4.48): y += i, Y += I, with (i, I) in the position block.
  void AddInformation(const InfoVector& info_vector, const InfoMatrix& info_matrix);

  const StateVector& info_vector() const { return y_; }  // y
  const StateMatrix& info_matrix() const { return Y_; }  // Y
  InfoState info_state() const { return {y_, Y_}; }
  StateVector State() const;                              // x = Y^-1 y
  StateMatrix Covariance() const;                         // P = Y^-1
  Vector2 PositionEstimate() const { return PositionOf(State()); }
  Matrix2 PositionCovariance() const { return PositionBlockOf(Covariance()); }
  const MotionModel& model() const { return model_; }

 private:
  MotionModel model_;
  StateVector y_;  // y(k|k)
  StateMatrix Y_;  // Y(k|k)
};

// eqs (4.49)-(4.51): the local contribution of one range, linearised at p_pred, the position
// part of the node's own prediction x(k|k-1).
//   I_j = H^T R^-1 H,   i_j = H^T R^-1 [ (z - h(x_pred)) + H x_pred ]
Contribution ComputeContribution(StepIndex step, const RangeObservation& z, const Vector2& p_pred,
                                 const SensingFunction& sensing);

// The sums of eqs (4.47)-(4.48), added in ascending agent id, so that every node that fuses
// the same set gets a bit-identical result whatever the arrival order. The input need not
// be sorted. Throws std::invalid_argument when two contributions share an agent id.
struct InformationSum {
  InfoVector info_vector = InfoVector::Zero();
  InfoMatrix info_matrix = InfoMatrix::Zero();
  int count = 0;
};
InformationSum SumContributions(std::vector<Contribution> contributions);

// ---------------------------------------------------------------------------------------
// One DEIF node (section 4.5): predict, compute the local contribution at its own
// prediction, fuse every contribution of the step.
class DeifNode {
 public:
  DeifNode(AgentId id, const MotionModel& model, const StateVector& x0, const StateMatrix& P0,
           const SensingFunction& sensing);

  AgentId id() const { return id_; }
  void Predict();  // eqs (4.45)-(4.46)
  // eqs (4.49)-(4.51) at this node's prediction.
  Contribution LocalContribution(StepIndex step, const RangeObservation& z) const;
  // eqs (4.47)-(4.48). Returns the number fused.
  int Fuse(const std::vector<Contribution>& contributions);
  // Replace the estimate by x, P (a node that rejoins adopts a peer's estimate).
  void Reset(const StateVector& x, const StateMatrix& P);

  const Eif& filter() const { return filter_; }

 private:
  AgentId id_;
  Eif filter_;
  SensingFunction sensing_;
};

// A centralized EIF: the reference every DEIF node must equal under full communication.
class CentralizedEif {
 public:
  CentralizedEif(const MotionModel& model, const StateVector& x0, const StateMatrix& P0,
                 const SensingFunction& sensing);
  // Predict, then process every range of the step, each linearised at the prediction.
  void Step(StepIndex step, const std::vector<RangeObservation>& observations);
  const Eif& filter() const { return filter_; }

 private:
  Eif filter_;
  SensingFunction sensing_;
};

// ---------------------------------------------------------------------------------------
// Validation of a contribution received from a peer, before it can touch an estimate.
enum class RejectReason {
  kNone,
  kNonFinite,        // a NaN or an infinity in i_j or I_j
  kNotSymmetric,     // |I - I^T| beyond a relative tolerance
  kNotPsd,           // an eigenvalue of I_j below -tolerance
  kAbsurdMagnitude,  // |i_j| or |I_j| beyond the configured ceiling
};
const char* ToString(RejectReason reason);

struct ContributionLimits {
  double max_abs_entry = 1e12;  // a ceiling on every entry of i_j and I_j
  double symmetry_rel_tol = 1e-9;
  double psd_rel_tol = 1e-9;
};
RejectReason ValidateContribution(const Contribution& c, const ContributionLimits& limits = {});

}  // namespace deif
