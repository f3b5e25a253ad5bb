// The one place where the target converts between the wire types (deif.idl) and the core's
// Eigen types. Pure field copies.
#pragma once

#include "common/artefacts/artefacts.hpp"
#include "common/core/types.hpp"
#include "deif.h"

namespace deif::target {

inline deif_msgs::Truth ToIdl(const TargetRow& row) {
  deif_msgs::Truth msg;
  msg.step(row.step);
  msg.t_s(row.t_s);
  msg.x_m(row.p_true.x());
  msg.y_m(row.p_true.y());
  return msg;
}

inline deif_msgs::Range ToIdl(const RangeRow& row) {
  deif_msgs::Range msg;
  msg.agent_id(row.agent_id);
  msg.step(row.step);
  msg.range_m(row.range_m);
  msg.variance_m2(row.variance_m2);
  msg.sensor_x_m(row.p_sensor.x());
  msg.sensor_y_m(row.p_sensor.y());
  return msg;
}

inline Vector2 ToEigenPosition(const deif_msgs::AgentState& msg) {
  return Vector2(msg.pos_x_m(), msg.pos_y_m());
}

}  // namespace deif::target
