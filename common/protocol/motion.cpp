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
  // A lone agent (every other member lost) stands still. One range fixes only the distance
  // to the target (one sensor's FIM is singular: det J = 0 in eq (2.6)), so its estimate can
  // slide along that circle to the mirror side of the sensor; a sensor that keeps its place
  // on the ring about that estimate follows it away, and one that circles it carries the
  // error into the ring it rejoins (docs/ARCHITECTURE.md, "A lone agent").
  const bool still = alone && ring.size() == 1;
  if (config.agents.control_law != ControlLawKind::kStationary && !still) {
    // eq (3.2) / (3.6): the next angle; the goal lies on the circle about the estimate.
    const double next_angle_rad = NextAngle(config.agents.control_law, self, ring);
    const Vector2 p_goal = PointOnCircle(p_estimate, config.agents.radius_m, next_angle_rad);
    result.position_m = MoveToward(own_position, p_goal,
                                   config.agents.max_speed_mps * config.scenario.dt_s);
  }
  result.angle_rad = AngleAbout(p_estimate, result.position_m);
  result.ring_size = static_cast<int>(ring.size());
  return result;
}

}  // namespace deif
