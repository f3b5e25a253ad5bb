#include "common/protocol/motion.hpp"

#include <cmath>
#include <vector>

namespace deif {

double AngleAbout(const Vector2& centre, const Vector2& p) {
  const Vector2 d = p - centre;
  return std::atan2(d.y(), d.x());
}

MotionResult MoveOnRing(const Config& config, AgentId self, const Vector2& p_estimate,
                        const Vector2& own_position,
                        const std::map<AgentId, Vector2>& member_positions, bool alone) {
  std::vector<RingMember> ring;
  ring.reserve(member_positions.size() + 1);
  for (const auto& [member_id, p_member] : member_positions) {
    ring.push_back({member_id, AngleAbout(p_estimate, member_id == self ? own_position : p_member)});
  }
  if (member_positions.find(self) == member_positions.end()) {
    ring.push_back({self, AngleAbout(p_estimate, own_position)});
  }
  MotionResult result;
  result.position_m = own_position;
  if (config.agents.control_law != ControlLawKind::kStationary) {
    // eq (3.2) / (3.6): the next angle; the goal lies on the circle about the estimate.
    double next_angle_rad = NextAngle(config.agents.control_law, self, ring);
    if (alone && ring.size() == 1) {
      // A lone agent (every other member lost): one range fixes only the distance to the
      // target (the FIM of one sensor is singular: det J = 0 in eq (2.6)), and the laws leave
      // it where it is. It circles the estimate instead, covering the arc of one step at
      // full speed, so that its ranges come from changing bearings (docs/ARCHITECTURE.md,
      // "A lone agent").
      next_angle_rad += config.agents.max_speed_mps * config.scenario.dt_s / config.agents.radius_m;
    }
    const Vector2 p_goal = PointOnCircle(p_estimate, config.agents.radius_m, next_angle_rad);
    result.position_m = MoveToward(own_position, p_goal,
                                   config.agents.max_speed_mps * config.scenario.dt_s);
  }
  result.angle_rad = AngleAbout(p_estimate, result.position_m);
  result.ring_size = static_cast<int>(ring.size());
  return result;
}

}  // namespace deif
