#include <catch2/catch.hpp>

#include <algorithm>
#include <cmath>
#include <vector>

#include <Eigen/Eigenvalues>

#include "common/core/control_law.hpp"

namespace deif {
namespace {

using deif::kPi;
using deif::kTwoPi;

// Every agent applies the law to the same snapshot (synchronous update, eq 3.10).
std::vector<RingMember> SynchronousStep(ControlLawKind law,
                                        const std::vector<RingMember>& members) {
  std::vector<RingMember> next = members;
  for (RingMember& m : next) {
    m.angle_rad = NextAngle(law, m.agent_id, members);
  }
  return next;
}

std::vector<RingMember> Members(const std::vector<double>& angles_rad) {
  std::vector<RingMember> members;
  for (std::size_t j = 0; j < angles_rad.size(); ++j) {
    members.push_back({static_cast<AgentId>(j), angles_rad[j]});
  }
  return members;
}

// The largest angular distance between the same agents in two snapshots (same order).
double LargestMove(const std::vector<RingMember>& a, const std::vector<RingMember>& b) {
  double largest = 0.0;
  for (std::size_t j = 0; j < a.size(); ++j) {
    REQUIRE(a[j].agent_id == b[j].agent_id);
    largest = std::max(largest, std::abs(WrapPi(a[j].angle_rad - b[j].angle_rad)));
  }
  return largest;
}

// eq (3.11): 1/2 on the two cyclic off-diagonals.
Eigen::MatrixXd B1(int n) {
  Eigen::MatrixXd B = Eigen::MatrixXd::Zero(n, n);
  for (int i = 0; i < n; ++i) {
    B(i, (i + 1) % n) += 0.5;
    B(i, (i + n - 1) % n) += 0.5;
  }
  return B;
}

const std::vector<double> kThesisAngles = {2.1818, 2.4500, 3.7160, 4.5167};  // Table 5.x

TEST_CASE("WrapTwoPi maps into [0, 2 pi) and WrapPi into (-pi, pi]", "[control]") {
  CHECK(WrapTwoPi(-0.5) == Approx(kTwoPi - 0.5));
  CHECK(WrapTwoPi(7.0) == Approx(7.0 - kTwoPi));
  CHECK(WrapTwoPi(kTwoPi) == 0.0);
  CHECK(WrapTwoPi(-1e-18) < kTwoPi);
  CHECK(WrapPi(kPi) == Approx(kPi));
  CHECK(WrapPi(-kPi) == Approx(kPi));
  CHECK(WrapPi(3.5) == Approx(3.5 - kTwoPi));
  CHECK(WrapPi(-0.25) == Approx(-0.25));
}

TEST_CASE("FormRing orders by wrapped angle then id, and the gaps sum to 2 pi", "[control]") {
  const auto ring = FormRing({{5, 1.0}, {2, -0.5}, {9, 1.0}, {1, 7.0}});
  // wrapped: 5 -> 1.0, 2 -> 5.783, 9 -> 1.0, 1 -> 0.717
  REQUIRE(ring.size() == 4);
  CHECK(ring[0].agent_id == 1);
  CHECK(ring[1].agent_id == 5);
  CHECK(ring[2].agent_id == 9);
  CHECK(ring[3].agent_id == 2);
  const auto gaps = RingGaps(ring);
  CHECK(gaps[1] == 0.0);  // the tie
  double total = 0.0;
  for (const double g : gaps) {
    CHECK(g >= 0.0);
    total += g;
  }
  CHECK(total == Approx(kTwoPi));
  CHECK(RingGaps({{4, 1.0}}) == std::vector<double>{kTwoPi});
}

TEST_CASE("B1 of eq (3.11) has the eigenvalues cos(2 pi k / N) of eq (3.13)", "[control]") {
  for (int n = 3; n <= 8; ++n) {
    Eigen::SelfAdjointEigenSolver<Eigen::MatrixXd> solver(B1(n));
    std::vector<double> computed(solver.eigenvalues().data(),
                                 solver.eigenvalues().data() + n);
    std::vector<double> expected;
    for (int k = 1; k <= n; ++k) {
      expected.push_back(std::cos(kTwoPi * static_cast<double>(k) / static_cast<double>(n)));
    }
    std::sort(computed.begin(), computed.end());
    std::sort(expected.begin(), expected.end());
    for (std::size_t k = 0; k < expected.size(); ++k) {
      CAPTURE(n, k);
      CHECK(computed[k] == Approx(expected[k]).margin(1e-12));
    }
  }
}

// The gap from agent i to its counter-clockwise successor, indexed by agent id (0..n-1).
std::vector<double> GapsByAgent(const std::vector<RingMember>& members) {
  const auto ring = FormRing(members);
  const auto gaps = RingGaps(ring);
  std::vector<double> by_agent(members.size());
  for (std::size_t r = 0; r < ring.size(); ++r) {
    by_agent[static_cast<std::size_t>(ring[r].agent_id)] = gaps[r];
  }
  return by_agent;
}

TEST_CASE("Law 1 moves the gaps by B1 (eqs 3.10-3.11)", "[control]") {
  // agent 0 wraps below 0 in the step, so the ring is re-indexed by id, not by position
  const auto members = Members({0.3, 1.1, 1.9, 3.5, 5.0});
  const std::vector<double> gaps = GapsByAgent(members);
  const std::vector<double> next_gaps =
      GapsByAgent(SynchronousStep(ControlLawKind::kMidpoint, members));
  const Eigen::VectorXd expected =
      B1(5) * Eigen::Map<const Eigen::VectorXd>(gaps.data(), 5);
  for (int i = 0; i < 5; ++i) {
    CHECK(next_gaps[static_cast<std::size_t>(i)] == Approx(expected(i)).margin(1e-12));
  }
}

TEST_CASE("Law 1 oscillates with period two for even N (eq 3.17)", "[control]") {
  for (const int n : {4, 6, 8}) {
    // GIVEN an uneven ring
    std::vector<double> angles;
    for (int k = 0; k < n; ++k) {
      const double kd = static_cast<double>(k);
      angles.push_back(kTwoPi * kd / static_cast<double>(n) + 0.25 * std::sin(1.7 * kd + 0.4));
    }
    auto members = Members(angles);
    // WHEN law 1 runs long enough for the |mu| < 1 modes to die out (|mu| <= cos(pi/4))
    for (int k = 0; k < 300; ++k) {
      members = SynchronousStep(ControlLawKind::kMidpoint, members);
    }
    const auto step_k1 = SynchronousStep(ControlLawKind::kMidpoint, members);
    const auto step_k2 = SynchronousStep(ControlLawKind::kMidpoint, step_k1);
    // THEN the configuration returns every second step but differs in between (mu = -1)
    CAPTURE(n);
    CHECK(LargestMove(members, step_k2) < 1e-9);
    CHECK(LargestMove(members, step_k1) > 1e-3);
    CHECK(MaxGapError(members) > 1e-3);
  }
}

TEST_CASE("Law 1 converges to equal gaps for odd N (eq 3.13)", "[control]") {
  auto members = Members({0.1, 0.4, 2.0, 2.2, 4.0});
  for (int k = 0; k < 300; ++k) {
    members = SynchronousStep(ControlLawKind::kMidpoint, members);
  }
  CHECK(MaxGapError(members) < 1e-9);
}

TEST_CASE("Law 2 converges to equal gaps from the thesis's initial angles", "[control]") {
  auto members = Members(kThesisAngles);
  REQUIRE(MaxGapError(members) > 0.5);
  for (int k = 0; k < 100; ++k) {
    members = SynchronousStep(ControlLawKind::kVoronoi, members);
  }
  for (const double gap : RingGaps(FormRing(members))) {
    CHECK(gap == Approx(kPi / 2.0).margin(1e-6));
  }
  CHECK(MaxGapError(members) < 1e-6);
}

TEST_CASE("Law 2 brings two agents to a right angle", "[control]") {
  auto members = Members({0.2, 3.0});
  for (int k = 0; k < 50; ++k) {
    members = SynchronousStep(ControlLawKind::kVoronoi, members);
  }
  const auto gaps = RingGaps(FormRing(members));
  CHECK(std::min(gaps[0], gaps[1]) == Approx(kPi / 2.0).margin(1e-9));
  CHECK(MaxGapError(members) < 1e-9);
}

TEST_CASE("Two coincident agents are separated, ties broken by id", "[control]") {
  const auto members = std::vector<RingMember>{{3, 1.0}, {8, 1.0}};
  // The gaps are 0 (3 -> 8) and 2 pi (8 -> 3): the 0 gap aims at pi/2, the other at 3pi/2.
  const auto gaps = RingGaps(FormRing(members));
  CHECK(gaps[0] == 0.0);
  CHECK(gaps[1] == Approx(kTwoPi));
  // law 2 for agent 3: phi + ((0 - pi/2) - (2pi - 3pi/2)) / 4 = 1 - pi/4
  CHECK(NextAngle(ControlLawKind::kVoronoi, 3, members) == Approx(1.0 - kPi / 4.0));
  // for agent 8: phi + ((2pi - 3pi/2) - (0 - pi/2)) / 4 = 1 + pi/4
  CHECK(NextAngle(ControlLawKind::kVoronoi, 8, members) == Approx(1.0 + kPi / 4.0));
}

TEST_CASE("Law 2 re-forms a three-agent ring after a member of a four-ring leaves",
          "[control]") {
  auto members = Members(kThesisAngles);
  for (int k = 0; k < 100; ++k) {
    members = SynchronousStep(ControlLawKind::kVoronoi, members);
  }
  REQUIRE(MaxGapError(members) < 1e-6);
  // WHEN agent 2 drops out
  members.erase(members.begin() + 2);
  REQUIRE(MaxGapError(members) > 0.5);  // gaps pi/2, pi, pi/2
  for (int k = 0; k < 200; ++k) {
    members = SynchronousStep(ControlLawKind::kVoronoi, members);
  }
  // THEN the survivors spread to 2 pi / 3
  for (const double gap : RingGaps(FormRing(members))) {
    CHECK(gap == Approx(kTwoPi / 3.0).margin(1e-6));
  }
}

TEST_CASE("Stationary law and a lone agent leave the angle unchanged", "[control]") {
  const auto members = Members(kThesisAngles);
  CHECK(NextAngle(ControlLawKind::kStationary, 1, members) == Approx(2.4500));
  CHECK(NextAngle(ControlLawKind::kVoronoi, 0, {{0, 7.0}}) == Approx(7.0 - kTwoPi));
  CHECK_THROWS(NextAngle(ControlLawKind::kVoronoi, 42, members));
}

TEST_CASE("Law 1 and law 2 match eqs (3.2) and (3.6) for one agent", "[control]") {
  // agent 1 between 0.5 and 2.0 in a ring of three (s = 2pi/3 cancels for equal spacing)
  const auto members = Members({0.5, 1.0, 2.0});
  CHECK(NextAngle(ControlLawKind::kMidpoint, 1, members) == Approx((0.5 + 2.0) / 2.0));
  CHECK(NextAngle(ControlLawKind::kVoronoi, 1, members) ==
        Approx((0.5 + 2.0 * 1.0 + 2.0) / 4.0));
  // agent 0 wraps: predecessor 2.0 - 2pi, successor 1.0
  CHECK(NextAngle(ControlLawKind::kMidpoint, 0, members) ==
        Approx(WrapTwoPi((2.0 - kTwoPi + 1.0) / 2.0)));
}

TEST_CASE("MoveToward steps at most max_step along the straight line", "[control]") {
  // from (0,0) to (3,4) (distance 5) by 1: (0.6, 0.8)
  const Vector2 p = MoveToward(Vector2::Zero(), Vector2(3.0, 4.0), 1.0);
  CHECK(p.x() == Approx(0.6));
  CHECK(p.y() == Approx(0.8));
  CHECK(MoveToward(Vector2::Zero(), Vector2(3.0, 4.0), 6.0) == Vector2(3.0, 4.0));
  const Vector2 on_circle = PointOnCircle(Vector2(1.0, 1.0), 2.0, kPi / 2.0);
  CHECK(on_circle.x() == Approx(1.0));
  CHECK(on_circle.y() == Approx(3.0));
}

TEST_CASE("MaxGapError measures the distance from the optimal gaps", "[control]") {
  // gaps of the thesis angles: 0.2682, 1.2660, 0.8007, 3.9483; worst |3.9483 - pi/2| = 2.3775
  CHECK(MaxGapError(Members(kThesisAngles)) == Approx(2.1818 + kTwoPi - 4.5167 - kPi / 2.0));
  // two agents 1 rad apart: |1 - pi/2|
  CHECK(MaxGapError(Members({0.0, 1.0})) == Approx(kPi / 2.0 - 1.0));
  CHECK(MaxGapError(Members({1.0})) == 0.0);
}

}  // namespace
}  // namespace deif
