// A passive observer of a run, for the benchmarks: it reads deif/truth, deif/range and
// deif/agent_state (never writes) and stamps every arrival with CLOCK_MONOTONIC (the clock
// of Python's time.monotonic()). When the last step's states arrived, on SIGINT/SIGTERM or
// at --timeout it prints one JSON object:
//
//   {"clock": "CLOCK_MONOTONIC", "t_start": T, "steps": [[k, t_truth, t_range_first,
//    n_ranges, t_state_first, t_state_last, n_states], ...]}
//
// t_* are seconds (null when nothing arrived). For step k:
//   step latency = t_state_last(k) - t_range_first(k): from the target's first range of step
//                  k to the last agent's state of step k;
//   step period  = t_range_first(k+1) - t_range_first(k).
// It is one more participant: it costs the target and every agent one extra delivery per
// sample (docs/BENCHMARKS.md).
#include <time.h>

#include <atomic>
#include <csignal>
#include <cstdio>
#include <cstdlib>
#include <map>
#include <string>

#include <CLI/CLI.hpp>

#include "common/config/config.hpp"
#include "dds/node.hpp"

namespace {

std::atomic<bool> g_stop{false};

double MonotonicNow() {
  timespec ts{};
  clock_gettime(CLOCK_MONOTONIC, &ts);
  return static_cast<double>(ts.tv_sec) + 1e-9 * static_cast<double>(ts.tv_nsec);
}

struct StepRecord {
  double t_truth = -1.0;
  double t_range_first = -1.0;
  int n_ranges = 0;
  double t_state_first = -1.0;
  double t_state_last = -1.0;
  int n_states = 0;
};

}  // namespace

int main(int argc, char** argv) {
  std::string config_path, run_name;
  double timeout_s = 600.0;
  CLI::App app{"Passive observer of a run: per-step arrival times as JSON"};
  app.add_option("--config", config_path, "the run's config.yaml")->required();
  app.add_option("--run", run_name, "the run's name")->required();
  app.add_option("--timeout", timeout_s, "give up after this many seconds");
  CLI11_PARSE(app, argc, argv);
  std::signal(SIGINT, [](int) { g_stop.store(true); });
  std::signal(SIGTERM, [](int) { g_stop.store(true); });
  try {
    const deif::Config config = deif::LoadConfig(config_path);
    std::map<long long, StepRecord> steps;
    const double t_start = MonotonicNow();
    {
      deif::dds::Node node(config, "bench-observer", run_name);
      node.AddReader({deif::dds::Topic::kTruth, {}});
      node.AddReader({deif::dds::Topic::kRange, {}});
      node.AddReader({deif::dds::Topic::kAgentState, {}});
      std::fprintf(stderr, "step_observer: ready on domain %d\n", config.network.domain_id);
      const double give_up = t_start + timeout_s;
      bool done = false;
      while (!g_stop.load() && !done && MonotonicNow() < give_up) {
        for (const auto& event : node.Wait(deif::dds::Clock::now() + std::chrono::milliseconds(100))) {
          const double t = MonotonicNow();
          if (const auto* truth = std::get_if<deif::dds::Received<deif::protocol::TruthMsg>>(&event)) {
            StepRecord& r = steps[truth->msg.step];
            if (r.t_truth < 0) r.t_truth = t;
          } else if (const auto* range = std::get_if<deif::dds::Received<deif::protocol::RangeMsg>>(&event)) {
            StepRecord& r = steps[range->msg.step];
            if (r.t_range_first < 0) r.t_range_first = t;
            ++r.n_ranges;
          } else if (const auto* state = std::get_if<deif::dds::Received<deif::protocol::StateMsg>>(&event)) {
            if (state->msg.step < 1) continue;  // the initial states
            StepRecord& r = steps[state->msg.step];
            if (r.t_state_first < 0) r.t_state_first = t;
            r.t_state_last = t;
            ++r.n_states;
            done = state->msg.step >= config.scenario.steps && r.n_states >= config.agents.count;
          }
        }
      }
      // Leaves without deleting the participant, as the run's processes do at its end:
      // deleting a secure one can hang for good in Fast DDS 2.9.1 (docs/FASTDDS_NOTES.md,
      // "Security"), and then the figures below were never printed.
      node.Abandon();
    }
    const auto num = [](double v) { return v < 0 ? std::string("null") : std::to_string(v); };
    std::printf("{\"clock\": \"CLOCK_MONOTONIC\", \"t_start\": %.6f, \"steps\": [", t_start);
    bool first = true;
    for (const auto& [k, r] : steps) {
      std::printf("%s\n[%lld, %s, %s, %d, %s, %s, %d]", first ? "" : ",", k, num(r.t_truth).c_str(),
                  num(r.t_range_first).c_str(), r.n_ranges, num(r.t_state_first).c_str(),
                  num(r.t_state_last).c_str(), r.n_states);
      first = false;
    }
    std::printf("]}\n");
    std::fflush(stdout);
    std::fflush(stderr);
    std::_Exit(0);  // not exit(): Fast DDS's own teardown would delete the participant
  } catch (const std::exception& e) {
    std::fprintf(stderr, "step_observer: error: %s\n", e.what());
    return 2;
  }
}
