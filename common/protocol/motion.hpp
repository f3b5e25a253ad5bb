// One agent's control-law step (chapter 3), free of transport and of the filter.
#pragma once

#include <map>

#include "common/config/config.hpp"
#include "common/core/control_law.hpp"

namespace deif {

struct MotionResult {
  Vector2 position_m = Vector2::Zero();  // the new position
  double angle_rad = 0.0;                // its angle about the estimate, in (-pi, pi]
  int ring_size = 0;                     // members of the ring, this agent included
};

// The angle of a position about a centre, as atan2 gives it: (-pi, pi].
double AngleAbout(const Vector2& centre, const Vector2& p);

// The ring of member_positions (each member's position at step k-1, the one its range of
// step k was measured from; this agent's own entry is own_position when missing), as angles
// about this agent's fused estimate p_estimate; the control law of config.agents (eq 3.2 or
// 3.6) picks the next angle; the agent moves toward the point at that angle on the circle of
// agents.radius_m about the estimate, at most max_speed_mps * dt_s. An agent `alone` (no
// other member left) whose ring is itself stands still instead (docs/ARCHITECTURE.md, "A
// lone agent").
MotionResult MoveOnRing(const Config& config, AgentId self, const Vector2& p_estimate,
                        const Vector2& own_position,
                        const std::map<AgentId, Vector2>& member_positions, bool alone = false);

}  // namespace deif
