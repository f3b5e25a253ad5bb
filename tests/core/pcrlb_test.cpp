#include <catch2/catch.hpp>

#include <cmath>
#include <vector>

#include "common/core/fisher.hpp"

namespace deif {
namespace {

constexpr double kPi = 3.141592653589793238462643383279;

std::vector<SensorGeometry> EvenRing(const Vector2& centre, int n, double radius_m,
                                     double variance_m2) {
  std::vector<SensorGeometry> sensors;
  for (int k = 0; k < n; ++k) {
    const double a = 0.4 + 2.0 * kPi * static_cast<double>(k) / static_cast<double>(n);
    SensorGeometry s;
    s.p_sensor = centre + radius_m * Vector2(std::cos(a), std::sin(a));
    s.variance_m2 = variance_m2;
    sensors.push_back(s);
  }
  return sensors;
}

TEST_CASE("One snapshot of N evenly spaced range sensors bounds the RMSE at 2 sigma / sqrt(N)",
          "[pcrlb]") {
  // J = sum u u^T / sigma^2 = N / (2 sigma^2) I for evenly spaced unit vectors, so
  // J^-1 = 2 sigma^2 / N I and sqrt(tr J^-1) = 2 sigma / sqrt(N).
  const double sigma = 0.023;
  const Vector2 target(0.4, -0.1);
  for (int n = 3; n <= 8; ++n) {
    const auto sensors = EvenRing(target, n, 1.3, sigma * sigma);
    const double expected = 2.0 * sigma / std::sqrt(static_cast<double>(n));
    CAPTURE(n);
    // directly from eq (2.2)
    const Matrix2 J = FisherInformation(sensors, target, SensingFunction{});
    CHECK(std::sqrt(J.inverse().trace()) == Approx(expected).epsilon(1e-12));
    // and through the recursion from (almost) no prior information
    MotionModel model;
    model.process_noise = 1e-4;
    Pcrlb pcrlb(model, 1e12 * Eigen::Matrix2d::Identity());
    pcrlb.Step(target, sensors, SensingFunction{});
    CHECK(pcrlb.PositionRmseBound() == Approx(expected).epsilon(1e-9));
  }
}

TEST_CASE("PCRLB of a static target under a random walk converges to the Riccati fixed point",
          "[pcrlb]") {
  // GIVEN a static target watched by 4 sensors and a random-walk model
  MotionModel model;
  model.kind = MotionModelKind::kRandomWalk;
  model.process_noise = 1.3e-4;
  const Vector2 target(0.0, 0.0);
  const std::vector<SensorGeometry> sensors = {
      {Vector2(1.0, 0.2), 5.3e-4}, {Vector2(-0.5, 1.1), 5.3e-4},
      {Vector2(-0.9, -0.7), 5.3e-4}, {Vector2(0.3, -1.4), 5.3e-4}};
  const Eigen::Matrix2d P0 = 0.5 * Eigen::Matrix2d::Identity();
  Pcrlb pcrlb(model, P0);
  const double initial_bound = pcrlb.PositionRmseBound();
  CHECK(initial_bound == Approx(1.0));  // sqrt(0.5 + 0.5)

  // WHEN the recursion runs
  double previous = initial_bound;
  for (int k = 0; k < 500; ++k) {
    pcrlb.Step(target, sensors, SensingFunction{});
    // THEN the bound stays below the prior one and never increases (more data, same truth)
    REQUIRE(pcrlb.PositionRmseBound() < initial_bound);
    REQUIRE(pcrlb.PositionRmseBound() <= previous + 1e-15);
    previous = pcrlb.PositionRmseBound();
  }
  // AND it settles on J_ss = (Q + J_ss^-1)^-1 + J_meas (F = I)
  const Eigen::Matrix2d J_ss = pcrlb.information();
  const Eigen::Matrix2d J_meas = FisherInformation(sensors, target, SensingFunction{});
  const Eigen::Matrix2d Q = model.ProcessNoise();
  const Eigen::Matrix2d fixed_point = (Q + J_ss.inverse()).inverse() + J_meas;
  CHECK((fixed_point - J_ss).norm() < 1e-9 * J_ss.norm());
  // the steady state is worth more than one snapshot but less than unbounded averaging
  CHECK(pcrlb.PositionRmseBound() < std::sqrt(J_meas.inverse().trace()));
}

TEST_CASE("PCRLB with the constant velocity model tightens the position bound", "[pcrlb]") {
  MotionModel model;
  model.kind = MotionModelKind::kConstantVelocity;
  model.dt_s = 0.1;
  model.process_noise = 0.1;
  const Eigen::Matrix4d P0 = Eigen::Vector4d(1.0, 1.0, 1.0, 1.0).asDiagonal();
  Pcrlb pcrlb(model, P0);
  const auto sensors = EvenRing(Vector2::Zero(), 3, 1.0, 0.01);
  REQUIRE(pcrlb.information().rows() == 4);
  for (int k = 0; k < 50; ++k) {
    // the target moves along x at 0.1 m/s
    pcrlb.Step(Vector2(0.01 * static_cast<double>(k), 0.0), sensors, SensingFunction{});
  }
  // tighter than a single snapshot of the same sensors, 2 sigma / sqrt(3) = 0.1155
  CHECK(pcrlb.PositionRmseBound() < 2.0 * 0.1 / std::sqrt(3.0));
  CHECK(pcrlb.PositionBound().isApprox(pcrlb.PositionBound().transpose()));
}

}  // namespace
}  // namespace deif
