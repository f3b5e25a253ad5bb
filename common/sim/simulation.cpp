// The in-process oracle: the same TargetCore and AgentCore the DDS processes use, stepped
// in one loop with full communication, following DESIGN.md "One step":
//   at step k every live agent measures its range from its position p(k-1), predicts and
//   computes its contribution; every live agent fuses all contributions and runs the
//   control law on the members' positions p(k-1) about its own estimate x(k|k).
#include "common/sim/simulation.hpp"

#include <algorithm>
#include <cmath>
#include <filesystem>
#include <limits>
#include <map>
#include <memory>
#include <optional>

#include "common/protocol/agent_core.hpp"
#include "common/artefacts/artefacts.hpp"
#include "common/core/fisher.hpp"
#include "common/protocol/target_core.hpp"

namespace deif {

namespace {

enum class AgentState { kRunning, kStopped, kKilled };

struct SimAgent {
  std::unique_ptr<AgentCore> core;
  AgentState state = AgentState::kRunning;
  Vector2 p_previous_m = Vector2::Zero();  // p(k-1): where this step's range is taken from
  AgentSnapshot last;                      // the latest finished step
  std::optional<AgentCsv> csv;
};

// The run artefacts, when an output folder is given.
struct Artefacts {
  std::optional<TargetCsv> target;
  std::optional<RangesCsv> ranges;
};

}  // namespace

SimulationMetrics RunSimulation(const Config& config, const std::string& out_dir) {
  TargetCore target(config);

  std::map<AgentId, SimAgent> agents;  // ordered: every loop runs in ascending id
  for (AgentId id = 1; id <= config.agents.count; ++id) {
    SimAgent& agent = agents[id];
    agent.core = std::make_unique<AgentCore>(config, id);
    agent.last = agent.core->Initial();
    agent.p_previous_m = agent.last.position_m;
  }

  Artefacts files;
  if (!out_dir.empty()) {
    std::filesystem::create_directories(out_dir);
    const std::filesystem::path dir(out_dir);
    files.target.emplace((dir / "target.csv").string());
    files.ranges.emplace((dir / "ranges.csv").string());
    for (auto& [id, agent] : agents) agent.csv.emplace((dir / AgentCsvName(id)).string());
  }

  // The bound uses the filter's model with the TRUE range noise at the TRUE positions.
  Pcrlb pcrlb(config.filter.motion_model, InitialCovariance(config));

  SimulationMetrics metrics;
  metrics.steps = config.scenario.steps;
  double sum_squared_error = 0.0;
  double sum_nees = 0.0;
  long error_samples = 0;
  double sum_bound_trace = 0.0;
  double sum_optimality = 0.0;
  long optimality_samples = 0;

  for (StepIndex k = 1; k <= config.scenario.steps; ++k) {
    // Faults take effect at the start of their step.
    bool ranges_this_step = true;
    for (const FaultConfig& fault : config.faults) {
      if (fault.step != k) continue;
      switch (fault.action) {
        case FaultAction::kKill:
          agents.at(fault.agent_id).state = AgentState::kKilled;
          break;
        case FaultAction::kStop:
          agents.at(fault.agent_id).state = AgentState::kStopped;
          break;
        case FaultAction::kCont:
          agents.at(fault.agent_id).state = AgentState::kRunning;
          break;
        case FaultAction::kRestartTarget:
          ranges_this_step = false;
          break;
      }
    }

    const Vector2 p_true = target.TruthAt(k);
    const double t_s = target.TimeAt(k);
    if (files.target) files.target->Write({k, t_s, p_true});

    // The members of this step and the positions they measure from: p(k-1).
    std::map<AgentId, Vector2> member_positions;
    for (const auto& [id, agent] : agents) {
      if (agent.state == AgentState::kRunning) member_positions.emplace(id, agent.p_previous_m);
    }

    // First half: ranges, prediction, local contributions.
    std::vector<Contribution> contributions;
    for (auto& [id, agent] : agents) {
      if (agent.state == AgentState::kKilled) continue;
      std::optional<RangeObservation> z;
      if (agent.state == AgentState::kRunning && ranges_this_step) {
        RangeObservation observation;
        observation.agent_id = id;
        observation.range_m = target.NoisyRange(k, id, p_true, agent.p_previous_m);
        observation.variance_m2 = config.filter.range_variance_m2;
        observation.p_sensor = agent.p_previous_m;
        if (files.ranges) {
          files.ranges->Write(
              {k, id, observation.range_m, observation.variance_m2, observation.p_sensor});
        }
        z = observation;
      }
      // A stopped agent only predicts (it takes no part in the step).
      if (auto c = agent.core->BeginStep(k, z)) contributions.push_back(*c);
    }

    // Second half: fuse everything, move, record.
    for (auto& [id, agent] : agents) {
      if (agent.state != AgentState::kRunning) continue;
      agent.last = agent.core->FinishStep(k, contributions, member_positions);
      if (agent.csv) {
        AgentRow row;
        row.step = k;
        row.t_s = t_s;
        row.estimate_m = agent.last.estimate_m;
        row.covariance = agent.last.covariance;
        row.position_m = agent.last.position_m;
        row.angle_rad = agent.last.angle_rad;
        row.alive = agent.last.alive;
        row.fused = agent.last.fused;
        agent.csv->Write(row);
      }
      const Vector2 error = p_true - agent.last.estimate_m;
      sum_squared_error += error.squaredNorm();
      metrics.max_error_m = std::max(metrics.max_error_m, error.norm());
      sum_nees += error.dot(agent.last.covariance.ldlt().solve(error));
      ++error_samples;
    }
    metrics.error_m.push_back(
        member_positions.empty()
            ? std::numeric_limits<double>::quiet_NaN()
            : (p_true - agents.at(member_positions.begin()->first).last.estimate_m).norm());

    // The geometry the ranges of this step were measured from, with the true noise.
    std::vector<SensorGeometry> sensors;
    for (const auto& [id, p_sensor] : member_positions) {
      sensors.push_back({p_sensor, config.target.range_noise_variance_m2});
    }
    if (!sensors.empty()) {
      sum_optimality += OptimalityRatio(FisherInformation(sensors, p_true, config.sensing));
      ++optimality_samples;
    }
    pcrlb.Step(p_true, ranges_this_step ? sensors : std::vector<SensorGeometry>{},
               config.sensing);
    const double bound_trace = pcrlb.PositionBound().trace();
    sum_bound_trace += bound_trace;
    metrics.pcrlb_m.push_back(std::sqrt(bound_trace));

    // The positions of this step are the measuring positions of the next.
    for (auto& [id, agent] : agents) {
      if (agent.state == AgentState::kRunning) agent.p_previous_m = agent.last.position_m;
    }
  }

  const double steps = static_cast<double>(config.scenario.steps);
  const double samples = static_cast<double>(error_samples);
  metrics.rmse_m = error_samples > 0 ? std::sqrt(sum_squared_error / samples) : 0.0;
  metrics.anees = error_samples > 0 ? sum_nees / samples / 2.0 : 0.0;
  metrics.pcrlb_rmse_m = std::sqrt(sum_bound_trace / steps);
  metrics.mean_optimality_ratio =
      optimality_samples > 0 ? sum_optimality / static_cast<double>(optimality_samples) : 0.0;

  std::vector<RingMember> final_ring;
  for (const auto& [id, agent] : agents) {
    if (agent.state == AgentState::kRunning) final_ring.push_back({id, agent.last.angle_rad});
  }
  metrics.final_alive = static_cast<int>(final_ring.size());
  metrics.final_max_gap_error_rad = MaxGapError(final_ring);
  return metrics;
}

}  // namespace deif
