// The in-process simulation: a target plus N DEIF nodes with the control law, stepped
// deterministically from the seed, with no transport. It is the oracle the multi-process
// system is compared with, and the fast path for Monte Carlo work.
#pragma once

#include <string>
#include <vector>

#include "common/config/config.hpp"

namespace deif {

struct SimulationMetrics {
  StepIndex steps = 0;
  double rmse_m = 0.0;           // sqrt(mean over steps and live agents of ||x - x_hat||^2)
  double max_error_m = 0.0;      // max over steps and live agents of ||x - x_hat||
  double final_max_gap_error_rad = 0.0;  // MaxGapError of the final ring
  double mean_optimality_ratio = 0.0;    // mean over steps of det J / det J* (true geometry)
  double pcrlb_rmse_m = 0.0;     // sqrt(mean over steps of trace of the position PCRLB)
  double anees = 0.0;            // mean NEES of the position over steps / 2 (dimension)
  int final_alive = 0;
  std::vector<double> error_m;   // ||x - x_hat|| per step (agent with the lowest live id)
  std::vector<double> pcrlb_m;   // sqrt(trace) of the position PCRLB per step
};

// Run the scenario. When out_dir is not empty, write the run artefacts (target.csv,
// ranges.csv, agent_<id>.csv) into it; summary.json is the caller's.
// Faults: kill removes the agent from that step on; stop/cont remove it and bring it back
// (it predicts without fusing while stopped); restart_target drops every range of that step.
SimulationMetrics RunSimulation(const Config& config, const std::string& out_dir = "");

}  // namespace deif
