// The metrics of a run, computed once, here, from the run artefacts (target.csv, ranges.csv,
// agent_<id>.csv) and the config: by deif_sim for its own runs and by `deif_sim --evaluate
// RUN` for multi-process runs. Scripts only reduce and plot what this writes
// (metrics.csv, and the "metrics" of summary.json; docs/ARTEFACTS.md).
#pragma once

#include <map>
#include <string>
#include <vector>

#include "common/artefacts/artefacts.hpp"
#include "common/config/config.hpp"

namespace deif::sim {

// Agents agree at a step when every pair of their estimates is within this distance [m].
inline constexpr double kAgreementToleranceM = 1e-6;

// The artefacts of one run.
struct RunData {
  std::vector<TargetRow> truth;
  std::vector<RangeRow> ranges;
  std::map<AgentId, std::vector<AgentRow>> agents;
};

// Reads a run folder (missing files give no rows).
RunData LoadRun(const std::string& dir, int agent_count);

struct StepMetrics {
  StepIndex step = 0;
  double t_s = 0.0;
  int rows = 0;                      // agent rows written for this step
  int measured = 0;                  // ranges the target published for this step
  double rms_error_m = 0.0;          // over the agents' rows of this step
  double max_error_m = 0.0;
  double mean_nees = 0.0;            // position NEES, mean over the rows
  double pcrlb_m = 0.0;              // sqrt(trace) of the position PCRLB
  double optimality_ratio = 0.0;     // det J / det J* of the geometry measured (0: none)
  double max_disagreement_m = 0.0;   // largest distance between two agents' estimates
  double gap_error_rad = 0.0;        // of the ring of the agents' angles (rows of this step)
};

struct AgentMetrics {
  int rows = 0;
  StepIndex first_step = 0;
  StepIndex last_step = 0;
  int missing_rows = 0;  // steps between its first and last row without a row
  double rmse_m = 0.0;
  double max_error_m = 0.0;
  long rejected = 0;
  long dropped = 0;
  long late = 0;
  long deadline_misses = 0;
};

struct RunMetrics {
  StepIndex last_step = 0;           // the highest step with a truth row
  double rmse_m = 0.0;               // over every agent row
  double max_error_m = 0.0;
  double anees = 0.0;                // mean position NEES / 2
  double pcrlb_rmse_m = 0.0;         // sqrt(mean over steps of the PCRLB trace)
  double mean_optimality_ratio = 0.0;
  double final_max_gap_error_rad = 0.0;
  int final_agents = 0;              // agents whose last row is at last_step
  double agreement_fraction = 1.0;   // steps with >= 2 rows where every pair agrees
  double max_disagreement_m = 0.0;
  int longest_disagreement_steps = 0;  // longest run of consecutive disagreeing steps
  bool any_non_finite = false;       // a NaN or inf estimate anywhere (never reported as 0)
  std::vector<StepMetrics> per_step;
  std::map<AgentId, AgentMetrics> per_agent;
};

RunMetrics EvaluateRun(const Config& config, const RunData& run);

// metrics.csv: one row per step (the columns of StepMetrics).
void WriteMetricsCsv(const std::string& path, const RunMetrics& metrics);

}  // namespace deif::sim
