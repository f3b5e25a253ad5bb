// MoveOnRing: one agent's control-law step, with expected values worked out by hand.
#include <catch2/catch.hpp>

#include <cmath>
#include <map>
#include <string>

#include "common/config/config.hpp"
#include "common/protocol/motion.hpp"

using deif::AgentId;
using deif::Config;
using deif::kPi;
using deif::Vector2;

namespace {

// Three agents on a circle of radius 2 about the origin at angles 0, 0.5 and pi.
std::string ThreeAgents(const std::string& law, double max_speed_mps) {
  return "scenario: {dt_s: 0.1}\n"
         "agents:\n"
         "  count: 3\n"
         "  initial_angles_rad: [0.0, 0.5, 3.141592653589793]\n"
         "  radius_m: 2.0\n"
         "  max_speed_mps: " + std::to_string(max_speed_mps) + "\n"
         "  control_law: " + law + "\n";
}

std::map<AgentId, Vector2> Positions() {
  return {{1, Vector2(2.0, 0.0)},
          {2, Vector2(2.0 * std::cos(0.5), 2.0 * std::sin(0.5))},
          {3, Vector2(-2.0, 0.0)}};
}

}  // namespace

TEST_CASE("Law 1 steers to the midpoint of the neighbours' angles about the estimate", "[motion]") {
  const Config config = deif::ParseConfig(ThreeAgents("midpoint", 1000.0), "inline");
  // About the estimate (0.5, 0) the neighbours are at (2, 0) -> angle 0 and (-2, 0) -> pi.
  // eq (3.2) with s = 2 pi / 3: ((0 + s) + (pi - s)) / 2 = pi / 2, so the goal is
  // (0.5, 0) + 2 (cos pi/2, sin pi/2) = (0.5, 2), reached at this speed.
  const auto m = deif::MoveOnRing(config, 2, Vector2(0.5, 0.0), Positions()[2], Positions());
  CHECK(m.position_m.x() == Approx(0.5));
  CHECK(m.position_m.y() == Approx(2.0));
  CHECK(m.angle_rad == Approx(kPi / 2));
  CHECK(m.ring_size == 3);
}

TEST_CASE("Law 2 steers by a quarter of the gap difference (eq 3.6)", "[motion]") {
  const Config config = deif::ParseConfig(ThreeAgents("voronoi", 1000.0), "inline");
  const auto m = deif::MoveOnRing(config, 2, Vector2::Zero(), Positions()[2], Positions());
  // phi' = phi + ((phi3 - phi - s) - (phi - phi1 - s)) / 4 = 0.5 + (pi - 1) / 4.
  const double expected = 0.5 + (kPi - 1.0) / 4.0;
  CHECK(m.angle_rad == Approx(expected));
  CHECK(m.position_m.x() == Approx(2.0 * std::cos(expected)));
  CHECK(m.position_m.y() == Approx(2.0 * std::sin(expected)));
}

TEST_CASE("An agent moves at most max_speed * dt per step", "[motion]") {
  const Config config = deif::ParseConfig(ThreeAgents("midpoint", 0.5), "inline");
  const Vector2 start = Positions()[2];
  const auto m = deif::MoveOnRing(config, 2, Vector2(0.5, 0.0), start, Positions());
  // The goal (0.5, 2) is about 1.1 m away; one step covers 0.5 m/s * 0.1 s = 0.05 m of it.
  const Vector2 goal(0.5, 2.0);
  CHECK((m.position_m - start).norm() == Approx(0.05));
  const Vector2 expected = start + 0.05 * (goal - start).normalized();
  CHECK((m.position_m - expected).norm() == Approx(0.0).margin(1e-12));
}

TEST_CASE("The stationary law never moves the agent", "[motion]") {
  const Config config = deif::ParseConfig(ThreeAgents("stationary", 1.0), "inline");
  const Vector2 start = Positions()[2];
  const auto m = deif::MoveOnRing(config, 2, Vector2(0.5, 0.0), start, Positions());
  CHECK(m.position_m == start);
  // Its angle is reported about the estimate (0.5, 0).
  CHECK(m.angle_rad == Approx(std::atan2(start.y(), start.x() - 0.5)));
}

TEST_CASE("An agent missing from the member positions is placed at its own position", "[motion]") {
  const Config config = deif::ParseConfig(ThreeAgents("midpoint", 1000.0), "inline");
  auto positions = Positions();
  positions.erase(2);
  const auto with = deif::MoveOnRing(config, 2, Vector2(0.5, 0.0), Positions()[2], Positions());
  const auto without = deif::MoveOnRing(config, 2, Vector2(0.5, 0.0), Positions()[2], positions);
  CHECK(with.position_m == without.position_m);
  CHECK(without.ring_size == 3);
}

TEST_CASE("A lone agent stands still; one that is not alone follows the ring's law", "[motion]") {
  // Alone at (2, 0), the estimate moved from the origin to (0.5, 0), 1 m/s, dt 0.1 s.
  const Config config = deif::ParseConfig(ThreeAgents("voronoi", 1.0), "inline");
  const Config law1 = deif::ParseConfig(ThreeAgents("midpoint", 1.0), "inline");
  const std::map<AgentId, Vector2> alone_at{{1, Vector2(2.0, 0.0)}};
  for (const Config* c : {&config, &law1}) {
    const auto m = deif::MoveOnRing(*c, 1, Vector2(0.5, 0.0), Vector2(2.0, 0.0), alone_at, /*alone=*/true);
    CHECK(m.position_m == Vector2(2.0, 0.0));
    CHECK(m.angle_rad == Approx(0.0).margin(1e-12));
    CHECK(m.ring_size == 1);
  }
  // Not alone (a restarted agent that has not heard its peers yet): the laws keep its angle
  // (0) on the circle of 2 m about the new estimate, the goal (2.5, 0), 0.1 m of it a step.
  const auto follows = deif::MoveOnRing(config, 1, Vector2(0.5, 0.0), Vector2(2.0, 0.0), alone_at, false);
  CHECK(follows.position_m.x() == Approx(2.1));
  CHECK(follows.position_m.y() == Approx(0.0).margin(1e-12));
  // Alone but with a ring of more (positions of members it still names): the ring's law.
  const Config fast = deif::ParseConfig(ThreeAgents("voronoi", 1000.0), "inline");
  const auto ringed = deif::MoveOnRing(fast, 2, Vector2::Zero(), Positions()[2], Positions(), true);
  CHECK(ringed.angle_rad == Approx(0.5 + (kPi - 1.0) / 4.0));
}
