// AgentCore: one agent's step, predict / contribute / fuse / steer, with expected values
// worked out by hand in the comments.
#include <catch2/catch.hpp>

#include <cmath>
#include <map>
#include <optional>
#include <vector>

#include "common/protocol/agent_core.hpp"
#include "common/config/config.hpp"

using deif::AgentCore;
using deif::AgentId;
using deif::Config;
using deif::Vector2;

namespace {

constexpr double kPi = 3.14159265358979323846;

// Three agents on a circle of radius 2 about the origin at angles 0, 0.5 and pi, with the
// filter's initial estimate at (0.5, 0). Without contributions a random-walk prediction
// keeps the mean, so the estimate after step 1 is still (0.5, 0).
std::string ThreeAgents(const std::string& law, double max_speed_mps) {
  return "scenario: {dt_s: 0.1}\n"
         "filter: {initial_estimate_m: [0.5, 0.0]}\n"
         "agents:\n"
         "  count: 3\n"
         "  initial_angles_rad: [0.0, 0.5, 3.141592653589793]\n"
         "  radius_m: 2.0\n"
         "  max_speed_mps: " + std::to_string(max_speed_mps) + "\n"
         "  control_law: " + law + "\n";
}

std::map<AgentId, Vector2> InitialPositions(const Config& config) {
  std::map<AgentId, Vector2> positions;
  for (AgentId id = 1; id <= config.agents.count; ++id) {
    positions[id] = AgentCore(config, id).position();
  }
  return positions;
}

}  // namespace

TEST_CASE("An agent starts on the configured circle at its initial angle", "[agent_core]") {
  const Config config = deif::ParseConfig(
      "agents: {count: 2, initial_angles_rad: [0.0, 1.5707963267948966],"
      " initial_centre_m: [1, 2], radius_m: 3}\n",
      "inline");
  // (1, 2) + 3 (cos 0, sin 0) = (4, 2);  (1, 2) + 3 (cos pi/2, sin pi/2) = (1, 5)
  const deif::AgentSnapshot a1 = AgentCore(config, 1).Initial();
  const deif::AgentSnapshot a2 = AgentCore(config, 2).Initial();
  CHECK(a1.step == 0);
  CHECK(a1.position_m.x() == Approx(4.0));
  CHECK(a1.position_m.y() == Approx(2.0));
  CHECK(a2.position_m.x() == Approx(1.0));
  CHECK(a2.position_m.y() == Approx(5.0));
  CHECK(a2.angle_rad == Approx(kPi / 2));
}

TEST_CASE("Without a range an agent contributes nothing and only predicts", "[agent_core]") {
  const Config config = deif::ParseConfig(ThreeAgents("voronoi", 1.0), "inline");
  AgentCore agent(config, 1);
  CHECK_FALSE(agent.BeginStep(1, std::nullopt).has_value());
  const deif::AgentSnapshot s = agent.FinishStep(1, {}, InitialPositions(config));
  // Random walk: x(1|0) = x(0) = (0.5, 0), P(1|0) = P0 + q I = (1 + 1.3e-4) I.
  CHECK(s.fused == 0);
  CHECK(s.alive == 3);
  CHECK(s.estimate_m.x() == Approx(0.5));
  CHECK(s.estimate_m.y() == Approx(0.0).margin(1e-15));
  CHECK(s.covariance(0, 0) == Approx(1.00013));
  CHECK(s.covariance(1, 1) == Approx(1.00013));
  CHECK(s.covariance(0, 1) == Approx(0.0).margin(1e-15));
}

TEST_CASE("A range gives the contribution of eqs (4.49)-(4.51) at the prediction",
          "[agent_core]") {
  const Config config = deif::ParseConfig(
      "filter: {initial_estimate_m: [0, 0]}\n"
      "agents: {count: 2, initial_angles_rad: [0, 3.141592653589793], radius_m: 2}\n",
      "inline");
  AgentCore agent(config, 1);  // at (2, 0)
  deif::RangeObservation z;
  z.agent_id = 1;
  z.range_m = 2.1;
  z.variance_m2 = 0.01;
  z.p_sensor = agent.position();
  const auto c = agent.BeginStep(1, z);
  REQUIRE(c.has_value());
  // At x_pred = (0, 0): h = 2, H = (x - p)^T / |x - p| = (-1, 0).
  // I = H^T H / R = [[100, 0], [0, 0]];  i = H^T / R (z - h + H x_pred) = (-10, 0).
  CHECK(c->agent_id == 1);
  CHECK(c->step == 1);
  CHECK(c->info_matrix(0, 0) == Approx(100.0));
  CHECK(c->info_matrix(0, 1) == Approx(0.0).margin(1e-12));
  CHECK(c->info_matrix(1, 1) == Approx(0.0).margin(1e-12));
  CHECK(c->info_vector(0) == Approx(-10.0));
  CHECK(c->info_vector(1) == Approx(0.0).margin(1e-12));
}

TEST_CASE("Law 1 steers to the midpoint of the neighbours' angles about the estimate",
          "[agent_core]") {
  const Config config = deif::ParseConfig(ThreeAgents("midpoint", 1000.0), "inline");
  AgentCore agent(config, 2);
  agent.BeginStep(1, std::nullopt);
  const deif::AgentSnapshot s = agent.FinishStep(1, {}, InitialPositions(config));
  // About the estimate (0.5, 0) the neighbours are at (2, 0) -> angle 0 and (-2, 0) -> pi.
  // eq (3.2) with s = 2 pi / 3: ((0 + s) + (pi - s)) / 2 = pi / 2, so the goal is
  // (0.5, 0) + 2 (cos pi/2, sin pi/2) = (0.5, 2), reached at this speed.
  CHECK(s.position_m.x() == Approx(0.5));
  CHECK(s.position_m.y() == Approx(2.0));
  CHECK(s.angle_rad == Approx(kPi / 2));
}

TEST_CASE("Law 2 steers by a quarter of the gap difference (eq 3.6)", "[agent_core]") {
  const Config config = deif::ParseConfig(
      "filter: {initial_estimate_m: [0, 0]}\n"
      "agents: {count: 3, initial_angles_rad: [0.0, 0.5, 3.141592653589793], radius_m: 2,"
      " max_speed_mps: 1000, control_law: voronoi}\n",
      "inline");
  AgentCore agent(config, 2);
  agent.BeginStep(1, std::nullopt);
  const deif::AgentSnapshot s = agent.FinishStep(1, {}, InitialPositions(config));
  // phi' = phi + ((phi3 - phi - s) - (phi - phi1 - s)) / 4 = 0.5 + (pi - 1) / 4.
  const double expected = 0.5 + (kPi - 1.0) / 4.0;
  CHECK(s.angle_rad == Approx(expected));
  CHECK(s.position_m.x() == Approx(2.0 * std::cos(expected)));
  CHECK(s.position_m.y() == Approx(2.0 * std::sin(expected)));
}

TEST_CASE("An agent moves at most max_speed * dt per step", "[agent_core]") {
  const Config config = deif::ParseConfig(ThreeAgents("midpoint", 0.5), "inline");
  AgentCore agent(config, 2);
  const Vector2 start = agent.position();
  agent.BeginStep(1, std::nullopt);
  const deif::AgentSnapshot s = agent.FinishStep(1, {}, InitialPositions(config));
  // The goal (0.5, 2) is about 1.1 m away; one step covers 0.5 m/s * 0.1 s = 0.05 m of it.
  const Vector2 goal(0.5, 2.0);
  CHECK((s.position_m - start).norm() == Approx(0.05));
  const Vector2 expected = start + 0.05 * (goal - start).normalized();
  CHECK((s.position_m - expected).norm() == Approx(0.0).margin(1e-12));
}

TEST_CASE("The stationary law never moves the agent", "[agent_core]") {
  const Config config = deif::ParseConfig(ThreeAgents("stationary", 1.0), "inline");
  AgentCore agent(config, 2);
  const Vector2 start = agent.position();
  for (deif::StepIndex k = 1; k <= 5; ++k) {
    agent.BeginStep(k, std::nullopt);
    const deif::AgentSnapshot s = agent.FinishStep(k, {}, InitialPositions(config));
    CHECK(s.position_m == start);
    // Its angle is reported about the estimate (0.5, 0).
    CHECK(s.angle_rad == Approx(std::atan2(start.y(), start.x() - 0.5)));
  }
}

TEST_CASE("Agents that fuse the same contributions hold bit-identical estimates",
          "[agent_core]") {
  const Config config = deif::ParseConfig("agents: {count: 3}\n", "inline");
  std::vector<AgentCore> agents;
  for (AgentId id = 1; id <= 3; ++id) agents.emplace_back(config, id);
  const Vector2 p_true(0.3, -0.2);
  std::vector<deif::Contribution> contributions;
  for (AgentCore& a : agents) {
    deif::RangeObservation z;
    z.agent_id = a.id();
    z.range_m = (p_true - a.position()).norm();
    z.variance_m2 = config.filter.range_variance_m2;
    z.p_sensor = a.position();
    contributions.push_back(*a.BeginStep(1, z));
  }
  const auto positions = InitialPositions(config);
  // Each fuses the contributions in a different arrival order.
  std::vector<deif::Contribution> reversed(contributions.rbegin(), contributions.rend());
  const deif::AgentSnapshot s1 = agents[0].FinishStep(1, contributions, positions);
  const deif::AgentSnapshot s2 = agents[1].FinishStep(1, reversed, positions);
  const deif::AgentSnapshot s3 = agents[2].FinishStep(1, contributions, positions);
  CHECK(s1.fused == 3);
  CHECK(s1.estimate_m == s2.estimate_m);
  CHECK(s1.estimate_m == s3.estimate_m);
  CHECK(s1.covariance == s2.covariance);
  // Three noiseless ranges from a good geometry pull the estimate toward the truth.
  CHECK((s1.estimate_m - p_true).norm() < (Vector2(0, 0) - p_true).norm());
}

TEST_CASE("An agent that rejoins adopts a peer's estimate and covariance", "[agent_core]") {
  // GIVEN an agent whose filter has only predicted for many steps (stale, uncertain)
  const deif::Config config = deif::ParseConfig("agents: {count: 3}\n", "inline");
  deif::AgentCore core(config, 2);
  for (deif::StepIndex k = 1; k <= 50; ++k) core.BeginStep(k, std::nullopt);
  // WHEN it adopts a peer's published estimate of the last step
  const deif::Vector2 estimate(0.31, -0.72);
  deif::Matrix2 covariance;
  covariance << 4e-4, 1e-5, 1e-5, 3e-4;
  core.AdoptEstimate(estimate, covariance);
  // THEN its filter holds exactly that estimate and (to rounding of Y = P^-1) that covariance
  const deif::Vector2 adopted = core.node().filter().PositionEstimate();
  CHECK(adopted.x() == Approx(0.31).margin(1e-12));
  CHECK(adopted.y() == Approx(-0.72).margin(1e-12));
  const deif::Matrix2 P = core.node().filter().PositionCovariance();
  CHECK(P(0, 0) == Approx(4e-4).epsilon(1e-9));
  CHECK(P(0, 1) == Approx(1e-5).epsilon(1e-9));
  CHECK(P(1, 1) == Approx(3e-4).epsilon(1e-9));
}
