// Replays the centralized EIF over a run's ranges.csv: the reference every DEIF agent of
// a full-communication run must equal.
#pragma once

#include <string>
#include <vector>

#include "common/config/config.hpp"

namespace deif {

struct ReplayRow {
  StepIndex step = 0;
  Vector2 estimate_m = Vector2::Zero();
  Matrix2 covariance = Matrix2::Zero();
  int ranges = 0;  // ranges processed at this step
};

// Read ranges.csv (header step,agent_id,range,variance,sensor_x,sensor_y) and run one
// CentralizedEif over it, steps 1..last (a step with no range only predicts). Ranges of a
// step are processed in ascending agent id. Throws std::runtime_error naming the file and
// line on a malformed row.
std::vector<ReplayRow> ReplayCentralized(const Config& config, const std::string& ranges_csv);

}  // namespace deif
