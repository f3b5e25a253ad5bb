#include "dds/conversions.hpp"

#include <algorithm>

namespace deif::dds {

deif_msgs::Truth ToIdl(const protocol::TruthMsg& m) {
  deif_msgs::Truth out;
  out.run_token(m.run);
  out.step(m.step);
  out.t_s(m.t_s);
  out.x_m(m.p_true.x());
  out.y_m(m.p_true.y());
  return out;
}

protocol::TruthMsg FromIdl(const deif_msgs::Truth& m) {
  protocol::TruthMsg out;
  out.run = m.run_token();
  out.step = m.step();
  out.t_s = m.t_s();
  out.p_true = Vector2(m.x_m(), m.y_m());
  return out;
}

deif_msgs::Range ToIdl(const protocol::RangeMsg& m) {
  deif_msgs::Range out;
  out.agent_id(m.agent_id);
  out.run_token(m.run);
  out.step(m.step);
  out.t_s(m.t_s);
  out.measured(m.measured);
  out.range_m(m.range_m);
  out.variance_m2(m.variance_m2);
  out.sensor_x_m(m.p_sensor.x());
  out.sensor_y_m(m.p_sensor.y());
  out.roll_call(std::vector<int32_t>(m.roll_call.begin(), m.roll_call.end()));
  return out;
}

protocol::RangeMsg FromIdl(const deif_msgs::Range& m) {
  protocol::RangeMsg out;
  out.agent_id = m.agent_id();
  out.run = m.run_token();
  out.step = m.step();
  out.t_s = m.t_s();
  out.measured = m.measured();
  out.range_m = m.range_m();
  out.variance_m2 = m.variance_m2();
  out.p_sensor = Vector2(m.sensor_x_m(), m.sensor_y_m());
  out.roll_call.assign(m.roll_call().begin(), m.roll_call().end());
  return out;
}

deif_msgs::Contribution ToIdl(const protocol::ContributionMsg& m) {
  deif_msgs::Contribution out;
  out.agent_id(m.agent_id);
  out.run_token(m.run);
  out.instance_token(m.instance_token);
  out.step(m.step);
  out.info_x(m.info_vector(0));
  out.info_y(m.info_vector(1));
  out.info_xx(m.info_matrix(0, 0));
  out.info_xy(m.info_matrix(0, 1));
  out.info_yx(m.info_matrix(1, 0));
  out.info_yy(m.info_matrix(1, 1));
  out.sensor_x_m(m.p_sensor.x());
  out.sensor_y_m(m.p_sensor.y());
  out.merge_request(m.merge_request);
  const auto dim = static_cast<int>(m.basis.y.size());
  out.basis_dim(dim);
  std::array<double, 4> y{};
  std::array<double, 16> Y{};
  for (int i = 0; i < dim && i < 4; ++i) {
    y[static_cast<std::size_t>(i)] = m.basis.y(i);
    for (int j = 0; j < dim && j < 4; ++j) {
      Y[static_cast<std::size_t>(i * dim + j)] = m.basis.Y(i, j);
    }
  }
  out.basis_vector(y);
  out.basis_matrix(Y);
  return out;
}

protocol::ContributionMsg FromIdl(const deif_msgs::Contribution& m) {
  protocol::ContributionMsg out;
  out.agent_id = m.agent_id();
  out.run = m.run_token();
  out.instance_token = m.instance_token();
  out.step = m.step();
  out.info_vector = InfoVector(m.info_x(), m.info_y());
  out.info_matrix << m.info_xx(), m.info_xy(), m.info_yx(), m.info_yy();
  out.p_sensor = Vector2(m.sensor_x_m(), m.sensor_y_m());
  out.merge_request = m.merge_request();
  const int dim = m.basis_dim();
  if (dim == 2 || dim == 4) {
    out.basis.y.resize(dim);
    out.basis.Y.resize(dim, dim);
    for (int i = 0; i < dim; ++i) {
      out.basis.y(i) = m.basis_vector()[static_cast<std::size_t>(i)];
      for (int j = 0; j < dim; ++j) {
        out.basis.Y(i, j) = m.basis_matrix()[static_cast<std::size_t>(i * dim + j)];
      }
    }
  }
  return out;
}

deif_msgs::AgentState ToIdl(const protocol::StateMsg& m) {
  deif_msgs::AgentState out;
  out.agent_id(m.agent_id);
  out.run_token(m.run);
  out.instance_token(m.instance_token);
  out.step(m.step);
  out.pos_x_m(m.position_m.x());
  out.pos_y_m(m.position_m.y());
  out.angle_rad(m.angle_rad);
  out.est_x_m(m.estimate_m.x());
  out.est_y_m(m.estimate_m.y());
  out.cov_xx(m.covariance(0, 0));
  out.cov_xy(m.covariance(0, 1));
  out.cov_yy(m.covariance(1, 1));
  out.alive(m.alive);
  out.fused(m.fused);
  out.complete(m.complete);
  out.deadline_misses(m.deadline_misses);
  out.rejected(m.rejected);
  out.dropped(m.dropped);
  out.matched(m.matched);
  return out;
}

protocol::StateMsg FromIdl(const deif_msgs::AgentState& m) {
  protocol::StateMsg out;
  out.agent_id = m.agent_id();
  out.run = m.run_token();
  out.instance_token = m.instance_token();
  out.step = m.step();
  out.position_m = Vector2(m.pos_x_m(), m.pos_y_m());
  out.angle_rad = m.angle_rad();
  out.estimate_m = Vector2(m.est_x_m(), m.est_y_m());
  out.covariance << m.cov_xx(), m.cov_xy(), m.cov_xy(), m.cov_yy();
  out.alive = m.alive();
  out.fused = m.fused();
  out.complete = m.complete();
  out.deadline_misses = m.deadline_misses();
  out.rejected = m.rejected();
  out.dropped = m.dropped();
  out.matched = m.matched();
  return out;
}

deif_msgs::ContributionBatch ToIdl(const protocol::BatchMsg& m) {
  deif_msgs::ContributionBatch out;
  out.agent_id(m.sender_id);
  out.run_token(m.run);
  out.step(m.step);
  out.items().reserve(m.items.size());
  for (const protocol::RelayedContribution& item : m.items) {
    deif_msgs::RelayedContribution r;
    std::copy(item.origin.begin(), item.origin.end(), r.origin_writer().begin());
    r.content(ToIdl(item.msg));
    out.items().push_back(std::move(r));
  }
  return out;
}

protocol::BatchMsg FromIdl(const deif_msgs::ContributionBatch& m, bool down) {
  protocol::BatchMsg out;
  out.sender_id = m.agent_id();
  out.run = m.run_token();
  out.step = m.step();
  out.down = down;
  out.items.reserve(m.items().size());
  for (const deif_msgs::RelayedContribution& r : m.items()) {
    protocol::RelayedContribution item;
    std::copy(r.origin_writer().begin(), r.origin_writer().end(), item.origin.begin());
    item.msg = FromIdl(r.content());
    out.items.push_back(std::move(item));
  }
  return out;
}

}  // namespace deif::dds
