#include <catch2/catch.hpp>

#include <cmath>

#include "common/core/models.hpp"
#include "tests/support/numerical_diff.hpp"

namespace deif {
namespace {

constexpr double kPi = 3.141592653589793238462643383279;

TEST_CASE("Random walk model has F = I2 and Q = q I2 (eq 5.1)", "[models]") {
  MotionModel model;
  model.kind = MotionModelKind::kRandomWalk;
  model.process_noise = 1.3e-4;
  REQUIRE(model.StateDim() == 2);
  CHECK(model.TransitionMatrix().isApprox(Eigen::Matrix2d::Identity()));
  CHECK(model.ProcessNoise().isApprox(1.3e-4 * Eigen::Matrix2d::Identity()));
}

TEST_CASE("Constant velocity model has the white-acceleration F and Q", "[models]") {
  MotionModel model;
  model.kind = MotionModelKind::kConstantVelocity;
  model.dt_s = 0.5;
  model.process_noise = 2.0;
  REQUIRE(model.StateDim() == 4);
  // F = [1 0 .5 0; 0 1 0 .5; 0 0 1 0; 0 0 0 1]
  Eigen::Matrix4d F_expected;
  F_expected << 1, 0, 0.5, 0,  //
      0, 1, 0, 0.5,            //
      0, 0, 1, 0,              //
      0, 0, 0, 1;
  // Q = 2 [dt^3/3, dt^2/2; dt^2/2, dt] per axis = [1/12, 1/4; 1/4, 1]
  Eigen::Matrix4d Q_expected;
  Q_expected << 1.0 / 12, 0, 0.25, 0,  //
      0, 1.0 / 12, 0, 0.25,            //
      0.25, 0, 1, 0,                   //
      0, 0.25, 0, 1;
  CHECK(model.TransitionMatrix().isApprox(F_expected, 1e-15));
  CHECK(model.ProcessNoise().isApprox(Q_expected, 1e-15));
}

TEST_CASE("Figure-eight trajectory follows eq (5.3)", "[models]") {
  TrajectoryConfig config;
  config.kind = TrajectoryKind::kFigureEight;
  // t = pi/2: [sin, sin cos] = [1, 0]
  const Vector2 at_half_pi = TrajectoryPosition(config, kPi / 2.0);
  CHECK(at_half_pi.x() == Approx(1.0));
  CHECK(at_half_pi.y() == Approx(0.0).margin(1e-15));
  // t = pi/6: [1/2, 1/2 * sqrt(3)/2] = [0.5, 0.4330127019]
  const Vector2 at_sixth_pi = TrajectoryPosition(config, kPi / 6.0);
  CHECK(at_sixth_pi.x() == Approx(0.5));
  CHECK(at_sixth_pi.y() == Approx(0.4330127019));
}

TEST_CASE("Shifted figure-eight trajectory follows eq (5.7)", "[models]") {
  TrajectoryConfig config;
  config.kind = TrajectoryKind::kFigureEightShifted;
  // t = 0: [0, -1]
  const Vector2 at_zero = TrajectoryPosition(config, 0.0);
  CHECK(at_zero.x() == Approx(0.0).margin(1e-15));
  CHECK(at_zero.y() == Approx(-1.0));
  // t = pi/4: [sqrt(2)/2, 1/2 - 1] = [0.7071067812, -0.5]
  const Vector2 at_quarter_pi = TrajectoryPosition(config, kPi / 4.0);
  CHECK(at_quarter_pi.x() == Approx(0.7071067812));
  CHECK(at_quarter_pi.y() == Approx(-0.5));
}

TEST_CASE("Circle, line and static trajectories", "[models]") {
  TrajectoryConfig config;
  config.start_m = Vector2(1.0, 2.0);

  config.kind = TrajectoryKind::kCircle;
  config.circle_radius_m = 2.0;
  config.angular_rate_radps = 0.5;
  // w t = 0.5 * pi = pi/2: centre + 2 [0, 1] = (1, 4)
  const Vector2 on_circle = TrajectoryPosition(config, kPi);
  CHECK(on_circle.x() == Approx(1.0));
  CHECK(on_circle.y() == Approx(4.0));

  config.kind = TrajectoryKind::kLine;
  config.velocity_mps = Vector2(0.1, -0.2);
  // (1, 2) + 10 (0.1, -0.2) = (2, 0)
  const Vector2 on_line = TrajectoryPosition(config, 10.0);
  CHECK(on_line.x() == Approx(2.0));
  CHECK(on_line.y() == Approx(0.0).margin(1e-14));

  config.kind = TrajectoryKind::kStatic;
  CHECK(TrajectoryPosition(config, 123.0) == Vector2(1.0, 2.0));
  config.kind = TrajectoryKind::kRandomWalk;
  CHECK(TrajectoryPosition(config, 123.0) == Vector2(1.0, 2.0));
}

TEST_CASE("Sensing function follows the three branches of eq (2.1)", "[models]") {
  SensingFunction f;
  f.c0 = 1.0;
  f.r0_m = 0.5;
  f.r1_m = 2.0;
  f.beta = 2.0;
  // c1 = c0 - R0^beta = 1 - 0.25 = 0.75
  double slope = -1.0;
  CHECK(f.Evaluate(0.3, &slope) == Approx(1.0));  // r <= R0: c0
  CHECK(slope == 0.0);
  CHECK(f.Evaluate(0.5) == Approx(1.0));  // continuous at R0
  CHECK(f.Evaluate(1.0, &slope) == Approx(1.75));  // 1 + 0.75
  CHECK(slope == Approx(2.0));                      // beta r^(beta-1) = 2
  CHECK(f.Evaluate(3.0, &slope) == Approx(4.75));  // R1^2 + c1 = 4 + 0.75
  CHECK(slope == 0.0);
  CHECK(f.InRange(1.0));
  CHECK_FALSE(f.InRange(0.5));
  CHECK_FALSE(f.InRange(2.5));
}

TEST_CASE("Default sensing function is the plain range of eq (5.5)", "[models]") {
  const SensingFunction f;
  // sensor at (1, 1), target at (4, 5): range 5, H = (3, 4) / 5
  RowVector2 H;
  CHECK(MeasureRange(Vector2(4.0, 5.0), Vector2(1.0, 1.0), f, &H) == Approx(5.0));
  CHECK(H(0) == Approx(0.6));
  CHECK(H(1) == Approx(0.8));
}

TEST_CASE("Inverse-range sensing with R0 = 0 is 1/r plus c0", "[models]") {
  SensingFunction f;
  f.beta = -1.0;
  f.c0 = 0.5;
  // R0 = 0: R0^beta is infinite, so c1 = c0 (documented choice); f(2) = 1/2 + 1/2 = 1.
  CHECK(f.Evaluate(2.0) == Approx(1.0));
  CHECK(f.Evaluate(0.0) == Approx(0.5));  // the r <= R0 branch
}

TEST_CASE("Sensing function derivative agrees with central differences", "[models][jacobian]") {
  for (const double beta : {1.0, 2.0, 3.0, -1.0}) {
    SensingFunction f;
    f.c0 = 0.3;
    f.r0_m = 0.2;
    f.r1_m = 5.0;
    f.beta = beta;
    for (const double r : {0.35, 1.0, 2.7, 4.6}) {
      double analytic = 0.0;
      f.Evaluate(r, &analytic);
      const double numeric =
          test::CentralDerivative([&f](double s) { return f.Evaluate(s); }, r);
      CAPTURE(beta, r);
      CHECK(analytic == Approx(numeric).epsilon(1e-7).margin(1e-8));
    }
  }
}

// The 1x2 analytic H of MeasureRange against central differences at a few geometries.
void CheckRangeJacobian(const SensingFunction& f) {
  const Vector2 p_sensor(0.4, -0.7);
  for (const Vector2& p_target :
       {Vector2(1.3, 0.2), Vector2(-0.9, -2.1), Vector2(0.4, 1.8), Vector2(2.2, -3.0)}) {
    REQUIRE(f.InRange((p_target - p_sensor).norm()));
    RowVector2 analytic;
    MeasureRange(p_target, p_sensor, f, &analytic);
    const RowVector2 numeric = test::CentralGradient(
        [&](const Vector2& x) { return MeasureRange(x, p_sensor, f); }, p_target);
    CAPTURE(p_target.transpose(), analytic, numeric);
    CHECK(analytic(0) == Approx(numeric(0)).epsilon(1e-7).margin(1e-8));
    CHECK(analytic(1) == Approx(numeric(1)).epsilon(1e-7).margin(1e-8));
  }
}

TEST_CASE("Range Jacobian H agrees with central differences for the plain range",
          "[models][jacobian]") {
  CheckRangeJacobian(SensingFunction{});
}

TEST_CASE("Range Jacobian H agrees with central differences for beta = 2 inside (R0, R1)",
          "[models][jacobian]") {
  SensingFunction f;
  f.c0 = 0.1;
  f.r0_m = 0.3;
  f.r1_m = 4.0;
  f.beta = 2.0;
  CheckRangeJacobian(f);
}

TEST_CASE("Range Jacobian H agrees with central differences for beta = -1 inside (R0, R1)",
          "[models][jacobian]") {
  SensingFunction f;
  f.c0 = 2.0;
  f.r0_m = 0.5;
  f.r1_m = 4.0;
  f.beta = -1.0;
  CheckRangeJacobian(f);
}

TEST_CASE("Range Jacobian is zero at the sensor position and outside the sensing range",
          "[models][jacobian]") {
  RowVector2 H;
  MeasureRange(Vector2(1.0, 1.0), Vector2(1.0, 1.0), SensingFunction{}, &H);
  CHECK(H.isZero(0.0));

  SensingFunction f;
  f.r1_m = 1.0;
  MeasureRange(Vector2(3.0, 1.0), Vector2(1.0, 1.0), f, &H);  // r = 2 > R1
  CHECK(H.isZero(0.0));
}

}  // namespace
}  // namespace deif
