// The target's step protocol as a pure state machine (docs/PROTOCOL.md): it waits for the
// agents, then at every step publishes the truth and, to every agent id, a range message
// with the step's roll call (the ids it measured); it paces the lock-step on the agents'
// states, or a real-time clock; and in lock-step it holds a step with a scripted fault until
// the fault is applied, so a faulted run is reproducible from its seed.
#pragma once

#include <map>
#include <optional>
#include <set>
#include <string>
#include <variant>
#include <vector>

#include "common/artefacts/artefacts.hpp"
#include "common/config/config.hpp"
#include "common/protocol/agent_protocol.hpp"
#include "common/protocol/lapse_filter.hpp"
#include "common/protocol/messages.hpp"
#include "common/protocol/target_core.hpp"

namespace deif::protocol {

namespace target_action {
struct PublishRange {
  RangeMsg msg;
};
struct PublishTruth {
  TruthMsg msg;
};
struct WriteTruthRow {
  TargetRow row;
};
struct WriteRangeRow {
  RangeRow row;
};
// The target reached a step with scripted faults. In lock-step it waits for OnGo(step)
// (the launcher applies the faults, then says go); in real time it goes on.
struct Hold {
  StepIndex step;
  std::string faults;  // e.g. "kill agent 3"
};
using protocol::Finish;
using protocol::Log;
}  // namespace target_action

using TargetAction =
    std::variant<target_action::PublishRange, target_action::PublishTruth,
                 target_action::WriteTruthRow, target_action::WriteRangeRow, target_action::Hold,
                 target_action::Log, target_action::Finish>;

class TargetProtocol {
 public:
  struct Options {
    RunToken run = 1;
    std::optional<StepIndex> start_step;  // a restarted target: resume here at the earliest
    bool hold_for_faults = false;         // hold steps with faults until OnGo (lock-step)
    // Before the run begins, a lapse of an agent's state writer is held this long before it
    // counts as a loss (< 0: network.liveliness_grace_s, as once the run has begun). Longer
    // where those writers renew rarely (dds::Timings::peer_grace_s): in the start storm of a
    // large run a renewal comes late, and each false loss held the start back
    // (docs/PROTOCOL.md, "The target").
    double start_grace_s = -1.0;
  };

  // The config must outlive the protocol.
  TargetProtocol(const Config& config, Options options);

  void Start(double now_s);
  void OnState(const StateMsg& msg, const SenderKey& from, double now_s);
  // An agent's state writer's liveliness changed.
  void OnWriterLiveliness(const SenderKey& writer, bool alive, double now_s);
  // An agent's process ended: the transport found the agent's participant `participant` gone
  // for good (on this host, the kernel released its shared-memory ports' locks;
  // docs/PROTOCOL.md, "A process that ended"). A loss at once, without a grace: a process that
  // is slow keeps its locks. Its state writer is SameProcess with `participant`.
  void OnProcessEnded(const SenderKey& participant, double now_s);
  // The transport knows that the writer `from` may not speak for the agent id `claimed`
  // (docs/SECURITY.md): its state is counted as rejected, reason not_authorised, unused.
  void OnUnauthorised(AgentId claimed, const SenderKey& from);
  // The faults of a held step were applied.
  void OnGo(StepIndex step, double now_s);
  void OnTimer(double now_s);
  // The readers the transport's range writer currently matches. Once reported, the run
  // starts only when it reaches every agent present (a reader in the process of the agent's
  // state writer, SameProcess), so that no first range waits for a
  // discovery repair (docs/PROTOCOL.md, "Start"). Never reported: not checked.
  void OnRangeReaders(std::set<SenderKey> readers);

  std::optional<double> NextDeadline() const;
  std::vector<TargetAction> TakeActions();

  bool finished() const { return phase_ == Phase::kDone; }
  bool started() const { return phase_ != Phase::kWaitingForAgents; }
  // Liveliness lapses that ended within network.liveliness_grace_s: an agent slow, not gone.
  long lapses_forgiven() const { return lapses_.ignored(); }
  long losses_undone() const { return lapses_.losses_undone(); }
  double grace_factor() const { return lapses_.grace_factor(); }
  StepIndex current_step() const { return step_; }
  std::set<AgentId> AliveAgents() const;  // alive with a known state
  // The alive agents its ranges do not reach yet (OnRangeReaders): while it waits for them,
  // what it waits for on its own side of discovery. Empty when the readers were never reported.
  std::set<AgentId> Unreached() const;
  const std::map<std::string, std::int64_t>& rejected_by_reason() const { return rejected_; }

 private:
  // A liveliness change that passed the lapse filter (a loss held for the grace, or a return).
  // why: what the loss line says it came from.
  void ApplyLiveliness(const SenderKey& writer, bool alive, double now_s, const char* why = "liveliness");
  // Acts on the held losses whose grace is over.
  void ConfirmLapses(double now_s);
  std::optional<double> PhaseDeadline() const;
  enum class Phase { kWaitingForAgents, kStepping, kHolding, kApplyingFaults, kDone };
  struct Agent {
    std::optional<SenderKey> writer;
    std::uint64_t instance_token = 0;
    bool alive = false;
    std::optional<StateMsg> latest;
  };

  void Advance(double now_s);
  bool RangesReach(const Agent& agent) const;
  bool StepDone(double now_s) const;
  double StepWait() const;
  // When the wait for the agents last made progress (the start, or a new agent seen).
  double WaitingSince() const;
  bool FaultsApplied(double now_s) const;
  void BeginStep(StepIndex k, double now_s);
  void PublishStep(StepIndex k);
  std::vector<const FaultConfig*> FaultsAt(StepIndex k) const;
  void Reject(const std::string& who, const std::string& reason);
  void Log(LogLevel level, std::string text);
  void Finish(int code, std::string reason);
  bool RealTime() const { return config_.scenario.mode == StepMode::kRealTime; }

  const Config& config_;
  const Options options_;
  TargetCore core_;
  std::vector<TargetAction> actions_;
  Phase phase_ = Phase::kWaitingForAgents;
  double start_s_ = 0.0;
  double last_new_agent_s_ = 0.0;
  std::optional<double> all_lost_since_s_;  // lock-step: when the last agent was lost
  StepIndex first_step_ = 1;
  StepIndex step_ = 0;          // the step published last
  double step_start_s_ = 0.0;   // when it was published (lock-step) / its tick (real time)
  double hold_deadline_s_ = 0.0;
  std::map<AgentId, Agent> agents_;
  std::map<SenderKey, AgentId> writer_ids_;
  LapseFilter lapses_;  // liveliness lapses held for network.liveliness_grace_s
  std::optional<std::set<SenderKey>> range_readers_;  // OnRangeReaders
  std::map<std::string, std::int64_t> rejected_;
  std::set<std::string> logged_once_;
};

}  // namespace deif::protocol
