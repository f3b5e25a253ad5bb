// A passive observer of a lock-step run, for scripts/bench: it subscribes to deif/truth,
// deif/range and deif/agent_state (never writes) and stamps every arrival with
// steady_clock (CLOCK_MONOTONIC, the clock of Python's time.monotonic()). At the end of the
// run (truth step -1), on SIGINT/SIGTERM or at --timeout it prints one JSON object:
//
//   {"clock": "CLOCK_MONOTONIC", "t_start": T, "steps": [[k, t_truth, t_range_first,
//    n_ranges, t_state_first, t_state_last, n_states], ...]}
//
// t_* are seconds of CLOCK_MONOTONIC (null when nothing arrived). For step k:
//   step latency  = t_state_last(k) - t_range_first(k): from the target's first range of step
//                   k to the last agent's state of step k (an agent publishes its state right
//                   after fusing step k and moving), both seen by this process;
//   step period   = t_range_first(k+1) - t_range_first(k).
// It is one more participant with three readers: it costs the target and every agent one
// extra delivery per sample (docs/BENCHMARKS.md).
#include <time.h>

#include <atomic>
#include <chrono>
#include <cstdio>
#include <map>
#include <mutex>
#include <string>
#include <thread>

#include <CLI/CLI.hpp>

#include "dds/dds_common.hpp"
#include "common/config/config.hpp"
#include "deifPubSubTypes.h"

namespace {

using deif::dds::Clock;

std::atomic<bool> g_stop{false};  // set from the signal thread

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

class Recorder {
 public:
  void Truth(long long step) {
    const double t = MonotonicNow();
    if (step < 0) {
      end_.store(true);
      return;
    }
    std::lock_guard<std::mutex> lock(mutex_);
    StepRecord& r = steps_[step];
    if (r.t_truth < 0) r.t_truth = t;
  }
  void Range(long long step) {
    const double t = MonotonicNow();
    std::lock_guard<std::mutex> lock(mutex_);
    StepRecord& r = steps_[step];
    if (r.t_range_first < 0) r.t_range_first = t;
    ++r.n_ranges;
  }
  void State(long long step) {
    const double t = MonotonicNow();
    if (step < 1) return;  // the initial states
    std::lock_guard<std::mutex> lock(mutex_);
    StepRecord& r = steps_[step];
    if (r.t_state_first < 0) r.t_state_first = t;
    r.t_state_last = t;
    ++r.n_states;
  }
  bool ended() const { return end_.load(); }

  void Print(double t_start) {
    std::lock_guard<std::mutex> lock(mutex_);
    auto num = [](double v) { return v < 0 ? std::string("null") : std::to_string(v); };
    std::printf("{\"clock\": \"CLOCK_MONOTONIC\", \"t_start\": %.6f, \"steps\": [", t_start);
    bool first = true;
    for (const auto& [k, r] : steps_) {
      std::printf("%s\n[%lld, %s, %s, %d, %s, %s, %d]", first ? "" : ",", k,
                  num(r.t_truth).c_str(), num(r.t_range_first).c_str(), r.n_ranges,
                  num(r.t_state_first).c_str(), num(r.t_state_last).c_str(), r.n_states);
      first = false;
    }
    std::printf("]}\n");
    std::fflush(stdout);
  }

 private:
  std::mutex mutex_;
  std::map<long long, StepRecord> steps_;
  std::atomic<bool> end_{false};
};

}  // namespace

int main(int argc, char** argv) {
  deif::dds::SignalStopper stopper;  // first, before any thread exists
  std::string config_path;
  int domain = -1;
  double timeout_s = 600.0;
  CLI::App app{"Passive observer of a lock-step run: per-step arrival times as JSON"};
  app.add_option("--config", config_path, "the run's YAML config (for the QoS leases)")->required();
  app.add_option("--domain", domain, "DDS domain id (default: the config's)");
  app.add_option("--timeout", timeout_s, "give up after this many seconds");
  CLI11_PARSE(app, argc, argv);

  try {
    const deif::Config config = deif::LoadConfig(config_path);
    deif::NetworkConfig network = config.network;
    if (domain >= 0) network.domain_id = domain;
    stopper.SetHandler([](int) { g_stop.store(true); });

    Recorder recorder;
    deif::dds::ReaderListener<deif_msgs::Truth> truth_listener(
        [&](const deif_msgs::Truth& m, const deif::dds::WriterKey&) { recorder.Truth(m.step()); },
        nullptr);
    deif::dds::ReaderListener<deif_msgs::Range> range_listener(
        [&](const deif_msgs::Range& m, const deif::dds::WriterKey&) { recorder.Range(m.step()); },
        nullptr);
    deif::dds::ReaderListener<deif_msgs::AgentState> state_listener(
        [&](const deif_msgs::AgentState& m, const deif::dds::WriterKey&) {
          recorder.State(m.step());
        },
        nullptr);
    const double t_start = MonotonicNow();
    {
      deif::dds::DdsParticipant participant(network.domain_id, network, "bench-observer");
      participant.CreateReader(deif::dds::kTruthTopic, deif::dds::TruthReaderQos(), &truth_listener);
      participant.CreateReader(deif::dds::kRangeTopic, deif::dds::RangeReaderQos(), &range_listener);
      participant.CreateReader(deif::dds::kAgentStateTopic,
                               deif::dds::AgentStateReaderQos(network), &state_listener);
      std::fprintf(stderr, "step_observer: ready on domain %d\n", network.domain_id);
      const auto give_up = Clock::now() + deif::dds::ToDuration(timeout_s);
      while (!g_stop.load() && !recorder.ended() && Clock::now() < give_up) {
        std::this_thread::sleep_for(std::chrono::milliseconds(20));
      }
      std::this_thread::sleep_for(std::chrono::milliseconds(100));  // the last states
    }  // entities deleted before the listeners
    recorder.Print(t_start);
    return 0;
  } catch (const std::exception& e) {
    std::fprintf(stderr, "step_observer: error: %s\n", e.what());
    return 2;
  }
}
