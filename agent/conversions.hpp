// The one place where the agent converts between the wire types (deif.idl) and the core's
// Eigen types. Pure field copies: no arithmetic, so transport never changes a value.
#pragma once

#include <cstdint>

#include "common/protocol/agent_core.hpp"
#include "common/core/filters.hpp"
#include "deif.h"

namespace deif::agent {

inline Contribution ToContribution(const deif_msgs::Contribution& msg) {
  Contribution c;
  c.agent_id = msg.agent_id();
  c.step = msg.step();
  c.info_vector = InfoVector(msg.info_x(), msg.info_y());  // i_j
  c.info_matrix << msg.info_xx(), msg.info_xy(),            // I_j, all four entries
      msg.info_yx(), msg.info_yy();
  return c;
}

inline deif_msgs::Contribution ToIdl(const Contribution& c) {
  deif_msgs::Contribution msg;
  msg.agent_id(c.agent_id);
  msg.step(c.step);
  msg.info_x(c.info_vector(0));
  msg.info_y(c.info_vector(1));
  msg.info_xx(c.info_matrix(0, 0));
  msg.info_xy(c.info_matrix(0, 1));
  msg.info_yx(c.info_matrix(1, 0));
  msg.info_yy(c.info_matrix(1, 1));
  return msg;
}

inline RangeObservation ToRangeObservation(const deif_msgs::Range& msg) {
  RangeObservation z;
  z.agent_id = msg.agent_id();
  z.range_m = msg.range_m();
  z.variance_m2 = msg.variance_m2();
  z.p_sensor = Vector2(msg.sensor_x_m(), msg.sensor_y_m());
  return z;
}

inline Vector2 ToEigenPosition(const deif_msgs::AgentState& msg) {
  return Vector2(msg.pos_x_m(), msg.pos_y_m());
}

inline Vector2 ToEigenEstimate(const deif_msgs::AgentState& msg) {
  return Vector2(msg.est_x_m(), msg.est_y_m());
}

inline Matrix2 ToEigenCovariance(const deif_msgs::AgentState& msg) {
  Matrix2 P;
  P << msg.cov_xx(), msg.cov_xy(), msg.cov_xy(), msg.cov_yy();
  return P;
}

inline deif_msgs::AgentState ToIdl(const AgentSnapshot& s, AgentId id,
                                   std::uint64_t instance_token) {
  deif_msgs::AgentState msg;
  msg.agent_id(id);
  msg.step(s.step);
  msg.pos_x_m(s.position_m.x());
  msg.pos_y_m(s.position_m.y());
  msg.angle_rad(s.angle_rad);
  msg.est_x_m(s.estimate_m.x());
  msg.est_y_m(s.estimate_m.y());
  msg.cov_xx(s.covariance(0, 0));
  msg.cov_xy(s.covariance(0, 1));
  msg.cov_yy(s.covariance(1, 1));
  msg.alive(s.alive);
  msg.fused(s.fused);
  msg.instance_token(instance_token);
  return msg;
}

}  // namespace deif::agent
