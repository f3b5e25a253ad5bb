#include "common/core/control_law.hpp"

#include "common/core/fisher.hpp"

#include <algorithm>
#include <cmath>
#include <stdexcept>

namespace deif {
namespace {


// The desired gap s_i for each gap of a ring (gap i runs from ring[i] to ring[i+1]).
std::vector<double> DesiredGaps(const std::vector<RingMember>& ring,
                                const std::vector<double>& gaps) {
  const std::size_t n = ring.size();
  const double optimal = OptimalGapRad(static_cast<int>(n));  // section 2.3.1.4
  if (n >= 3) {
    return std::vector<double>(n, optimal);  // Proposition 1: 2 pi / N
  }
  if (n == 2) {
    // Section 2.3.1.4: for two sensors the optimum is a right angle, so the smaller gap
    // aims for pi/2 and the larger for 3 pi/2. On a tie (both pi) the gap that starts at
    // the lower id, going counter-clockwise, aims for pi/2.
    bool first_is_small = gaps[0] < gaps[1];
    if (gaps[0] == gaps[1]) {
      first_is_small = ring[0].agent_id < ring[1].agent_id;
    }
    return first_is_small ? std::vector<double>{optimal, kTwoPi - optimal}
                          : std::vector<double>{kTwoPi - optimal, optimal};
  }
  return std::vector<double>(n, kTwoPi);
}

}  // namespace

double WrapTwoPi(double angle_rad) {
  double wrapped = std::fmod(angle_rad, kTwoPi);
  if (wrapped < 0.0) {
    wrapped += kTwoPi;
  }
  // -tiny + 2 pi rounds to 2 pi.
  return wrapped >= kTwoPi ? 0.0 : wrapped;
}

double WrapPi(double angle_rad) {
  const double wrapped = WrapTwoPi(angle_rad);
  return wrapped > kPi ? wrapped - kTwoPi : wrapped;
}

std::vector<RingMember> FormRing(std::vector<RingMember> members) {
  for (RingMember& m : members) {
    m.angle_rad = WrapTwoPi(m.angle_rad);
  }
  std::sort(members.begin(), members.end(), [](const RingMember& a, const RingMember& b) {
    return a.angle_rad != b.angle_rad ? a.angle_rad < b.angle_rad : a.agent_id < b.agent_id;
  });
  return members;
}

std::vector<double> RingGaps(const std::vector<RingMember>& ring) {
  const std::size_t n = ring.size();
  std::vector<double> gaps(n);
  for (std::size_t i = 0; i + 1 < n; ++i) {
    gaps[i] = WrapTwoPi(ring[i + 1].angle_rad) - WrapTwoPi(ring[i].angle_rad);
  }
  if (n > 0) {
    // The closing gap, from the last member back round to the first.
    gaps[n - 1] = WrapTwoPi(ring[0].angle_rad) + kTwoPi - WrapTwoPi(ring[n - 1].angle_rad);
  }
  return gaps;
}

double NextAngle(ControlLawKind law, AgentId self_id, const std::vector<RingMember>& members) {
  const std::vector<RingMember> ring = FormRing(members);
  const auto self_it = std::find_if(ring.begin(), ring.end(), [self_id](const RingMember& m) {
    return m.agent_id == self_id;
  });
  if (self_it == ring.end()) {
    throw std::invalid_argument("NextAngle: agent " + std::to_string(self_id) +
                                " is not among the ring members");
  }
  const std::size_t n = ring.size();
  const std::size_t i = static_cast<std::size_t>(self_it - ring.begin());
  const double phi_self = ring[i].angle_rad;
  if (law == ControlLawKind::kStationary || n < 2) {
    return phi_self;
  }

  const std::vector<double> gaps = RingGaps(ring);
  const std::vector<double> desired = DesiredGaps(ring, gaps);
  const std::size_t i_prev_gap = (i + n - 1) % n;  // the gap from the predecessor to self
  const std::size_t i_next_gap = i;                // the gap from self to the successor
  // Unwrapped so that phi_prev <= phi_self <= phi_next (for n = 2 both are the other agent).
  const double phi_prev = phi_self - gaps[i_prev_gap];
  const double phi_next = phi_self + gaps[i_next_gap];
  const double s_prev = desired[i_prev_gap];
  const double s_next = desired[i_next_gap];

  double next = phi_self;
  if (law == ControlLawKind::kMidpoint) {
    // eq (3.2) with a general spacing: phi_i' = ((phi_{i-1} + s) + (phi_{i+1} - s')) / 2
    next = 0.5 * ((phi_prev + s_prev) + (phi_next - s_next));
  } else {
    // eq (3.6) with a general spacing; for equal s it is (phi_{i-1} + 2 phi_i + phi_{i+1}) / 4.
    next = phi_self + 0.25 * ((phi_next - phi_self - s_next) - (phi_self - phi_prev - s_prev));
  }
  return WrapTwoPi(next);
}

Vector2 PointOnCircle(const Vector2& centre, double radius_m, double angle_rad) {
  return centre + radius_m * Vector2(std::cos(angle_rad), std::sin(angle_rad));
}

Vector2 MoveToward(const Vector2& p_from, const Vector2& p_goal, double max_step_m) {
  const Vector2 d = p_goal - p_from;
  const double distance_m = d.norm();
  if (distance_m <= max_step_m) {
    return p_goal;
  }
  if (max_step_m <= 0.0) {
    return p_from;
  }
  return p_from + d * (max_step_m / distance_m);
}

double MaxGapError(const std::vector<RingMember>& members) {
  const std::size_t n = members.size();
  if (n < 2) {
    return 0.0;
  }
  const std::vector<double> gaps = RingGaps(FormRing(members));
  const double optimal = OptimalGapRad(static_cast<int>(n));
  if (n == 2) {
    return std::abs(std::min(gaps[0], gaps[1]) - optimal);
  }
  double worst = 0.0;
  for (const double gap : gaps) {
    worst = std::max(worst, std::abs(gap - optimal));
  }
  return worst;
}

}  // namespace deif
