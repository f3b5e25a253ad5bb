// What the live page shows (docs/LIVE.md), as a pure state machine: the observer's main loop
// feeds it the samples and liveliness changes it reads from deif/truth, deif/range and
// deif/agent_state, and sends the JSON it returns. No DDS, no HTTP, no clock of its own:
// every call gets the time, so tests drive it like the in-process simulation drives the
// protocol.
//
// Derived figures, per step k (finalised once the step's truth, ranges and states are in,
// or a later step has begun):
//   error    ||x(k|k) - x_true(k)|| of the estimate shown (the lowest agent id with a state
//            of step k), and the largest error over all agents;
//   sigma    sqrt(tr P) of that estimate, its own 1-sigma claim;
//   PCRLB    sqrt(tr of the position block of J(k)^-1) from the recursion of
//            common/core/fisher.hpp (Tichavsky et al.) over the measured sensors' positions
//            of deif/range and the truth, with the true range noise of the config: the same
//            bound deif_sim --evaluate writes into metrics.csv;
//   ratio    det J / (tr J / 2)^2 of the Fisher information (thesis eq 2.2) of those
//            sensors at the truth (common/core/fisher.hpp OptimalityRatio).
// The ring's gaps are those of the live agents' angles (each about its own estimate)
// against the optimum 2 pi / n (pi / 2 for two; thesis section 2.3.1.4).
#pragma once

#include <cstdint>
#include <deque>
#include <map>
#include <optional>
#include <set>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>

#include "common/config/config.hpp"
#include "common/core/fisher.hpp"
#include "common/protocol/messages.hpp"

namespace deif::observer {

// Whose liveliness changed: the target's range writer or an agent's state writer.
enum class WriterKind { kRange, kState, kOther };

struct ModelOptions {
  int trail_steps = 200;            // positions kept per agent (and of the truth)
  int series_steps = 6000;          // per-step figures kept for a new page
  int marks_kept = 500;             // fault marks kept for a new page
  double min_update_interval_s = 0.05;  // at most 20 updates per second
  double settle_s = 0.02;           // a started step waits this long for its other states
  double stale_after_s = 2.0;       // alive but silent this long while others go on: stale
  double together_s = 1.0;          // two losses this close are marked as a partition
  double counter_mark_interval_s = 1.0;  // rejected/dropped/misses marks per agent at most this often
};

// One fault or event, as a mark on the time line.
struct Mark {
  std::int64_t id = 0;        // 1, 2, ... in order
  StepIndex step = 0;         // the newest step seen when it happened
  double t_s = 0.0;           // observer clock, seconds since its start
  std::string kind;           // lost, back, restart, partition, heal, rejected, dropped,
                              // misses, target_lost, target_back, target_restart, views,
                              // end, done (an agent or the target finished), ignored
  AgentId agent = 0;          // 0: not about one agent
  std::string text;
};

struct SeriesPoint {
  StepIndex step = 0;
  double t_s = 0.0;           // model time of the step
  double error_m = 0.0;       // NaN when unknown (no truth or no state)
  double max_error_m = 0.0;
  double sigma_m = 0.0;
  double pcrlb_m = 0.0;       // NaN before the first truth
  double ratio = 0.0;         // NaN without sensors
  int alive = 0;
  int agent = 0;              // whose estimate the error is of
};

class LiveModel {
 public:
  // config: the run's config (agents.count, the filter's model and P0, the sensing function,
  // the true range noise); run: the run's token (messages of other runs are ignored).
  LiveModel(const Config& config, protocol::RunToken run, const std::string& run_name,
            ModelOptions options = {});

  void OnTruth(const protocol::TruthMsg& msg, double now_s);
  void OnRange(const protocol::RangeMsg& msg, const protocol::SenderKey& from, double now_s);
  // written_unix_s: when the agent wrote it (its clock); sent on with the state so a client
  // can measure the latency from the write to the page.
  void OnState(const protocol::StateMsg& msg, const protocol::SenderKey& from,
               double written_unix_s, double now_s);
  void OnLiveliness(WriterKind kind, const protocol::SenderKey& writer, bool alive, double now_s);
  // An agent's process ended: the transport saw the locks of its participant's shared-memory
  // ports released (docs/PROTOCOL.md, "A process that ended"). Not live from now on, as a
  // lapse would say later. Its state writer is SameProcess with `participant`.
  void OnProcessEnded(const protocol::SenderKey& participant, double now_s);
  // The live agents that the target's newest roll call leaves out: the transport looks for
  // the end of their processes more often.
  std::set<AgentId> LiveOutOfRollCall() const;
  // With DDS Security the transport knows that a state's writer may not speak for the id it
  // claims (docs/SECURITY.md): the state is ignored and counted, never shown.
  void OnUnauthorised(AgentId claimed, double now_s);
  // now_s is the observer's clock in seconds (monotonic; e.g. since its start).
  // Staleness, settled steps, throttled marks: call after every batch of samples and at
  // least every 100 ms. Incomplete steps are given up only here.
  void OnTimer(double now_s);

  // Whether an update is due now (something changed, the last one is at least
  // min_update_interval_s old, and the newest step had its states or settle_s passed), and
  // when the next one could be.
  bool UpdateDue(double now_s) const;
  std::optional<double> NextUpdateTime(double now_s) const;
  // What changed since the last update (and marks it sent); empty when nothing did.
  std::optional<nlohmann::json> TakeUpdate(double now_s);
  // Everything a new page needs. A page merges later updates by step and mark id, so
  // changes that are in both a snapshot and the next update are applied once.
  nlohmann::json Snapshot(double now_s) const;

  // For tests and the observer's files.
  int AliveCount() const;
  std::string StatusOf(AgentId id) const;  // never, alive, stale, lost, done (finished the run)
  StepIndex newest_step() const { return newest_step_; }
  const std::deque<SeriesPoint>& series() const { return series_; }
  const std::deque<Mark>& marks() const { return marks_; }
  std::optional<StepIndex> pcrlb_from_step() const { return pcrlb_from_step_; }
  std::int64_t ignored() const { return ignored_; }
  bool ended() const { return ended_; }

 private:
  struct TrailPoint {
    StepIndex step;
    Vector2 p;
  };
  struct Agent {
    bool seen = false;            // a state arrived
    bool live = false;            // its state writer is alive
    bool stale = false;
    protocol::SenderKey writer{};
    std::uint64_t token = 0;
    protocol::StateMsg state;
    double state_rx_s = 0.0;
    double written_unix_s = 0.0;
    int restarts = 0;
    std::deque<TrailPoint> trail;
    StepIndex trail_sent_step = -1;  // trail points up to this step were sent
    bool changed = false;
    // Counters already marked, and deltas waiting for their mark.
    std::int64_t rejected_marked = 0, dropped_marked = 0, misses_marked = 0;
    double last_counter_mark_s = -1e9;
  };
  struct StepData {
    std::optional<Vector2> truth;
    double t_s = 0.0;
    std::map<AgentId, Vector2> sensors;  // measured ranges' sensor positions
    std::optional<std::vector<AgentId>> roll_call;
    std::map<AgentId, std::pair<Vector2, Matrix2>> estimates;  // estimate, covariance
    std::map<AgentId, int> members;  // how many members each agent believed alive
    double first_seen_s = 0.0;
  };

  void Touch(double now_s);
  void AddMark(double now_s, const std::string& kind, AgentId agent, const std::string& text);
  void NoteStep(StepIndex step, double now_s);
  StepData& Step(StepIndex step, double now_s);
  void FinaliseSteps(double now_s, bool all_old, bool by_age = false);
  void Finalise(StepIndex step, StepData& data);
  bool StepComplete(StepIndex step, const StepData& data) const;
  void FlushCounterMarks(double now_s, bool force);
  // why: what a loss mark says it came from.
  void SetLive(AgentId id, bool live, double now_s, const char* why = "liveliness");
  nlohmann::json AgentJson(AgentId id, const Agent& a, bool full_trail) const;
  nlohmann::json CommonJson(double now_s) const;
  nlohmann::json SeriesJson(StepIndex after_step) const;
  void Ignore(const std::string& reason, double now_s);
  nlohmann::json RingJson() const;
  bool NewestStepHasStates() const;

  Config config_;
  protocol::RunToken run_;
  std::string run_name_;
  ModelOptions options_;
  std::map<AgentId, Agent> agents_;            // 1..agents.count
  std::map<protocol::SenderKey, AgentId> state_writers_;
  std::set<protocol::SenderKey> live_unknown_;  // alive before their first sample
  // The target: its range writer.
  std::optional<protocol::SenderKey> range_writer_;
  bool target_live_ = false;
  bool target_seen_ = false;
  int target_restarts_ = 0;
  std::optional<protocol::TruthMsg> truth_;
  std::deque<TrailPoint> truth_trail_;
  StepIndex truth_sent_step_ = -1;

  std::map<StepIndex, StepData> steps_;        // not finalised yet
  StepIndex finalised_ = 0;
  StepIndex newest_step_ = 0;
  std::vector<AgentId> newest_roll_call_;      // of the newest step a range came for
  StepIndex newest_roll_call_step_ = 0;
  double newest_step_s_ = 0.0;                 // when newest_step_ began (observer clock)
  Pcrlb pcrlb_;
  std::optional<StepIndex> pcrlb_from_step_;
  std::deque<SeriesPoint> series_;
  StepIndex series_sent_step_ = -1;            // points up to this step were sent
  std::deque<Mark> marks_;
  std::int64_t next_mark_id_ = 1;
  std::int64_t marks_sent_up_to_ = 0;          // highest mark id sent
  std::deque<std::pair<double, AgentId>> recent_losses_;
  std::deque<std::pair<double, AgentId>> recent_returns_;
  double last_partition_mark_s_ = -1e9;
  double last_heal_mark_s_ = -1e9;
  bool views_differ_ = false;
  bool ended_ = false;
  std::int64_t ignored_ = 0;
  std::set<std::string> ignored_marked_;       // one mark per reason

  bool dirty_ = false;
  double dirty_since_s_ = 0.0;
  double last_update_s_ = -1e9;
};

}  // namespace deif::observer
