// Micro-benchmarks of the core's per-step work (Google Benchmark), no transport:
//   - one agent's DEIF step: predict, its own contribution, validation of the N received
//     contributions, fusion of the N contributions (eqs 4.45-4.51);
//   - one control-law step (NextAngle) on a ring of N agents (eqs 3.2 / 3.6);
//   - one PCRLB recursion step with N sensors.
// N runs from 4 to 1024. These report time per call; they assert nothing.
#include <benchmark/benchmark.h>

#include <cmath>
#include <vector>

#include "common/core/control_law.hpp"
#include "common/core/filters.hpp"
#include "common/core/fisher.hpp"
#include "common/core/models.hpp"

namespace {

using deif::AgentId;
using deif::Contribution;
using deif::MotionModel;
using deif::MotionModelKind;
using deif::RangeObservation;
using deif::SensingFunction;
using deif::StateMatrix;
using deif::StateVector;
using deif::Vector2;

using deif::kPi;
constexpr double kRangeVariance = 5.3e-4;  // R_j of configs/default.yaml
constexpr double kRadius_m = 2.0;

MotionModel Model(MotionModelKind kind) {
  MotionModel model;
  model.kind = kind;
  model.dt_s = 0.1;
  model.process_noise = 1.3e-4;
  return model;
}

// N sensors evenly spaced on a circle about the origin, each with its exact range to p_target.
std::vector<RangeObservation> RingObservations(int n, const Vector2& p_target) {
  std::vector<RangeObservation> observations;
  observations.reserve(static_cast<std::size_t>(n));
  for (int j = 0; j < n; ++j) {
    const double angle_rad = 2.0 * kPi * j / n;
    RangeObservation z;
    z.agent_id = j + 1;
    z.p_sensor = kRadius_m * Vector2(std::cos(angle_rad), std::sin(angle_rad));
    z.range_m = (p_target - z.p_sensor).norm();
    z.variance_m2 = kRangeVariance;
    observations.push_back(z);
  }
  return observations;
}

// One agent's DEIF step with N contributions in the sum. The peers' contributions are
// precomputed (in the real system they arrive over the network); the agent predicts,
// computes its own, validates the N - 1 received ones and fuses all N in ascending id.
void BM_DeifAgentStep(benchmark::State& state) {
  const int n = static_cast<int>(state.range(0));
  const auto kind = static_cast<MotionModelKind>(state.range(1));
  const MotionModel model = Model(kind);
  const StateVector x0 = StateVector::Zero(model.StateDim());
  const StateMatrix P0 = StateMatrix::Identity(model.StateDim(), model.StateDim());
  const SensingFunction sensing;
  deif::DeifNode node(1, model, x0, P0, sensing);

  const Vector2 p_target(0.1, -0.05);
  const std::vector<RangeObservation> observations = RingObservations(n, p_target);
  std::vector<Contribution> received;
  for (int j = 1; j < n; ++j) {
    received.push_back(deif::ComputeContribution(1, observations[static_cast<std::size_t>(j)],
                                                 Vector2::Zero(), sensing));
  }
  std::vector<Contribution> to_fuse;
  to_fuse.reserve(static_cast<std::size_t>(n));
  deif::StepIndex k = 0;
  for (auto _ : state) {
    ++k;
    node.Predict();  // eqs (4.45)-(4.46)
    to_fuse.clear();
    to_fuse.push_back(node.LocalContribution(k, observations[0]));  // eqs (4.49)-(4.51)
    for (Contribution c : received) {
      c.step = k;
      if (deif::ValidateContribution(c) == deif::RejectReason::kNone) to_fuse.push_back(c);
    }
    benchmark::DoNotOptimize(node.Fuse(to_fuse));  // eqs (4.47)-(4.48)
    benchmark::DoNotOptimize(node.filter().PositionEstimate());
  }
  state.SetItemsProcessed(state.iterations() * n);  // contributions fused
  state.SetLabel(kind == MotionModelKind::kRandomWalk ? "random_walk" : "constant_velocity");
}
BENCHMARK(BM_DeifAgentStep)
    ->ArgsProduct({benchmark::CreateRange(4, 1024, 2),
                   {static_cast<int>(MotionModelKind::kRandomWalk),
                    static_cast<int>(MotionModelKind::kConstantVelocity)}})
    ->ArgNames({"N", "model"});

// The fusion alone: SumContributions (which sorts by id) of N contributions in reverse id
// order plus AddInformation, to separate the O(N log N) part from the fixed cost.
void BM_SumContributions(benchmark::State& state) {
  const int n = static_cast<int>(state.range(0));
  const SensingFunction sensing;
  const std::vector<RangeObservation> observations = RingObservations(n, Vector2(0.1, -0.05));
  std::vector<Contribution> contributions;
  for (int j = n - 1; j >= 0; --j) {
    contributions.push_back(deif::ComputeContribution(
        1, observations[static_cast<std::size_t>(j)], Vector2::Zero(), sensing));
  }
  for (auto _ : state) {
    benchmark::DoNotOptimize(deif::SumContributions(contributions));
  }
  state.SetItemsProcessed(state.iterations() * n);
}
BENCHMARK(BM_SumContributions)->RangeMultiplier(2)->Range(4, 1024)->ArgName("N");

// One control-law step: agent 1 picks its next angle from a ring of N members (slightly
// perturbed from even spacing, unsorted as they would come out of a map of positions).
void BM_NextAngle(benchmark::State& state) {
  const int n = static_cast<int>(state.range(0));
  const auto law = static_cast<deif::ControlLawKind>(state.range(1));
  std::vector<deif::RingMember> members;
  for (int j = 0; j < n; ++j) {
    const double jitter_rad = 0.3 * std::sin(1.7 * j) * (2.0 * kPi / n);
    members.push_back({j + 1, deif::WrapTwoPi(2.0 * kPi * j / n + jitter_rad)});
  }
  for (auto _ : state) {
    benchmark::DoNotOptimize(deif::NextAngle(law, 1, members));
  }
  state.SetLabel(law == deif::ControlLawKind::kVoronoi ? "voronoi" : "midpoint");
}
BENCHMARK(BM_NextAngle)
    ->ArgsProduct({benchmark::CreateRange(4, 1024, 2),
                   {static_cast<int>(deif::ControlLawKind::kMidpoint),
                    static_cast<int>(deif::ControlLawKind::kVoronoi)}})
    ->ArgNames({"N", "law"});

// One PCRLB recursion step with N sensors on a ring about the true position.
void BM_PcrlbStep(benchmark::State& state) {
  const int n = static_cast<int>(state.range(0));
  const auto kind = static_cast<MotionModelKind>(state.range(1));
  const MotionModel model = Model(kind);
  const SensingFunction sensing;
  std::vector<deif::SensorGeometry> sensors;
  for (const RangeObservation& z : RingObservations(n, Vector2::Zero())) {
    sensors.push_back({z.p_sensor, kRangeVariance});
  }
  deif::Pcrlb pcrlb(model, StateMatrix::Identity(model.StateDim(), model.StateDim()));
  const Vector2 p_true(0.1, -0.05);
  for (auto _ : state) {
    pcrlb.Step(p_true, sensors, sensing);
    benchmark::DoNotOptimize(pcrlb.information().data());
  }
  state.SetItemsProcessed(state.iterations() * n);
  state.SetLabel(kind == MotionModelKind::kRandomWalk ? "random_walk" : "constant_velocity");
}
BENCHMARK(BM_PcrlbStep)
    ->ArgsProduct({benchmark::CreateRange(4, 1024, 2),
                   {static_cast<int>(MotionModelKind::kRandomWalk),
                    static_cast<int>(MotionModelKind::kConstantVelocity)}})
    ->ArgNames({"N", "model"});

}  // namespace

BENCHMARK_MAIN();
