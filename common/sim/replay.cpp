#include "common/sim/replay.hpp"

#include <algorithm>
#include <fstream>
#include <map>
#include <sstream>
#include <stdexcept>

#include "common/core/filters.hpp"

namespace deif {

namespace {

std::vector<std::string> SplitCsvLine(const std::string& line) {
  std::vector<std::string> fields;
  std::stringstream stream(line);
  for (std::string field; std::getline(stream, field, ',');) fields.push_back(field);
  return fields;
}

}  // namespace

std::vector<ReplayRow> ReplayCentralized(const Config& config, const std::string& ranges_csv) {
  std::ifstream in(ranges_csv);
  if (!in) throw std::runtime_error("cannot read '" + ranges_csv + "'");
  std::string line;
  std::getline(in, line);
  if (line != "step,agent_id,range,variance,sensor_x,sensor_y") {
    throw std::runtime_error(ranges_csv + ":1: unexpected header '" + line + "'");
  }
  std::map<StepIndex, std::vector<RangeObservation>> by_step;
  int line_no = 1;
  while (std::getline(in, line)) {
    ++line_no;
    if (line.empty()) continue;
    const std::vector<std::string> f = SplitCsvLine(line);
    if (f.size() != 6) {
      throw std::runtime_error(ranges_csv + ":" + std::to_string(line_no) + ": expected 6 fields");
    }
    try {
      RangeObservation z;
      z.agent_id = std::stoi(f[1]);
      z.range_m = std::stod(f[2]);
      z.variance_m2 = std::stod(f[3]);
      z.p_sensor = Vector2(std::stod(f[4]), std::stod(f[5]));
      by_step[std::stoll(f[0])].push_back(z);
    } catch (const std::logic_error&) {
      throw std::runtime_error(ranges_csv + ":" + std::to_string(line_no) + ": not a number");
    }
  }

  CentralizedEif central(config.filter.motion_model, InitialState(config),
                         InitialCovariance(config), config.sensing);
  std::vector<ReplayRow> rows;
  const StepIndex last = by_step.empty() ? 0 : by_step.rbegin()->first;
  for (StepIndex k = 1; k <= last; ++k) {
    std::vector<RangeObservation>& obs = by_step[k];
    std::sort(obs.begin(), obs.end(), [](const RangeObservation& a, const RangeObservation& b) {
      return a.agent_id < b.agent_id;
    });
    central.Step(k, obs);
    ReplayRow row;
    row.step = k;
    row.estimate_m = central.filter().PositionEstimate();
    row.covariance = central.filter().PositionCovariance();
    row.ranges = static_cast<int>(obs.size());
    rows.push_back(row);
  }
  return rows;
}

}  // namespace deif
