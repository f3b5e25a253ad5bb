#include "common/sim/replay.hpp"

#include <algorithm>
#include <map>

#include "common/artefacts/artefacts.hpp"
#include "common/core/filters.hpp"

namespace deif {

std::vector<ReplayRow> ReplayCentralized(const Config& config, const std::string& ranges_csv) {
  std::map<StepIndex, std::vector<RangeObservation>> by_step;
  for (const RangeRow& row : ReadRangesCsv(ranges_csv)) {
    RangeObservation z;
    z.agent_id = row.agent_id;
    z.range_m = row.range_m;
    z.variance_m2 = row.variance_m2;
    z.p_sensor = row.p_sensor;
    by_step[row.step].push_back(z);
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
