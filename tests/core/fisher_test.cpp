#include <catch2/catch.hpp>

#include <cmath>
#include <random>
#include <vector>

#include "common/core/fisher.hpp"

namespace deif {
namespace {

constexpr double kPi = 3.141592653589793238462643383279;

// Sensors at the given bearings about the target, at the given distances.
std::vector<SensorGeometry> SensorsAtAngles(const Vector2& p_target,
                                            const std::vector<double>& angles_rad,
                                            const std::vector<double>& distances_m,
                                            double variance_m2) {
  std::vector<SensorGeometry> sensors;
  for (std::size_t j = 0; j < angles_rad.size(); ++j) {
    SensorGeometry s;
    s.p_sensor = p_target + distances_m[j] * Vector2(std::cos(angles_rad[j]),
                                                     std::sin(angles_rad[j]));
    s.variance_m2 = variance_m2;
    sensors.push_back(s);
  }
  return sensors;
}

std::vector<double> EvenlySpaced(int n, double offset_rad) {
  std::vector<double> angles;
  for (int k = 0; k < n; ++k) {
    angles.push_back(offset_rad + 2.0 * kPi * static_cast<double>(k) / static_cast<double>(n));
  }
  return angles;
}

TEST_CASE("Eq (2.6) equals det(G^T G) / sigma^4 on random geometries", "[fisher]") {
  std::mt19937 rng(42);
  std::uniform_real_distribution<double> coordinate(-3.0, 3.0);
  std::uniform_int_distribution<int> count(2, 8);
  SensingFunction squared;  // beta = 2: gradients of different lengths, not unit vectors
  squared.beta = 2.0;
  for (int trial = 0; trial < 200; ++trial) {
    const SensingFunction& sensing = trial % 2 == 0 ? SensingFunction{} : squared;
    const Vector2 p_target(coordinate(rng), coordinate(rng));
    std::vector<SensorGeometry> sensors(static_cast<std::size_t>(count(rng)));
    for (SensorGeometry& s : sensors) {
      s.p_sensor = Vector2(coordinate(rng), coordinate(rng));
      s.variance_m2 = 0.04;
    }
    const Eigen::MatrixX2d G = SensitivityMatrix(sensors, p_target, sensing);
    const double expected = (G.transpose() * G).determinant() / (0.04 * 0.04);
    CAPTURE(trial);
    CHECK(DetFisherClosedForm(sensors, p_target, sensing) ==
          Approx(expected).epsilon(1e-9).margin(1e-9));
    // and eq (2.2) is G^T G / sigma^2 for equal variances
    CHECK(FisherInformation(sensors, p_target, sensing)
              .isApprox(G.transpose() * G / 0.04, 1e-12));
  }
}

TEST_CASE("f(theta) of eq (2.7) never exceeds N^2", "[fisher]") {
  std::mt19937 rng(7);
  std::uniform_real_distribution<double> angle(0.0, 2.0 * kPi);
  for (int n = 2; n <= 10; ++n) {
    double largest = 0.0;
    for (int trial = 0; trial < 2000; ++trial) {
      std::vector<double> angles(static_cast<std::size_t>(n));
      for (double& a : angles) {
        a = angle(rng);
      }
      const double f = AngleObjective(angles);
      largest = std::max(largest, f);
      REQUIRE(f <= static_cast<double>(n * n) + 1e-9);
      REQUIRE(f >= 0.0);
    }
    // random sets come reasonably close to the bound, so the check above had teeth
    CHECK(largest > 0.8 * static_cast<double>(n * n));
  }
}

TEST_CASE("Evenly spaced sensors reach f(theta) = N^2 for N >= 3", "[fisher]") {
  for (int n = 3; n <= 10; ++n) {
    // f = 2 sum_{i,j} sin^2 = sum_{i,j} (1 - cos 2(theta_i - theta_j))
    //   = N^2 - |sum_k e^{2 i theta_k}|^2 = N^2 since the doubled angles cancel for N >= 3.
    CHECK(AngleObjective(EvenlySpaced(n, 0.3)) == Approx(static_cast<double>(n * n)));
  }
}

TEST_CASE("Two sensors at a right angle reach N^2 = 4 while opposite sensors give det J = 0",
          "[fisher]") {
  // f({0, pi/2}) = 2 (sin^2(pi/2) + sin^2(-pi/2)) = 4
  CHECK(AngleObjective({0.0, kPi / 2.0}) == Approx(4.0));
  // f({0, pi}) = 2 (sin^2(pi) + sin^2(-pi)) = 0
  CHECK(AngleObjective({0.0, kPi}) == Approx(0.0).margin(1e-12));
  const Vector2 target(0.5, 0.5);
  const auto opposite = SensorsAtAngles(target, {0.0, kPi}, {1.0, 2.0}, 0.1);
  CHECK(FisherInformation(opposite, target, SensingFunction{}).determinant() ==
        Approx(0.0).margin(1e-12));
  CHECK(DetFisherClosedForm(opposite, target, SensingFunction{}) == Approx(0.0).margin(1e-12));
}

TEST_CASE("f(theta) equals 4 sigma^4 det J for unit gradients", "[fisher]") {
  std::mt19937 rng(3);
  std::uniform_real_distribution<double> angle(0.0, 2.0 * kPi);
  std::uniform_real_distribution<double> distance(0.5, 4.0);
  const Vector2 target(-0.3, 1.2);
  const double sigma2 = 0.25;
  for (int trial = 0; trial < 50; ++trial) {
    std::vector<double> angles(5);
    std::vector<double> distances(5);
    for (std::size_t j = 0; j < 5; ++j) {
      angles[j] = angle(rng);
      distances[j] = distance(rng);
    }
    const auto sensors = SensorsAtAngles(target, angles, distances, sigma2);
    const double det_J = FisherInformation(sensors, target, SensingFunction{}).determinant();
    CHECK(AngleObjective(angles) == Approx(4.0 * sigma2 * sigma2 * det_J).epsilon(1e-9));
  }
}

TEST_CASE("OptimalityRatio is 1 at the optimum, f / N^2 otherwise, 0 for no information",
          "[fisher]") {
  const Vector2 target(1.0, -1.0);
  const auto even = SensorsAtAngles(target, EvenlySpaced(5, 0.7), {1, 2, 3, 1.5, 0.8}, 0.1);
  CHECK(OptimalityRatio(FisherInformation(even, target, SensingFunction{})) == Approx(1.0));

  const std::vector<double> angles = {0.1, 0.5, 2.0, 2.2};
  const auto uneven = SensorsAtAngles(target, angles, {1, 1, 1, 1}, 0.1);
  CHECK(OptimalityRatio(FisherInformation(uneven, target, SensingFunction{})) ==
        Approx(AngleObjective(angles) / 16.0));
  CHECK(OptimalityRatio(Matrix2::Zero()) == 0.0);
}

TEST_CASE("Optimal gap is 2 pi / n for n >= 3 and pi / 2 for two sensors", "[fisher]") {
  CHECK(OptimalGapRad(0) == 0.0);
  CHECK(OptimalGapRad(1) == 0.0);
  CHECK(OptimalGapRad(2) == Approx(1.5707963268));
  CHECK(OptimalGapRad(3) == Approx(2.0943951024));
  CHECK(OptimalGapRad(4) == Approx(1.5707963268));
  CHECK(OptimalGapRad(8) == Approx(0.7853981634));
}

}  // namespace
}  // namespace deif
