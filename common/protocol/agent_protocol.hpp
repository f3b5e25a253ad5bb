// One agent's step protocol as a pure state machine (docs/PROTOCOL.md): events in (a range,
// a peer's contribution, a writer's liveliness, the clock), actions out (publish, write a
// row, log, finish). The DDS adapter (agent/) and the in-process simulation (common/sim)
// only deliver events and carry out actions, so the protocol is tested here with a scripted
// network that drops, delays, duplicates, reorders and partitions.
//
// What it guarantees (docs/PROTOCOL.md, "Eventual exactness"):
// - The target's roll call tells every agent which contributions step k should have.
// - A contribution that arrives late, within network.history_steps, is fused into the step
//   it belongs to and the estimate is re-propagated to now. Information adds, so the order
//   of arrival does not matter, and sums run in ascending id: once every contribution of a
//   step has reached every agent, all agents hold bit-identical estimates.
// - A step that leaves the history incomplete (a partition longer than the history, a
//   sender that died mid-send) makes the agent ask for a merge; every agent then replaces
//   the posterior of that step's predecessor by the covariance intersection of every
//   distinct posterior carried by that step's contributions: the same rule from the same
//   data at every agent, and never more confident than its inputs.
// - An agent that (re)joins without usable history adopts the posterior carried by the
//   lowest-id contributor of its first step.
#pragma once

#include <cstdint>
#include <deque>
#include <map>
#include <optional>
#include <set>
#include <string>
#include <utility>
#include <variant>
#include <vector>

#include "common/artefacts/artefacts.hpp"
#include "common/config/config.hpp"
#include "common/core/filters.hpp"
#include "common/protocol/lapse_filter.hpp"
#include "common/protocol/messages.hpp"

namespace deif::protocol {

enum class LogLevel { kDebug, kInfo, kWarn, kError };

// Process exit codes shared by every executable (docs/RUNNING.md).
inline constexpr int kExitOk = 0;
inline constexpr int kExitRuntimeError = 1;
inline constexpr int kExitBadConfig = 2;
inline constexpr int kExitDuplicate = 3;  // an agent id (or the run's target) is already live

// The innovation gate relents after this many of an agent's own ranges in a row failed it:
// ranges that keep disagreeing with the prediction say that the estimate is wrong, not the
// ranges, and the next ones are fused until one passes (docs/PROTOCOL.md, "The innovation
// gate").
inline constexpr int kGateRelentsAfter = 5;

// What an agent counted, by reason (reported in summary.json).
struct AgentCounters {
  std::int64_t rejected = 0;         // invalid, hostile or foreign messages
  std::int64_t dropped = 0;          // valid but unusable: too old, too far ahead, duplicate
  std::int64_t late = 0;             // contributions fused after their step's row was written
  std::int64_t deadline_misses = 0;  // rows written without every roll-call contribution
  std::int64_t adoptions = 0;        // posteriors adopted from a peer (rejoin)
  std::int64_t merges = 0;           // covariance-intersection merges applied
  std::map<std::string, std::int64_t> by_reason;  // "rejected: not_psd" -> count
};

// Actions both protocols produce.
struct Log {
  LogLevel level;
  std::string text;
};
struct Finish {  // the process is done (its exit code and why)
  int exit_code;
  std::string reason;
};

namespace agent_action {
using protocol::Finish;
using protocol::Log;
struct PublishContribution {
  ContributionMsg msg;
};
struct PublishState {
  StateMsg msg;
};
struct WriteRow {
  AgentRow row;
};
}  // namespace agent_action

using AgentAction = std::variant<agent_action::PublishContribution, agent_action::PublishState,
                                 agent_action::WriteRow, agent_action::Log, agent_action::Finish>;

class AgentProtocol {
 public:
  struct Options {
    RunToken run = 1;
    std::uint64_t instance_token = 1;  // random per process start (tells restarts apart)
    double innovation_gate_sigma = 0.0;  // 0: config.filter's value
    // A restarted process that appends to its rows: the last step they hold. It never opens
    // a step at or before it, even on a range from the target's history that was measured
    // for its predecessor where this process starts too (the initial position).
    StepIndex resume_after = 0;
    // How long a lapse of a peer's contribution writer is held before it counts as a loss
    // (< 0: network.liveliness_grace_s, as for the target's writer). Longer where those
    // writers renew their liveliness rarely (dds::Timings::peer_grace_s).
    double peer_grace_s = -1.0;
    // network.membership: roll_call (docs/PROTOCOL.md, "Membership from the roll call"): no
    // peer's liveliness reaches this agent; the target's newest roll call says who is a
    // member. A peer it leaves out is lost at once, one it names again is back, and a new
    // writer that speaks for a member is that agent restarted once the bound writer has
    // missed a step.
    bool roll_call_membership = false;
  };

  // The config must outlive the protocol. Throws std::invalid_argument for an id outside
  // 1..agents.count.
  AgentProtocol(const Config& config, AgentId id, Options options);

  // ---- events (now_s: a monotonic clock, the same for every call) ----
  // Publishes the initial state (step 0) so the target knows where this agent is.
  void Start(double now_s);
  void OnRange(const RangeMsg& msg, const SenderKey& from, double now_s);
  void OnContribution(const ContributionMsg& msg, const SenderKey& from, double now_s);
  // Several contributions at once, forwarded by a relay of the tree exchange: the same
  // outcome as OnContribution for each in order, with the estimates recomputed once, except
  // that a contribution of a writer seen lost does not make it a member again (only its
  // liveliness does: a relay's history holds contributions of the dead).
  void OnContributions(const std::vector<std::pair<ContributionMsg, SenderKey>>& batch, double now_s);
  // A remote writer's liveliness changed: a peer's contribution writer, or the target's
  // range writer.
  void OnWriterLiveliness(const SenderKey& writer, bool alive, double now_s);
  // The process of a peer ended: the transport found the peer's participant `participant`
  // gone for good (on this host, the kernel released its shared-memory ports' locks;
  // docs/PROTOCOL.md, "A process that ended"). A loss at once, without a grace: a process that
  // is slow keeps its locks. Its writers are those SameProcess with `participant`.
  void OnProcessEnded(const SenderKey& participant, double now_s);
  // The peers this agent still counts as members that the target's newest roll call leaves
  // out (the target saw them gone, or they are catching up): the transport then looks for
  // the end of their processes more often (docs/PROTOCOL.md, "A process that ended").
  std::set<AgentId> MembersOutOfRollCall() const;
  // In lock-step, the members of the open step's roll call whose contribution has not come
  // kSuspectAfterS after the step opened: a peer killed during a step is waited for by every
  // agent, and the target waits for the agents, so no roll call can leave it out; the
  // transport looks for the end of their processes often too (docs/PROTOCOL.md, "A process
  // that ended"). Empty in real time, where the deadline ends the wait.
  std::set<AgentId> MembersWaitedFor(double now_s) const;
  // When MembersWaitedFor becomes non-empty if nothing comes meanwhile (nullopt: it will not).
  std::optional<double> WaitedForFromS() const;
  static constexpr double kSuspectAfterS = 0.1;
  // More missing than this is a slow step or a batch of the tree still on its way, not a
  // death: nobody is waited for then (looking at dozens of processes every few hundredths of
  // a second would slow a starved host further).
  static constexpr std::size_t kMaxWaitedFor = 4;
  // This process itself was away (frozen or starved; its loop stood still) until now: a
  // lapse of a peer's or the target's writer within hold_s from now counts only if it lasts
  // until then. Its peers were not gone; it read nothing (docs/PROTOCOL.md, "Slow is not
  // gone").
  void OnAway(double now_s, double hold_s) { lapses_.HoldUntil(now_s + hold_s); }
  // This process ran again only now, several periods after its loop should have woken
  // (frozen or starved). What reached its host meanwhile is still in its sockets, and its
  // readers get it only in the moments that follow. In real time no step is written at its
  // deadline, and none opened on the clock, before kResumeShare x the step's deadline from
  // now, so that the steps it slept through are written with what did arrive for them (with
  // one deadline, a relay frozen at 64 agents still wrote 4 of 20 such rows with 3
  // contributions of 64; a host loaded by other work can take longer still; docs/PROTOCOL.md,
  // "Rejoining"). Returns how long it holds them (0 in lock-step, where a step waits for its
  // members anyway).
  double OnResumed(double now_s);
  static constexpr double kResumeShare = 2.0;
  void OnTimer(double now_s);
  // How many peers' contribution writers this agent's transport has matched, and how many
  // range writers its range reader has matched. Before the first step the first is
  // republished in the initial state, as 0 while no range writer is matched, so the target
  // can start only when every agent can hear every other and hears the target
  // (docs/PROTOCOL.md, "Start").
  void OnPeersMatched(int matched, int range_writers, double now_s);
  // Whether the transport sees the run's target process up, before any of its endpoints
  // may exist (a target of a large run takes seconds to make them). Before its first range
  // an agent waits for one while one is up: by this, or by a matched range writer.
  void OnTargetParticipant(bool up, double now_s);
  // The transport knows that the writer `from` may not speak for the agent id `claimed`
  // (with DDS Security its permissions name another id: docs/SECURITY.md): the message is
  // counted as rejected, reason not_authorised, and never used.
  void OnUnauthorised(AgentId claimed, const SenderKey& from);
  // The transport has dropped `total` contributions so far, keyed to ids outside
  // 1..agents.count, before they reached this protocol (a content filter: garbage costs no
  // wake-up). Counted as rejected, reason unknown_agent_id, like those this protocol sees.
  void OnUnknownIdsDropped(long total);
  // The tree exchange (common/protocol/tree_exchange.hpp) refused a batch or a relayed
  // contribution: counted as rejected, with its reason.
  void OnRelayRejected(const std::string& reason, std::int64_t count);

  // When OnTimer should next be called (nullopt: only events can move the protocol on).
  std::optional<double> NextDeadline() const;
  // The actions produced since the last call, in order.
  std::vector<AgentAction> TakeActions();

  bool finished() const { return finished_; }
  AgentId id() const { return id_; }
  StepIndex last_written_step() const { return written_; }
  const AgentCounters& counters() const { return counters_; }
  // Liveliness lapses that ended within network.liveliness_grace_s: a peer slow, not gone.
  long lapses_forgiven() const { return lapses_.ignored(); }
  // Losses undone (the peer or target was back soon after), and how many times its grace a
  // lapse is held now (docs/PROTOCOL.md, "Losses that are undone").
  long losses_undone() const { return lapses_.losses_undone(); }
  double grace_factor() const { return lapses_.grace_factor(); }
  // How many merges by covariance intersection were computed (BaseOf): once per step and
  // distinct set of posteriors its contributions carry, not once per contribution.
  long merges_computed() const { return merges_computed_; }
  const Vector2& position() const { return position_m_; }
  // The posterior of step k while k is within the history.
  std::optional<InfoState> PosteriorOf(StepIndex k) const;
  // Members believed alive: this agent and every bound peer whose contribution writer lives.
  std::set<AgentId> Members() const;
  int MemberCount() const;  // Members().size(), without building the set (each row and state)
  // The roll call of step k as this protocol accepted it from its target (validated, from
  // the bound writer), while k is pending or within the history; nullopt otherwise.
  std::optional<std::vector<AgentId>> RollCallOf(StepIndex k) const;
  // Peers whose bound contribution writer was seen lost and has not come back.
  std::set<AgentId> LostPeers() const;
  // Changes whenever a peer is seen alive or lost (LostPeers and Members may have changed).
  std::uint64_t membership_version() const { return membership_version_; }

 private:
  long merges_computed_ = 0;  // merges_computed()
  // A liveliness change that passed the lapse filter (a loss held for the grace, or a return).
  // why: what the loss line says it came from.
  // quiet: no line in the log (the caller writes one for several peers).
  void ApplyLiveliness(const SenderKey& writer, bool alive, double now_s, const char* why = "liveliness",
                       bool quiet = false);
  // The target's newest roll call this agent holds: of a range waiting, or of the newest
  // step; nullptr before any.
  // step: set to the step of that roll call.
  const std::vector<AgentId>* NewestRollCall(StepIndex* step = nullptr) const;
  void HoldTargetRange(const RangeMsg& msg, const SenderKey& from);
  void AdoptHeldTarget(double now_s);
  // Acts on the held losses whose grace is over.
  void ConfirmLapses(double now_s);
  // network.membership: roll_call: the members follow the newest roll call.
  void FollowRollCall(double now_s);
  // Lock-step: the members of the open step's roll call whose contribution it lacks, if at
  // most kMaxWaitedFor (else, in real time, or with no step open: none).
  std::vector<AgentId> MissingInOpenStep() const;
  // A validated contribution held for its step.
  struct Held {
    ContributionMsg msg;
    Contribution contribution;
  };
  // One step of the history.
  struct Record {
    StepIndex step = 0;
    double start_s = 0.0;
    double deadline_s = 0.0;
    std::optional<std::vector<AgentId>> roll_call;
    std::optional<RangeObservation> own_range;  // when this agent was measured
    bool own_unusable = false;                  // ... but the value failed validation
    bool own_sent = false;
    bool awaiting_basis = false;     // rejoining: no usable posterior of step-1 yet
    std::optional<InfoState> basis;  // replaces the posterior of step-1 (adoption)
    bool merged = false;
    // The merge of the held contributions' posteriors (BaseOf), how many were held when it
    // was made, and the distinct posteriors it folded, in order: held only grows, and every
    // late contribution recomputes the steps after it, so the covariance intersections are
    // made again only when a contribution came that changed what they fold.
    std::optional<InfoState> merge_base;
    std::size_t merge_base_held = 0;
    std::vector<InfoState> merge_folded;
    std::map<AgentId, Held> held;    // ascending id
    InfoState prior;                 // y(k|k-1), Y(k|k-1)
    InfoState posterior;             // y(k|k), Y(k|k)
    int fused = 0;
    bool written = false;
  };
  struct Peer {
    std::optional<SenderKey> writer;  // the bound contribution writer
    std::uint64_t instance_token = 0;
    bool alive = false;
    double lost_at_s = 0.0;  // when it was last seen lost
    bool lost_once = false;  // this writer was seen lost at least once
    std::optional<std::pair<StepIndex, Vector2>> last_position;  // (step, position)
    StepIndex last_step = 0;  // of its newest valid contribution
    StepIndex lost_in_step = 0;  // the newest step this agent knew of when it saw it lost
    bool ended = false;  // its writer's process was seen ended (OnProcessEnded): never back
  };
  struct PendingRange {
    RangeMsg msg;
    double arrival_s = 0.0;
    bool unusable = false;  // measured, but the value failed validation
  };

  // Moves the protocol as far as it can go now.
  void Advance(double now_s);
  void OpenStep(StepIndex k, const std::optional<PendingRange>& range, double start_s);
  bool CanFinish(const Record& r, double now_s) const;
  void FinishStep(double now_s);
  bool IsComplete(const Record& r) const;
  // The newest step this agent knows the target began (opened, or a range waiting).
  StepIndex NewestKnownStep() const;
  // Asks the network for a merge if a written step in the history lacks `lost`'s contribution
  // though its roll call named it (docs/PROTOCOL.md, "Beyond the history: one merge").
  void AskMergeIfWrittenWithout(AgentId lost);
  // Whether a roll-call member whose contribution `r` lacks has been seen lost.
  bool MissesALostMember(const Record& r) const;
  void ApplyRange(Record& r, const RangeMsg& msg, bool unusable);
  void EmitOwnContribution(Record& r);
  bool TryAdopt(Record& r);
  void Recompute(StepIndex from);
  InfoState BaseOf(Record& r);
  void Hold(Record& r, Held held, bool count_late);
  void Trim();
  void SetRollCall(Record& r, std::vector<AgentId> roll_call);

  bool AcceptIdentity(const ContributionMsg& msg, const SenderKey& from, double now_s);
  void Reject(const std::string& who, const std::string& reason, std::int64_t count = 1);
  void Drop(const std::string& who, const std::string& reason);
  // Drops (and counts, under `reason`) the held contributions of early_'s steps in [first, last).
  using EarlyIt = std::map<StepIndex, std::map<AgentId, Held>>::iterator;
  EarlyIt DropEarly(EarlyIt first, EarlyIt last, const std::string& reason);
  // Drops (and counts as skipped_step) the pending ranges before `last`.
  void DropPendingRanges(std::map<StepIndex, PendingRange>::iterator last);
  void FlushJoined();
  void Log(LogLevel level, std::string text);
  void LogOnce(LogLevel level, const std::string& key, std::string text);
  void Publish(const StateMsg& msg);
  void Finish(int code, std::string reason);
  StateMsg MakeState(StepIndex step, const InfoState& posterior, int fused, bool complete) const;
  bool PublishedPosition(const Vector2& p) const;
  double ExpectedStart(StepIndex k) const;
  // How long the target may be silent before this agent gives up (lock-step).
  double Patience() const;
  bool RealTime() const { return config_.scenario.mode == StepMode::kRealTime; }

  const Config& config_;
  const AgentId id_;
  const Options options_;
  const MotionModel model_;
  const InfoState initial_;  // the common prior, posterior of step 0
  const double gate_sigma_;

  bool started_ = false;
  bool finished_ = false;
  std::uint64_t membership_version_ = 0;
  bool deferring_ = false;                // within OnContributions
  bool relaying_ = false;                 // ... whose contributions a relay forwarded
  std::optional<StepIndex> dirty_from_;   // held while deferring, not yet recomputed
  std::vector<AgentAction> actions_;
  // Peers that became members since the last line of the log: one line names them all
  // (FlushJoined), not one line each (63 at every agent when 64 start together).
  std::vector<AgentId> joined_;
  AgentCounters counters_;
  std::set<std::string> logged_once_;

  // Steps: records_ holds the history [oldest, current]; written_ is the last step whose
  // row is written; an open step is records_.rbegin() with !written.
  std::map<StepIndex, Record> records_;
  StepIndex written_ = 0;
  bool open_ = false;
  bool ever_opened_ = false;
  bool needs_basis_ = false;
  bool merge_pending_ = false;
  std::map<StepIndex, PendingRange> pending_ranges_;          // steps not yet opened
  std::map<StepIndex, std::map<AgentId, Held>> early_;        // contributions ahead of us
  std::optional<std::pair<StepIndex, double>> clock_sync_;    // real time: (step, its start)
  double resumed_until_s_ = -1.0;  // OnResumed: no step written or opened by the clock before

  // Motion.
  Vector2 position_m_;
  double angle_rad_;
  bool alone_ = false;        // alone at the last move (docs/ARCHITECTURE.md, "A lone agent")
  int gated_in_a_row_ = 0;    // own ranges that failed the innovation gate in a row
  std::vector<Vector2> published_positions_;  // recent positions, for stale-range detection

  // Peers and the target.
  std::map<AgentId, Peer> peers_;
  std::map<SenderKey, AgentId> writer_ids_;
  LapseFilter lapses_;  // liveliness lapses held for network.liveliness_grace_s
  long unknown_ids_dropped_ = 0;  // by the transport, as last reported
  std::optional<SenderKey> target_writer_;
  bool target_alive_ = false;  // the bound target writer: alive until seen lost
  // Ranges of another writer, refused while the bound target seemed alive: a process frozen
  // while the target restarted hears the new target before it sees the old one lost, and
  // the new one holds its next step until this process catches up (docs/PROTOCOL.md,
  // "Rejoining", "A new target"). Used once the bound target is lost; at most
  // history_steps per writer.
  std::map<SenderKey, std::deque<RangeMsg>> held_target_ranges_;
  int matched_ = -1;
  // Before the first range (docs/PROTOCOL.md, "An agent"): a target of this run is up, and
  // no peer has a step yet, so the target is still waiting for the agents.
  bool range_writer_matched_ = false;  // the range reader has matched a writer (OnPeersMatched)
  bool target_participant_up_ = false;  // OnTargetParticipant
  bool run_begun_ = false;              // a peer's valid contribution arrived
  bool WaitingForTarget() const {
    return !ever_opened_ && !run_begun_ && (range_writer_matched_ || target_participant_up_);
  }
  void SetTargetUp(bool range_writer, bool participant, double now_s);
  double last_target_contact_s_ = 0.0;
  bool target_silent_logged_ = false;
};

}  // namespace deif::protocol
