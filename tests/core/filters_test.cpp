#include <catch2/catch.hpp>

#include <algorithm>
#include <array>
#include <cmath>
#include <limits>
#include <random>
#include <vector>

#include "common/core/filters.hpp"

namespace deif {
namespace {

// A seeded scenario: sensors scattered about the origin, a target on the figure-eight of
// eq (5.3), noisy ranges. Independent of the code under test except for the models.
struct Scenario {
  std::vector<Vector2> sensors;
  std::vector<Vector2> truth;                            // per step
  std::vector<std::vector<RangeObservation>> ranges;     // per step
};

Scenario MakeScenario(unsigned seed, int n_sensors, int n_steps, double dt_s,
                      double range_variance) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<double> radius(1.0, 3.0);
  std::uniform_real_distribution<double> angle(0.0, 2.0 * 3.14159265358979);
  std::normal_distribution<double> noise(0.0, std::sqrt(range_variance));
  Scenario s;
  for (int j = 0; j < n_sensors; ++j) {
    const double r = radius(rng);
    const double a = angle(rng);
    s.sensors.emplace_back(r * std::cos(a), r * std::sin(a));
  }
  for (int k = 1; k <= n_steps; ++k) {
    const double t = dt_s * static_cast<double>(k);
    const Vector2 p(std::sin(t), std::sin(t) * std::cos(t));  // eq (5.3)
    s.truth.push_back(p);
    std::vector<RangeObservation> step;
    for (int j = 0; j < n_sensors; ++j) {
      RangeObservation z;
      z.agent_id = j;
      z.p_sensor = s.sensors[static_cast<std::size_t>(j)];
      z.range_m = (p - z.p_sensor).norm() + noise(rng);
      z.variance_m2 = range_variance;
      step.push_back(z);
    }
    s.ranges.push_back(step);
  }
  return s;
}

void CheckEifEqualsEkf(const MotionModel& model, const StateVector& x0, const StateMatrix& P0,
                       unsigned seed) {
  const Scenario scenario = MakeScenario(seed, 4, 40, model.dt_s, 0.01);
  const SensingFunction sensing;
  Ekf ekf(model, x0, P0);
  Eif eif(model, x0, P0);
  for (const auto& ranges : scenario.ranges) {
    ekf.Predict();
    eif.Predict();
    // EIF: sum of eqs (4.42)-(4.43) over the sensors, all at the same prediction.
    const Vector2 p_pred = eif.PositionEstimate();
    for (const RangeObservation& z : ranges) {
      const Contribution c = ComputeContribution(0, z, p_pred, sensing);
      eif.AddInformation(c.info_vector, c.info_matrix);
    }
    ekf.Update(ranges, sensing);
    REQUIRE((eif.State() - ekf.state()).cwiseAbs().maxCoeff() < 1e-9);
    REQUIRE((eif.Covariance() - ekf.covariance()).cwiseAbs().maxCoeff() < 1e-9);
  }
  // And the filter actually tracked the target (the comparison is not of two idle filters).
  CHECK((PositionOf(ekf.state()) - scenario.truth.back()).norm() < 0.2);
}

TEST_CASE("EIF equals EKF on the same data with the random walk model", "[filters]") {
  MotionModel model;
  model.kind = MotionModelKind::kRandomWalk;
  model.dt_s = 0.1;
  model.process_noise = 1e-2;
  for (const unsigned seed : {1u, 2u, 3u}) {
    CheckEifEqualsEkf(model, Vector2(0.3, -0.2), 0.5 * Eigen::Matrix2d::Identity(), seed);
  }
}

TEST_CASE("EIF equals EKF on the same data with the constant velocity model", "[filters]") {
  MotionModel model;
  model.kind = MotionModelKind::kConstantVelocity;
  model.dt_s = 0.1;
  model.process_noise = 0.5;
  StateVector x0(4);
  x0 << 0.2, 0.1, 0.5, 0.5;
  const StateMatrix P0 = Eigen::Vector4d(0.5, 0.5, 1.0, 1.0).asDiagonal();
  for (const unsigned seed : {4u, 5u, 6u}) {
    CheckEifEqualsEkf(model, x0, P0, seed);
  }
}

TEST_CASE("Contribution follows eqs (4.49)-(4.51) for a hand-computed geometry", "[filters]") {
  // Sensor at the origin, prediction at (3, 4): h = 5, H = (0.6, 0.8).
  // z = 5.5, R = 0.25: v = 0.5, H p_pred = 5,
  // I = H^T H / R = 4 [0.36 0.48; 0.48 0.64] = [1.44 1.92; 1.92 2.56],
  // i = H^T (v + H p_pred) / R = (0.6, 0.8) * 4 * 5.5 = (13.2, 17.6).
  RangeObservation z;
  z.agent_id = 7;
  z.range_m = 5.5;
  z.variance_m2 = 0.25;
  const Contribution c = ComputeContribution(12, z, Vector2(3.0, 4.0), SensingFunction{});
  CHECK(c.agent_id == 7);
  CHECK(c.step == 12);
  CHECK(c.info_matrix(0, 0) == Approx(1.44));
  CHECK(c.info_matrix(0, 1) == Approx(1.92));
  CHECK(c.info_matrix(1, 0) == Approx(1.92));
  CHECK(c.info_matrix(1, 1) == Approx(2.56));
  CHECK(c.info_vector(0) == Approx(13.2));
  CHECK(c.info_vector(1) == Approx(17.6));
}

TEST_CASE("DEIF nodes that fuse every contribution equal the centralized EIF", "[filters]") {
  // GIVEN five nodes and a centralized EIF with the same prior
  MotionModel model;
  model.kind = MotionModelKind::kRandomWalk;
  model.process_noise = 1.3e-4;
  const SensingFunction sensing;
  const Vector2 x0(0.1, 0.1);
  const Eigen::Matrix2d P0 = 0.2 * Eigen::Matrix2d::Identity();
  constexpr int kNodes = 5;
  const Scenario scenario = MakeScenario(11, kNodes, 100, model.dt_s, 5.3e-4);
  std::vector<DeifNode> nodes;
  for (int j = 0; j < kNodes; ++j) {
    nodes.emplace_back(j, model, x0, P0, sensing);
  }
  CentralizedEif central(model, x0, P0, sensing);

  for (std::size_t k = 0; k < scenario.ranges.size(); ++k) {
    const auto step = static_cast<StepIndex>(k);
    const auto& ranges = scenario.ranges[k];
    // WHEN each node predicts, computes its own contribution and receives all the others
    std::vector<Contribution> broadcast;
    for (DeifNode& node : nodes) {
      node.Predict();
      broadcast.push_back(node.LocalContribution(step, ranges[static_cast<std::size_t>(node.id())]));
    }
    for (std::size_t j = 0; j < nodes.size(); ++j) {
      // each node receives the broadcast in a different (rotated) order
      std::vector<Contribution> received = broadcast;
      std::rotate(received.begin(), received.begin() + static_cast<std::ptrdiff_t>(j),
                  received.end());
      REQUIRE(nodes[j].Fuse(received) == kNodes);
    }
    central.Step(step, ranges);
    // THEN every node holds exactly the centralized information state
    for (const DeifNode& node : nodes) {
      REQUIRE(node.filter().info_vector() == central.filter().info_vector());
      REQUIRE(node.filter().info_matrix() == central.filter().info_matrix());
    }
  }
  CHECK((central.filter().PositionEstimate() - scenario.truth.back()).norm() < 0.1);
}

TEST_CASE("Fusing the same contributions in any arrival order is bit-identical", "[filters]") {
  // GIVEN five contributions of very different magnitudes, so that floating-point
  // addition in different orders would round differently
  std::vector<Contribution> contributions;
  const std::array<double, 5> scales = {1e16, 1.0, -1e16, 3.3, 1e-3};
  for (int j = 0; j < 5; ++j) {
    Contribution c;
    c.agent_id = 10 + j;
    const double s = scales[static_cast<std::size_t>(j)];
    c.info_vector = InfoVector(s + 0.1 * j, 0.7 * s - j);
    c.info_matrix << std::abs(s) + 1.1, 0.3 * s, 0.3 * s, std::abs(s) + 0.9 * j;
    contributions.push_back(c);
  }
  MotionModel model;
  const Eif prior(model, Vector2(0.5, -0.25), 0.3 * Eigen::Matrix2d::Identity());

  std::array<std::size_t, 5> order = {0, 1, 2, 3, 4};
  Eif reference = prior;
  reference.AddInformation(SumContributions(contributions).info_vector,
                           SumContributions(contributions).info_matrix);
  bool naive_order_matters = false;
  InfoVector naive_reference = InfoVector::Zero();
  for (const auto& c : contributions) {
    naive_reference += c.info_vector;
  }
  int permutations = 0;
  do {
    std::vector<Contribution> arrived;
    InfoVector naive = InfoVector::Zero();
    for (const std::size_t idx : order) {
      arrived.push_back(contributions[idx]);
      naive += contributions[idx].info_vector;
    }
    naive_order_matters = naive_order_matters || naive != naive_reference;
    // WHEN a node fuses them in this arrival order
    DeifNode node(0, model, Vector2(0.5, -0.25), 0.3 * Eigen::Matrix2d::Identity(),
                  SensingFunction{});
    node.Fuse(arrived);
    // THEN y and Y are bit-identical to every other order
    REQUIRE(node.filter().info_vector() == reference.info_vector());
    REQUIRE(node.filter().info_matrix() == reference.info_matrix());
    ++permutations;
  } while (std::next_permutation(order.begin(), order.end()));
  CHECK(permutations == 120);
  // The data are such that a plain in-arrival-order sum would NOT be order-independent.
  CHECK(naive_order_matters);
}

TEST_CASE("SumContributions adds every contribution and counts them", "[filters]") {
  Contribution a;
  a.agent_id = 3;
  a.info_vector = InfoVector(1.0, 2.0);
  a.info_matrix << 1.0, 0.5, 0.5, 2.0;
  Contribution b;
  b.agent_id = 1;
  b.info_vector = InfoVector(-0.5, 4.0);
  b.info_matrix << 3.0, -1.0, -1.0, 1.0;
  const InformationSum sum = SumContributions({a, b});
  CHECK(sum.count == 2);
  CHECK(sum.info_vector == InfoVector(0.5, 6.0));
  CHECK(sum.info_matrix(0, 0) == 4.0);
  CHECK(sum.info_matrix(0, 1) == -0.5);
  CHECK(sum.info_matrix(1, 1) == 3.0);
  CHECK(SumContributions({}).count == 0);
}

// --- Validation ------------------------------------------------------------------------

Contribution RealContribution() {
  RangeObservation z;
  z.agent_id = 2;
  z.range_m = 1.7;
  z.variance_m2 = 5.3e-4;
  z.p_sensor = Vector2(1.5, -0.5);
  return ComputeContribution(3, z, Vector2(0.2, 0.3), SensingFunction{});
}

TEST_CASE("ValidateContribution accepts a real contribution", "[filters][validation]") {
  CHECK(ValidateContribution(RealContribution()) == RejectReason::kNone);
  CHECK(ValidateContribution(Contribution{}) == RejectReason::kNone);  // no information
}

TEST_CASE("ValidateContribution rejects a NaN", "[filters][validation]") {
  Contribution c = RealContribution();
  c.info_vector(1) = std::numeric_limits<double>::quiet_NaN();
  CHECK(ValidateContribution(c) == RejectReason::kNonFinite);
  c = RealContribution();
  c.info_matrix(0, 0) = std::numeric_limits<double>::quiet_NaN();
  CHECK(ValidateContribution(c) == RejectReason::kNonFinite);
}

TEST_CASE("ValidateContribution rejects an infinity", "[filters][validation]") {
  Contribution c = RealContribution();
  c.info_matrix(1, 1) = std::numeric_limits<double>::infinity();
  CHECK(ValidateContribution(c) == RejectReason::kNonFinite);
  c = RealContribution();
  c.info_vector(0) = -std::numeric_limits<double>::infinity();
  CHECK(ValidateContribution(c) == RejectReason::kNonFinite);
}

TEST_CASE("ValidateContribution rejects an asymmetric matrix", "[filters][validation]") {
  Contribution c;
  c.info_matrix << 2.0, 0.5, 0.4, 2.0;  // |0.5 - 0.4| = 0.1 >> 1e-9 * 2
  CHECK(ValidateContribution(c) == RejectReason::kNotSymmetric);
}

TEST_CASE("ValidateContribution rejects an indefinite matrix", "[filters][validation]") {
  Contribution c;
  c.info_matrix << 1.0, 2.0, 2.0, 1.0;  // eigenvalues 3 and -1
  CHECK(ValidateContribution(c) == RejectReason::kNotPsd);
  c.info_matrix << -1e-3, 0.0, 0.0, 5.0;  // a small negative diagonal
  CHECK(ValidateContribution(c) == RejectReason::kNotPsd);
}

TEST_CASE("ValidateContribution rejects an absurd magnitude", "[filters][validation]") {
  Contribution c;
  c.info_matrix << 1e13, 0.0, 0.0, 1.0;
  CHECK(ValidateContribution(c) == RejectReason::kAbsurdMagnitude);
  c = Contribution{};
  c.info_vector = InfoVector(0.0, -2e12);
  CHECK(ValidateContribution(c) == RejectReason::kAbsurdMagnitude);
  ContributionLimits tight;
  tight.max_abs_entry = 10.0;
  CHECK(ValidateContribution(RealContribution(), tight) == RejectReason::kAbsurdMagnitude);
}

TEST_CASE("Reject reasons have short snake_case names", "[filters][validation]") {
  CHECK(std::string(ToString(RejectReason::kNone)) == "none");
  CHECK(std::string(ToString(RejectReason::kNonFinite)) == "non_finite");
  CHECK(std::string(ToString(RejectReason::kNotSymmetric)) == "not_symmetric");
  CHECK(std::string(ToString(RejectReason::kNotPsd)) == "not_psd");
  CHECK(std::string(ToString(RejectReason::kAbsurdMagnitude)) == "absurd_magnitude");
}

}  // namespace
}  // namespace deif
