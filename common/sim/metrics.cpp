#include "common/sim/metrics.hpp"

#include <algorithm>
#include <cmath>
#include <filesystem>
#include <limits>
#include <set>

#include "common/core/control_law.hpp"
#include "common/core/fisher.hpp"

namespace deif::sim {

RunData LoadRun(const std::string& dir, int agent_count) {
  const std::filesystem::path folder(dir);
  RunData run;
  run.truth = ReadTargetCsv((folder / kTargetCsvSchema.file_name).string());
  run.ranges = ReadRangesCsv((folder / kRangesCsvSchema.file_name).string());
  for (AgentId id = 1; id <= agent_count; ++id) {
    std::vector<AgentRow> rows = ReadAgentCsv((folder / AgentCsvName(id)).string());
    if (!rows.empty()) run.agents[id] = std::move(rows);
  }
  return run;
}

RunMetrics EvaluateRun(const Config& config, const RunData& run) {
  RunMetrics m;
  std::map<StepIndex, Vector2> truth;
  for (const TargetRow& row : run.truth) truth[row.step] = row.p_true;  // a restart rewrites
  std::map<StepIndex, std::vector<SensorGeometry>> geometry;
  for (const RangeRow& r : run.ranges) {
    geometry[r.step].push_back({r.p_sensor, config.target.range_noise_variance_m2});
  }
  std::map<StepIndex, std::vector<std::pair<AgentId, const AgentRow*>>> rows_by_step;
  for (const auto& [id, rows] : run.agents) {
    AgentMetrics& a = m.per_agent[id];
    std::set<StepIndex> steps;
    double sum_sq = 0.0;
    int samples = 0;
    for (const AgentRow& row : rows) {
      steps.insert(row.step);
      rows_by_step[row.step].emplace_back(id, &row);
      auto t = truth.find(row.step);
      if (t == truth.end()) continue;
      const double e = (t->second - row.estimate_m).norm();
      if (!std::isfinite(e)) m.any_non_finite = true;
      sum_sq += e * e;
      ++samples;
      a.max_error_m = std::max(a.max_error_m, std::isfinite(e) ? e : std::numeric_limits<double>::infinity());
    }
    a.rows = static_cast<int>(rows.size());
    if (!steps.empty()) {
      a.first_step = *steps.begin();
      a.last_step = *steps.rbegin();
      a.missing_rows = static_cast<int>(a.last_step - a.first_step + 1) - static_cast<int>(steps.size());
    }
    a.rmse_m = samples > 0 ? std::sqrt(sum_sq / samples) : 0.0;
    if (!rows.empty()) {
      a.rejected = rows.back().rejected;
      a.dropped = rows.back().dropped;
      a.late = rows.back().late;
      a.deadline_misses = rows.back().deadline_misses;
    }
  }

  Pcrlb pcrlb(config.filter.motion_model, InitialCovariance(config));
  double sum_sq = 0.0;
  double sum_nees = 0.0;
  long samples = 0;
  double sum_bound = 0.0;
  long bound_steps = 0;
  double sum_optimality = 0.0;
  long optimality_steps = 0;
  int agreeing = 0;
  int compared = 0;
  int streak = 0;
  m.last_step = truth.empty() ? 0 : truth.rbegin()->first;
  for (StepIndex k = 1; k <= m.last_step; ++k) {
    auto t = truth.find(k);
    if (t == truth.end()) continue;
    StepMetrics s;
    s.step = k;
    s.t_s = static_cast<double>(k) * config.scenario.dt_s;
    const std::vector<SensorGeometry>& sensors = geometry[k];
    s.measured = static_cast<int>(sensors.size());
    pcrlb.Step(t->second, sensors, config.sensing);
    const double bound = pcrlb.PositionBound().trace();
    s.pcrlb_m = std::sqrt(bound);
    sum_bound += bound;
    ++bound_steps;
    if (!sensors.empty()) {
      s.optimality_ratio = OptimalityRatio(FisherInformation(sensors, t->second, config.sensing));
      sum_optimality += s.optimality_ratio;
      ++optimality_steps;
    }
    const auto& rows = rows_by_step[k];
    s.rows = static_cast<int>(rows.size());
    double step_sq = 0.0;
    double step_nees = 0.0;
    std::vector<RingMember> ring;
    for (const auto& [id, row] : rows) {
      const Vector2 error = t->second - row->estimate_m;
      const double e = error.norm();
      step_sq += e * e;
      s.max_error_m = std::max(s.max_error_m, e);
      const double nees = error.dot(row->covariance.ldlt().solve(error));
      step_nees += nees;
      ring.push_back({id, row->angle_rad});
      for (const auto& [other_id, other] : rows) {
        if (other_id <= id) continue;
        s.max_disagreement_m =
            std::max(s.max_disagreement_m, (row->estimate_m - other->estimate_m).norm());
      }
    }
    if (!rows.empty()) {
      s.rms_error_m = std::sqrt(step_sq / static_cast<double>(rows.size()));
      s.mean_nees = step_nees / static_cast<double>(rows.size());
      sum_sq += step_sq;
      sum_nees += step_nees;
      samples += static_cast<long>(rows.size());
    }
    s.gap_error_rad = MaxGapError(ring);
    if (rows.size() >= 2) {
      ++compared;
      if (s.max_disagreement_m <= kAgreementToleranceM) {
        ++agreeing;
        streak = 0;
      } else {
        m.longest_disagreement_steps = std::max(m.longest_disagreement_steps, ++streak);
      }
    }
    m.max_error_m = std::max(m.max_error_m, s.max_error_m);
    m.max_disagreement_m = std::max(m.max_disagreement_m, s.max_disagreement_m);
    m.per_step.push_back(s);
  }
  m.rmse_m = samples > 0 ? std::sqrt(sum_sq / static_cast<double>(samples)) : 0.0;
  m.anees = samples > 0 ? sum_nees / static_cast<double>(samples) / 2.0 : 0.0;
  m.pcrlb_rmse_m = bound_steps > 0 ? std::sqrt(sum_bound / static_cast<double>(bound_steps)) : 0.0;
  m.mean_optimality_ratio =
      optimality_steps > 0 ? sum_optimality / static_cast<double>(optimality_steps) : 0.0;
  m.agreement_fraction = compared > 0 ? static_cast<double>(agreeing) / compared : 1.0;
  if (m.any_non_finite) {
    m.rmse_m = std::numeric_limits<double>::quiet_NaN();
    m.max_error_m = std::numeric_limits<double>::quiet_NaN();
  }
  // The final ring: the agents whose last row is at the last step written by anyone.
  StepIndex last_written = 0;
  for (const auto& [id, a] : m.per_agent) last_written = std::max(last_written, a.last_step);
  std::vector<RingMember> final_ring;
  for (const auto& [id, rows] : run.agents) {
    if (!rows.empty() && rows.back().step == last_written) {
      final_ring.push_back({id, rows.back().angle_rad});
    }
  }
  m.final_agents = static_cast<int>(final_ring.size());
  m.final_max_gap_error_rad = MaxGapError(final_ring);
  return m;
}

void WriteMetricsCsv(const std::string& path, const RunMetrics& metrics) {
  CsvWriter out(path,
                "step,t,rows,measured,rms_error,max_error,mean_nees,pcrlb,optimality_ratio,"
                "max_disagreement,gap_error");
  for (const StepMetrics& s : metrics.per_step) {
    out.WriteLine(std::to_string(s.step) + "," + FormatDouble(s.t_s) + "," + std::to_string(s.rows) +
                  "," + std::to_string(s.measured) + "," + FormatDouble(s.rms_error_m) + "," +
                  FormatDouble(s.max_error_m) + "," + FormatDouble(s.mean_nees) + "," +
                  FormatDouble(s.pcrlb_m) + "," + FormatDouble(s.optimality_ratio) + "," +
                  FormatDouble(s.max_disagreement_m) + "," + FormatDouble(s.gap_error_rad));
  }
}

}  // namespace deif::sim
