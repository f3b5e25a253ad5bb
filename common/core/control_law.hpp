// The decentralized motion control laws of chapter 3 on a ring of agents ordered by their
// angle about the estimate.
#pragma once

#include <string>
#include <vector>

#include "common/core/types.hpp"

namespace deif {

enum class ControlLawKind {
  kStationary,  // no motion
  kMidpoint,    // law 1, eq (3.2): theta_i' = (theta_{i-1} + theta_{i+1}) / 2
  kVoronoi,     // law 2, eq (3.6): theta_i' = (theta_{i-1} + 2 theta_i + theta_{i+1}) / 4
};

struct RingMember {
  AgentId agent_id = 0;
  double angle_rad = 0.0;  // the angle of the agent's position about the estimate
};

// Wraps an angle into [0, 2 pi).
double WrapTwoPi(double angle_rad);
// Wraps an angle into (-pi, pi].
double WrapPi(double angle_rad);

// The members sorted counter-clockwise by angle in [0, 2 pi) (ties by id): the ring.
std::vector<RingMember> FormRing(std::vector<RingMember> members);

// The counter-clockwise gaps of a ring: gap[i] = angle of ring[i+1] - angle of ring[i]
// (wrapping), all in [0, 2 pi), summing to 2 pi. For one member, {2 pi}.
std::vector<double> RingGaps(const std::vector<RingMember>& ring);

// The next angle of agent self_id (which must be in members). The laws act on the gaps
// with a desired gap s_i per gap (eqs 3.2 / 3.6 written for a general target spacing):
//   law 1: phi_i' = ((phi_{i-1} + s_{i-1,i}) + (phi_{i+1} - s_{i,i+1})) / 2
//   law 2: phi_i' = phi_i + ((phi_{i+1} - phi_i - s_{i,i+1}) - (phi_i - phi_{i-1} - s_{i-1,i})) / 4
// For n >= 3, s = 2 pi / n and these are exactly eqs (3.2) and (3.6). For n = 2 the two
// gaps are pi/2 (the smaller gap) and 3 pi/2, the optimum of section 2.3.1.4. With one
// member (or stationary) the angle is unchanged.
double NextAngle(ControlLawKind law, AgentId self_id, const std::vector<RingMember>& members);

// The desired position: on the circle of radius_m about the estimate at angle next_angle.
Vector2 PointOnCircle(const Vector2& centre, double radius_m, double angle_rad);

// Move from p_from toward p_goal by at most max_step_m.
Vector2 MoveToward(const Vector2& p_from, const Vector2& p_goal, double max_step_m);

// The largest |gap - optimal gap| of a ring [rad]. For n = 2 the optimum is pi/2 for the
// smaller gap. 0 for fewer than two members.
double MaxGapError(const std::vector<RingMember>& members);

}  // namespace deif
