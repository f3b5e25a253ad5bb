#include "common/protocol/agent_protocol.hpp"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <iterator>
#include <limits>

#include "common/core/check.hpp"
#include "common/core/control_law.hpp"
#include "common/protocol/motion.hpp"
#include "common/protocol/validation.hpp"

namespace deif::protocol {

namespace {

bool SameInfoState(const InfoState& a, const InfoState& b) {
  return a.y.size() == b.y.size() && a.Y.rows() == b.Y.rows() && a.y == b.y && a.Y == b.Y;
}

std::string Join(const std::vector<AgentId>& ids) {
  std::string out;
  for (AgentId id : ids) out += (out.empty() ? "" : " ") + std::to_string(id);
  return out;
}

// "agent 3" or "agents 2 4 6": several peers in one line of the log.
std::string AgentsNamed(const std::vector<AgentId>& ids) {
  return (ids.size() == 1 ? "agent " : "agents ") + Join(ids);
}

std::string FormatSeconds(double s) {
  char buffer[32];
  std::snprintf(buffer, sizeof buffer, "%.3f", s);
  return buffer;
}

}  // namespace

AgentProtocol::AgentProtocol(const Config& config, AgentId id, Options options)
    : config_(config),
      id_(id),
      options_(options),
      model_(config.filter.motion_model),
      initial_(ToInfoState(InitialState(config), InitialCovariance(config))),
      gate_sigma_(options.innovation_gate_sigma > 0.0 ? options.innovation_gate_sigma
                                                      : config.filter.innovation_gate_sigma),
      position_m_(Vector2::Zero()),
      angle_rad_(0.0),
      lapses_(config.network.liveliness_grace_s, config.network.participant_lease_s) {
  DEIF_THROW_UNLESS(ValidAgentId(id, config), "agent id " + std::to_string(id) +
                                                  " is outside 1.." +
                                                  std::to_string(config.agents.count));
  angle_rad_ = InitialAngle(config, id);  // about the initial centre
  position_m_ = PointOnCircle(config.agents.initial_centre_m, config.agents.radius_m, angle_rad_);
  written_ = options.resume_after;
}

// ---------------------------------------------------------------------------------------
// Events

void AgentProtocol::Start(double now_s) {
  if (started_) return;
  started_ = true;
  last_target_contact_s_ = now_s;
  // Step 0: where this agent starts, so the target can measure its first range.
  StateMsg msg = MakeState(0, initial_, 0, true);
  msg.alive = config_.agents.count;
  Publish(msg);
}

void AgentProtocol::OnRange(const RangeMsg& msg, const SenderKey& from, double now_s) {
  if (finished_ || !started_) return;
  if (msg.run != options_.run) {
    Reject("a process of another run", "other_run");
    return;
  }
  const char* reason = ValidateRange(msg, config_, id_);
  const bool unusable_measurement = reason != nullptr && IsMeasurementReason(reason);
  if (reason != nullptr && !unusable_measurement) {
    Reject("the target", reason);
    return;
  }
  // One target per run: the first writer of our ranges. Another writer is refused while the
  // first lives; once it is gone, a new one is the restarted target.
  if (!target_writer_) {
    target_writer_ = from;
    Log(LogLevel::kInfo, "target found (writer " + ToString(from) + ")");
  } else if (*target_writer_ != from) {
    if (target_alive_ && lapses_.Confirm(*target_writer_)) {
      ApplyLiveliness(*target_writer_, false, now_s);  // its lapse was within the grace
    }
    if (target_alive_) {
      Reject("a second target", "second_target");
      HoldTargetRange(msg, from);
      return;
    }
    Log(LogLevel::kInfo, "a new target writer " + ToString(from) + " (the target restarted)");
    target_writer_ = from;
  }
  target_alive_ = true;
  if (target_silent_logged_) {
    Log(LogLevel::kInfo, "measurements from the target resumed at step " + std::to_string(msg.step));
  }
  last_target_contact_s_ = now_s;
  target_silent_logged_ = false;
  if (unusable_measurement) {
    // The run's target measured us, but the value cannot be used: the step goes on, and
    // this agent's contribution carries no information (so nobody waits for it).
    Reject("the target", reason);
  }
  // The target measures from a position this process published. A range from the target's
  // history that was measured for an earlier process with our id is stale.
  if (msg.measured && !unusable_measurement && !PublishedPosition(msg.p_sensor)) {
    Drop("the target", "stale_range");
    return;
  }
  const bool opened = !records_.empty() && msg.step <= records_.rbegin()->first;
  if (opened || msg.step <= written_) {
    auto it = records_.find(msg.step);
    if (it == records_.end()) {
      Drop("the target", "range_too_old");
      return;
    }
    const bool opened_on_the_clock = !it->second.roll_call;  // a range sets the roll call
    ApplyRange(it->second, msg, unusable_measurement);
    FollowRollCall(now_s);
    if (finished_) return;
    if (RealTime() && opened_on_the_clock && msg.step == records_.rbegin()->first) {
      // Real time: the newest step's range came after its deadline, so the target's clock
      // runs behind ours (a restarted target keeps its own period's phase): follow it, or
      // every later range would miss its deadline too (docs/PROTOCOL.md, "An agent", clock).
      clock_sync_ = std::make_pair(msg.step, now_s);
    }
    Advance(now_s);
    return;
  }
  if (pending_ranges_.count(msg.step) > 0) {
    Drop("the target", "duplicate_range");
    return;
  }
  pending_ranges_[msg.step] = PendingRange{msg, now_s, unusable_measurement};
  FollowRollCall(now_s);  // before the step in hand is finished: a member may have died in it
  if (finished_) return;
  Advance(now_s);
  if (!finished_) ConfirmLapses(now_s);  // a new roll call: held lapses of peers it leaves out
}

void AgentProtocol::OnContribution(const ContributionMsg& msg, const SenderKey& from,
                                   double now_s) {
  if (finished_ || !started_) return;
  const std::string who = "agent " + std::to_string(msg.agent_id);
  if (msg.run != options_.run) {
    Reject("a process of another run", "other_run");
    return;
  }
  if (!AcceptIdentity(msg, from, now_s)) return;
  if (const char* reason = ValidateContributionMsg(msg, config_)) {
    Reject(who, reason);
    return;
  }
  Peer& peer = peers_[msg.agent_id];
  // A sample from its writer: it lives. Not one relayed by the tree exchange from a writer
  // seen lost: a relay's history holds the contributions of the dead too; its liveliness
  // says when it is back (docs/SCALING.md). Or a contribution to a step the target began
  // after this agent saw it lost (a step more, for a range still on its way): nobody
  // contributes to a step begun after its death. Fast DDS 2.9.1 can leave a live writer
  // lost for good in a reader's view, its returns never reported (docs/FASTDDS_NOTES.md,
  // "Liveliness that does not come back").
  const bool relayed_from_lost = relaying_ && peer.lost_once;
  if (!peer.alive && (!relayed_from_lost || msg.step > peer.lost_in_step + 1)) {
    peer.alive = true;
    ++membership_version_;
    if (relayed_from_lost) {
      Log(LogLevel::kWarn, who + " is alive again: it contributed to step " + std::to_string(msg.step) +
                               ", begun after it was seen lost (its liveliness was not reported back); members now " +
                               std::to_string(Members().size()));
    } else {
      joined_.push_back(msg.agent_id);  // logged with the others of this batch (FlushJoined)
    }
  }
  if (!peer.last_position || peer.last_position->first < msg.step - 1) {
    peer.last_position = std::make_pair(msg.step - 1, msg.p_sensor);
  }
  peer.last_step = std::max(peer.last_step, msg.step);
  if (!ever_opened_ && !run_begun_) {
    // A peer has a step: the target has begun without a range for us, so a target that is up
    // no longer means "wait" (WaitingForTarget); the patience counts from now.
    run_begun_ = true;
    last_target_contact_s_ = now_s;
  }

  Held held;
  held.msg = msg;
  held.contribution.agent_id = msg.agent_id;
  held.contribution.step = msg.step;
  held.contribution.info_vector = msg.info_vector;
  held.contribution.info_matrix = msg.info_matrix;

  auto record = records_.find(msg.step);
  if (record != records_.end()) {
    if (record->second.held.count(msg.agent_id) > 0) {
      Drop(who, "duplicate");
      return;
    }
    Hold(record->second, std::move(held), /*count_late=*/true);
    if (!deferring_) Advance(now_s);
    return;
  }
  if ((!records_.empty() && msg.step < records_.begin()->first) || msg.step <= written_) {
    Drop(who, "too_old");
    return;
  }
  // Ahead of this agent: held. After a freeze longer than the history, the peers' backlog
  // (their last history_steps contributions) can arrive before the target's roll calls of
  // the same steps, i.e. far beyond the last step written or announced; those are the
  // steps this agent resumes at, so they are kept too, but only the newest
  // history_steps + fusion_window_steps + 1 steps beyond that reach (memory stays bounded
  // whatever steps a peer announces); an evicted one is dropped as too_far_ahead.
  StepIndex known = written_;
  if (!pending_ranges_.empty()) known = std::max(known, pending_ranges_.rbegin()->first);
  const StepIndex span = config_.network.history_steps + config_.network.fusion_window_steps;
  const StepIndex reach = known + span;
  auto& slot = early_[msg.step];
  if (slot.count(msg.agent_id) > 0) {
    Drop(who, "duplicate");
    return;
  }
  slot.emplace(msg.agent_id, std::move(held));
  if (ever_opened_) {
    auto first_far = early_.upper_bound(reach);
    while (static_cast<StepIndex>(std::distance(first_far, early_.end())) > span + 1) {
      first_far = DropEarly(first_far, std::next(first_far), "too_far_ahead");
    }
  }
  // Before the first step only the newest few steps are kept (a joining agent starts at the
  // newest step the target announces).
  const std::size_t keep = static_cast<std::size_t>(config_.network.fusion_window_steps) + 2;
  while (!ever_opened_ && early_.size() > keep) DropEarly(early_.begin(), std::next(early_.begin()), "skipped_step");
  if (!deferring_) Advance(now_s);
}

void AgentProtocol::OnContributions(const std::vector<std::pair<ContributionMsg, SenderKey>>& batch,
                                    double now_s) {
  // The same as one OnContribution after another, with one recomputation of the steps they
  // touch instead of one per contribution (a batch of the tree exchange holds N of them).
  deferring_ = relaying_ = true;
  for (const auto& [msg, from] : batch) OnContribution(msg, from, now_s);
  deferring_ = relaying_ = false;
  if (finished_ || !started_) return;
  Advance(now_s);
}

void AgentProtocol::OnWriterLiveliness(const SenderKey& writer, bool alive, double now_s) {
  if (finished_ || !started_) return;
  const bool target = target_writer_ && writer == *target_writer_;
  const double grace_s = target || options_.peer_grace_s < 0.0 ? config_.network.liveliness_grace_s
                                                              : options_.peer_grace_s;
  if (const std::optional<bool> change = lapses_.Report(writer, alive, now_s, grace_s)) {
    ApplyLiveliness(writer, *change, now_s);
  }
  if (lapses_.TakeGrown()) {
    const auto bound = writer_ids_.find(writer);
    const std::string who = target ? "the target"
                            : bound != writer_ids_.end() ? "agent " + std::to_string(bound->second)
                                                         : "a peer's writer";
    Log(LogLevel::kWarn, GraceGrownLine(who, lapses_.grace_factor(), lapses_.GraceNow(grace_s)));
  }
}

void AgentProtocol::OnProcessEnded(const SenderKey& participant, double now_s) {
  if (finished_ || !started_) return;
  std::vector<SenderKey> ended;
  for (const auto& [id, peer] : peers_) {
    if (peer.writer && peer.alive && SameProcess(*peer.writer, participant)) ended.push_back(*peer.writer);
  }
  for (const SenderKey& writer : ended) {
    if (auto bound = writer_ids_.find(writer); bound != writer_ids_.end()) peers_[bound->second].ended = true;
    lapses_.Confirm(writer);
    ApplyLiveliness(writer, false, now_s, kProcessEnded);
    if (finished_) return;
  }
}

std::set<AgentId> AgentProtocol::MembersOutOfRollCall() const {
  std::set<AgentId> out;
  const std::vector<AgentId>* roll_call = NewestRollCall();
  if (roll_call == nullptr) return out;
  for (const auto& [id, peer] : peers_) {
    if (id != id_ && peer.writer && peer.alive && !std::binary_search(roll_call->begin(), roll_call->end(), id)) {
      out.insert(id);
    }
  }
  return out;
}

std::vector<AgentId> AgentProtocol::MissingInOpenStep() const {
  std::vector<AgentId> missing;
  if (RealTime() || !open_ || records_.empty() || finished_) return missing;
  const Record& r = records_.rbegin()->second;
  if (!r.roll_call) return missing;
  for (AgentId id : *r.roll_call) {
    if (id == id_ || r.held.count(id) > 0) continue;
    if (missing.size() == kMaxWaitedFor) return {};  // a slow step, not a death
    missing.push_back(id);
  }
  return missing;
}

std::optional<double> AgentProtocol::WaitedForFromS() const {
  if (MissingInOpenStep().empty()) return std::nullopt;
  return records_.rbegin()->second.start_s + kSuspectAfterS;
}

std::set<AgentId> AgentProtocol::MembersWaitedFor(double now_s) const {
  const std::vector<AgentId> missing = MissingInOpenStep();
  if (missing.empty() || now_s < records_.rbegin()->second.start_s + kSuspectAfterS) return {};
  return {missing.begin(), missing.end()};
}

const std::vector<AgentId>* AgentProtocol::NewestRollCall(StepIndex* step) const {
  // Of a range waiting, or of the newest step.
  if (!pending_ranges_.empty() && !pending_ranges_.rbegin()->second.msg.roll_call.empty()) {
    if (step != nullptr) *step = pending_ranges_.rbegin()->first;
    return &pending_ranges_.rbegin()->second.msg.roll_call;
  }
  if (!records_.empty() && records_.rbegin()->second.roll_call) {
    if (step != nullptr) *step = records_.rbegin()->first;
    return &*records_.rbegin()->second.roll_call;
  }
  return nullptr;
}

void AgentProtocol::FollowRollCall(double now_s) {
  // network.membership: roll_call (docs/PROTOCOL.md, "Membership from the roll call"). The
  // target names in each roll call the agents it hears (their state writers, whose lease and
  // grace it holds, and on one host their processes' port locks), and no peer's liveliness
  // reaches this agent: that roll call is who is a member. A peer it names again is back,
  // unless its process was seen ended, or the roll call is not newer than the step this
  // agent knew of when it lost the peer (a range on its way).
  if (!options_.roll_call_membership || finished_) return;
  StepIndex step = 0;
  const std::vector<AgentId>* roll_call = NewestRollCall(&step);
  if (roll_call == nullptr) return;
  std::vector<std::pair<SenderKey, bool>> changes;
  for (const auto& [id, peer] : peers_) {
    if (id == id_ || !peer.writer) continue;
    const bool named = std::binary_search(roll_call->begin(), roll_call->end(), id);
    if (peer.alive && !named) changes.emplace_back(*peer.writer, false);
    if (!peer.alive && named && !peer.ended && step > peer.lost_in_step) changes.emplace_back(*peer.writer, true);
  }
  if (changes.empty()) return;
  // One line for the peers lost, one for those back (a host cut off takes dozens at once).
  const std::string left_out = "left out of the target's roll call of step " + std::to_string(step);
  const std::string named = "named again in the target's roll call of step " + std::to_string(step);
  std::vector<AgentId> lost, back;
  for (const auto& [writer, alive] : changes) {
    const AgentId id = writer_ids_.at(writer);
    // One that finished the run is logged as having left (ApplyLiveliness).
    const bool left = !alive && peers_.at(id).last_step >= config_.scenario.steps;
    ApplyLiveliness(writer, alive, now_s, alive ? named.c_str() : left_out.c_str(), /*quiet=*/!left);
    if (!left) (alive ? back : lost).push_back(id);
    if (finished_) return;
  }
  const auto line = [this](LogLevel level, const std::vector<AgentId>& ids, const std::string& what) {
    if (!ids.empty()) Log(level, AgentsNamed(ids) + what + "; members now " + std::to_string(MemberCount()));
  };
  line(LogLevel::kWarn, lost, " lost (" + left_out + ")");
  line(LogLevel::kInfo, back, (back.size() == 1 ? " is" : " are") + std::string(" alive again (") + named + ")");
}

void AgentProtocol::ConfirmLapses(double now_s) {
  for (const SenderKey& writer : lapses_.Due(now_s)) {
    if (finished_) return;
    ApplyLiveliness(writer, false, now_s);
  }
  // A held lapse of a peer that the target's newest roll call no longer names ends now: the
  // target, whose view of each agent (its state writer) is renewed at every step, saw it
  // gone too. The longer peer grace only spares peers the rest of the network still hears
  // (docs/PROTOCOL.md, "Renewals that are rare").
  if (!lapses_.NextDue()) return;  // none held: nothing to end (at every range and wake-up)
  const std::vector<AgentId>* roll_call = NewestRollCall();
  if (roll_call == nullptr) return;
  std::vector<SenderKey> gone;
  for (const auto& [id, peer] : peers_) {
    if (peer.writer && peer.alive && std::find(roll_call->begin(), roll_call->end(), id) == roll_call->end() &&
        lapses_.Confirm(*peer.writer)) {
      gone.push_back(*peer.writer);
    }
  }
  for (const SenderKey& writer : gone) {
    if (finished_) return;
    ApplyLiveliness(writer, false, now_s);
  }
}

void AgentProtocol::ApplyLiveliness(const SenderKey& writer, bool alive, double now_s, const char* why,
                                    bool quiet) {
  if (target_writer_ && writer == *target_writer_) {
    target_alive_ = alive;
    LogOnce(alive ? LogLevel::kInfo : LogLevel::kWarn,
            std::string("target ") + (alive ? "alive" : "lost") + std::to_string(written_),
            alive ? "the target is alive" : "the target is lost (liveliness)");
    if (!alive) AdoptHeldTarget(now_s);
    return;
  }
  if (!alive) held_target_ranges_.erase(writer);  // a refused second target that left
  auto bound = writer_ids_.find(writer);
  if (bound == writer_ids_.end()) return;
  Peer& peer = peers_[bound->second];
  if (!peer.writer || *peer.writer != writer || peer.alive == alive) return;
  peer.alive = alive;
  ++membership_version_;
  if (!alive) {
    peer.lost_at_s = now_s;
    peer.lost_once = true;
    peer.lost_in_step = NewestKnownStep();
    if (RealTime()) AskMergeIfWrittenWithout(bound->second);
  }
  if (quiet) return;
  const std::string members = std::to_string(Members().size());
  if (alive) {
    const bool by_liveliness = std::string(why) == "liveliness";
    Log(LogLevel::kInfo, "agent " + std::to_string(bound->second) + " is alive again" +
                             (by_liveliness ? std::string() : " (" + std::string(why) + ")") + "; members now " + members);
  } else if (peer.last_step >= config_.scenario.steps) {
    // Its contribution to the last step arrived: it finished the run and left, it was not
    // lost (a peer that is behind sees the others leave first).
    Log(LogLevel::kInfo, "agent " + std::to_string(bound->second) + " left after the last step; members now " + members);
  } else {
    Log(LogLevel::kWarn, "agent " + std::to_string(bound->second) + " lost (" + why + "); members now " + members);
  }
  Advance(now_s);
}

void AgentProtocol::HoldTargetRange(const RangeMsg& msg, const SenderKey& from) {
  constexpr std::size_t kMaxWriters = 4;  // bounds what a stray writer can make us keep
  if (held_target_ranges_.count(from) == 0 && held_target_ranges_.size() >= kMaxWriters) return;
  std::deque<RangeMsg>& held = held_target_ranges_[from];
  held.push_back(msg);
  while (held.size() > static_cast<std::size_t>(config_.network.history_steps)) held.pop_front();
}

void AgentProtocol::AdoptHeldTarget(double now_s) {
  if (held_target_ranges_.empty()) return;
  // The writer that measured the latest step is the restarted target.
  auto latest = [](const std::deque<RangeMsg>& q) {
    StepIndex k = 0;
    for (const RangeMsg& m : q) k = std::max(k, m.step);
    return k;
  };
  auto best = held_target_ranges_.begin();
  for (auto it = held_target_ranges_.begin(); it != held_target_ranges_.end(); ++it) {
    if (latest(it->second) > latest(best->second)) best = it;
  }
  const SenderKey writer = best->first;
  std::deque<RangeMsg> ranges = std::move(best->second);
  held_target_ranges_.clear();
  Log(LogLevel::kInfo, "the target is lost and another writer's ranges were held: " +
                           std::to_string(ranges.size()) + " of them are used now");
  for (const RangeMsg& msg : ranges) {
    if (finished_) return;
    OnRange(msg, writer, now_s);
  }
}

void AgentProtocol::SetTargetUp(bool range_writer, bool participant, double now_s) {
  // Before the first range, a target of this run that is up is waiting for the other agents
  // (docs/PROTOCOL.md, "An agent"): the patience for the first range counts from when none
  // is up any more, not from this agent's start.
  const bool was_waiting = WaitingForTarget();
  range_writer_matched_ = range_writer;
  target_participant_up_ = participant;
  if (started_ && was_waiting && !WaitingForTarget()) last_target_contact_s_ = now_s;
}

void AgentProtocol::OnTargetParticipant(bool up, double now_s) {
  SetTargetUp(range_writer_matched_, up, now_s);
}

void AgentProtocol::OnPeersMatched(int matched, int range_writers, double now_s) {
  SetTargetUp(range_writers > 0, target_participant_up_, now_s);
  // A match is known to each side only from the other side's announcement: the target's
  // writer may have matched our range reader while our reader has not yet matched the
  // writer, and a range sent then is dropped here until a discovery repair (1 s and more).
  if (range_writers < 1) matched = 0;
  if (matched == matched_) return;
  matched_ = matched;
  if (started_ && !ever_opened_ && !finished_) {
    StateMsg msg = MakeState(0, initial_, 0, true);
    msg.alive = config_.agents.count;
    Publish(msg);
  }
}

void AgentProtocol::OnTimer(double now_s) {
  if (finished_ || !started_) return;
  ConfirmLapses(now_s);
  Advance(now_s);
  if (finished_) return;
  if (WaitingForTarget()) last_target_contact_s_ = now_s;  // it waits for the other agents
  const double silent_s = now_s - last_target_contact_s_;
  if (silent_s < Patience()) return;
  if (!ever_opened_ && run_begun_) {
    Finish(kExitRuntimeError, "no range from the target within " + std::to_string(Patience()) +
                                  " s (network.start_timeout_s + step_timeout_s) of the run's "
                                  "start, while the peers step: the target's ranges do not "
                                  "reach this agent");
  } else if (!ever_opened_) {
    Finish(kExitRuntimeError, "no range from the target within " + std::to_string(Patience()) +
                                  " s (network.start_timeout_s + step_timeout_s); is a target "
                                  "of this run up?");
  } else if (!RealTime()) {
    Finish(kExitRuntimeError, "the target has been silent for " + std::to_string(silent_s) +
                                  " s after step " + std::to_string(written_) +
                                  " (network.start_timeout_s)");
  } else if (!target_silent_logged_) {
    target_silent_logged_ = true;  // real time: keep stepping on the clock
    Log(LogLevel::kWarn, "no measurements from the target since step " + std::to_string(written_) +
                             "; stepping on the clock (prediction only)");
  }
}

std::optional<double> AgentProtocol::NextDeadline() const {
  if (finished_ || !started_) return std::nullopt;
  double t = last_target_contact_s_ + Patience();
  if (target_silent_logged_ || WaitingForTarget()) t = std::numeric_limits<double>::infinity();
  if (open_) {
    t = std::min(t, std::max(records_.rbegin()->second.deadline_s, resumed_until_s_));
  } else if (RealTime() && clock_sync_) {
    t = std::min(t, std::max(ExpectedStart(written_ + 1) + config_.network.deadline_fraction * config_.scenario.period_s,
                             resumed_until_s_));
  }
  if (const std::optional<double> lapse = lapses_.NextDue()) t = std::min(t, *lapse);
  if (!std::isfinite(t)) return std::nullopt;
  return t;
}

std::vector<AgentAction> AgentProtocol::TakeActions() {
  FlushJoined();
  std::vector<AgentAction> out;
  out.swap(actions_);
  return out;
}

std::optional<InfoState> AgentProtocol::PosteriorOf(StepIndex k) const {
  if (k == 0) return initial_;
  auto it = records_.find(k);
  if (it == records_.end() || it->second.awaiting_basis) return std::nullopt;
  return it->second.posterior;
}

int AgentProtocol::MemberCount() const {
  int count = 1;  // this agent
  for (const auto& [peer_id, peer] : peers_) count += peer.writer && peer.alive && peer_id != id_ ? 1 : 0;
  return count;
}

std::set<AgentId> AgentProtocol::Members() const {
  std::set<AgentId> members{id_};
  for (const auto& [peer_id, peer] : peers_) {
    if (peer.writer && peer.alive) members.insert(peer_id);
  }
  return members;
}

// ---------------------------------------------------------------------------------------
// Steps

void AgentProtocol::Advance(double now_s) {
  if (dirty_from_) {  // contributions held by OnContributions, not yet summed
    const StepIndex from = *dirty_from_;
    dirty_from_.reset();
    Recompute(from);
  }
  while (!finished_) {
    if (open_) {
      if (!CanFinish(records_.rbegin()->second, now_s)) break;
      FinishStep(now_s);
      continue;
    }
    const StepIndex next = written_ + 1;
    if (next > config_.scenario.steps) {
      Finish(kExitOk, "run over after step " + std::to_string(written_));
      break;
    }
    DropPendingRanges(pending_ranges_.lower_bound(next));  // steps it skipped (a join, a rejoin)
    const StepIndex gap_limit = next + config_.network.history_steps;
    if (!ever_opened_ || (!pending_ranges_.empty() && pending_ranges_.begin()->first > gap_limit)) {
      if (pending_ranges_.empty()) break;
      // Join, or rejoin after an absence longer than the history, at the newest step the
      // target announced. Without usable history the posterior is adopted from a peer.
      const auto newest = std::prev(pending_ranges_.end());
      const StepIndex k = newest->first;
      const PendingRange range = newest->second;
      DropPendingRanges(newest);  // the older steps announced: skipped
      pending_ranges_.clear();
      if (ever_opened_) {
        Log(LogLevel::kWarn, "missed steps " + std::to_string(next) + ".." + std::to_string(k - 1) +
                                 " (more than network.history_steps): rejoining at step " +
                                 std::to_string(k));
      }
      records_.clear();
      DropEarly(early_.begin(), early_.lower_bound(k), "skipped_step");
      written_ = k - 1;
      needs_basis_ = k > 1;
      OpenStep(k, range, range.arrival_s);
      continue;
    }
    auto it = pending_ranges_.find(next);
    if (it != pending_ranges_.end()) {
      const PendingRange range = it->second;
      pending_ranges_.erase(it);
      OpenStep(next, range, range.arrival_s);
      continue;
    }
    if (!pending_ranges_.empty()) {
      // A later step is announced but this one never will be (the target's history no
      // longer holds it): take the step without a range.
      OpenStep(next, std::nullopt, now_s);
      continue;
    }
    if (RealTime() && clock_sync_) {
      const double start_s = ExpectedStart(next);
      const double deadline_s =
          start_s + config_.network.deadline_fraction * config_.scenario.period_s;
      if (now_s >= deadline_s && now_s >= resumed_until_s_) {
        // Real time: the step's range has not come by its deadline (lost, late, or the
        // target is cut off): the step runs on the clock, and a range that comes later is
        // fused late.
        OpenStep(next, std::nullopt, start_s);
        continue;
      }
    }
    break;
  }
}

void AgentProtocol::OpenStep(StepIndex k, const std::optional<PendingRange>& range,
                             double start_s) {
  Record& r = records_[k];
  r.step = k;
  r.start_s = start_s;
  if (range) {
    r.deadline_s = start_s + (RealTime() ? config_.network.deadline_fraction * config_.scenario.period_s
                                         : config_.network.step_timeout_s);
    if (RealTime()) clock_sync_ = std::make_pair(k, range->arrival_s);
  } else {
    r.deadline_s = RealTime() ? start_s + config_.network.deadline_fraction * config_.scenario.period_s
                              : start_s;
  }
  ever_opened_ = true;
  open_ = true;
  if (range) {
    r.roll_call = range->msg.roll_call;
    if (range->msg.measured) {
      RangeObservation z;
      z.agent_id = id_;
      z.range_m = range->msg.range_m;
      z.variance_m2 = range->msg.variance_m2;
      z.p_sensor = range->msg.p_sensor;
      r.own_range = z;
      r.own_unusable = range->unusable;
    }
  }
  auto early = early_.find(k);
  if (early != early_.end()) {
    for (auto& [peer_id, held] : early->second) {
      if (r.roll_call && !std::binary_search(r.roll_call->begin(), r.roll_call->end(), peer_id)) {
        Reject("agent " + std::to_string(peer_id), "not_in_roll_call");
        continue;
      }
      r.held.emplace(peer_id, std::move(held));
    }
    early_.erase(early);
  }
  if (needs_basis_) {
    r.awaiting_basis = true;
    TryAdopt(r);
    return;
  }
  Recompute(k);
  if (r.own_range) EmitOwnContribution(r);
}

StepIndex AgentProtocol::NewestKnownStep() const {
  StepIndex k = written_;
  if (!records_.empty()) k = std::max(k, records_.rbegin()->first);
  if (!pending_ranges_.empty()) k = std::max(k, pending_ranges_.rbegin()->first);
  return k;
}

bool AgentProtocol::IsComplete(const Record& r) const {
  if (!r.roll_call || r.awaiting_basis) return false;
  for (AgentId id : *r.roll_call) {
    if (r.held.count(id) == 0) return false;
  }
  return true;
}

void AgentProtocol::AskMergeIfWrittenWithout(AgentId lost) {
  // A step already written without the contribution of a member lost only now (in real time
  // a step is written at its deadline, before a peer killed in it is seen lost): what that
  // member sent may have reached some peers only, as in the rule at the write (FinishStep).
  // Real time only: in lock-step such a step was written at the step timeout, and on a lossy
  // link a live peer taken for lost for a moment then asked for merges that a late
  // contribution would have made needless (docs/PROTOCOL.md, "Beyond the history: one
  // merge").
  for (const auto& [step, r] : records_) {
    if (!r.written || !r.roll_call || r.held.count(lost) > 0) continue;
    if (std::find(r.roll_call->begin(), r.roll_call->end(), lost) == r.roll_call->end()) continue;
    merge_pending_ = true;
    Log(LogLevel::kWarn, "step " + std::to_string(step) + " was written without the contribution of agent " +
                             std::to_string(lost) + ", lost since; the next contribution asks the network for a merge");
    return;
  }
}

bool AgentProtocol::MissesALostMember(const Record& r) const {
  for (AgentId id : *r.roll_call) {
    if (id == id_ || r.held.count(id) > 0) continue;
    auto peer = peers_.find(id);
    if (peer != peers_.end() && peer->second.writer && !peer->second.alive) return true;
  }
  return false;
}

double AgentProtocol::OnResumed(double now_s) {
  if (!RealTime()) return 0.0;
  const double hold_s = kResumeShare * config_.network.deadline_fraction * config_.scenario.period_s;
  resumed_until_s_ = std::max(resumed_until_s_, now_s + hold_s);
  return hold_s;
}

bool AgentProtocol::CanFinish(const Record& r, double now_s) const {
  if (IsComplete(r) || (now_s >= r.deadline_s && now_s >= resumed_until_s_)) return true;
  if (RealTime() || r.awaiting_basis) return false;
  if (!r.roll_call) return true;  // lock-step without a range: nobody to wait for
  // Lock-step: wait for every roll-call member, except one seen lost since the step began
  // (it died in the step). One this agent saw lost before was seen alive again by the target,
  // whose roll call is newer: it is waited for (up to the step timeout).
  for (AgentId id : *r.roll_call) {
    if (r.held.count(id) > 0) continue;
    if (id == id_) return false;
    auto peer = peers_.find(id);
    if (peer != peers_.end() && peer->second.writer && !peer->second.alive &&
        peer->second.lost_at_s > r.start_s) {
      continue;
    }
    return false;
  }
  return true;
}

void AgentProtocol::FinishStep(double now_s) {
  Record& r = records_.rbegin()->second;
  if (r.awaiting_basis) {
    bool peers = false;
    if (r.roll_call) {
      for (AgentId member : *r.roll_call) peers = peers || member != id_;
    }
    if (peers) {
      // Joining a running network: no peer's posterior has come yet. This step is
      // skipped (no row: this agent has no estimate worth writing), and the next one tries
      // again; nobody waits for this agent meanwhile (it is not in the roll call).
      LogOnce(LogLevel::kInfo, "joining",
              "joining at step " + std::to_string(r.step) + ": waiting for a peer's posterior "
              "to adopt; no row until then (logged once)");
      for (const auto& [peer_id, held] : r.held) {
        if (peer_id != id_) Drop("agent " + std::to_string(peer_id), "skipped_step");
      }
      written_ = r.step;
      open_ = false;
      records_.erase(r.step);
      return;
    }
    // Alone: nobody to adopt from; continue from this agent's own estimate.
    r.awaiting_basis = false;
    needs_basis_ = false;
    Log(LogLevel::kWarn, "step " + std::to_string(r.step) +
                             ": no peer in the roll call to adopt from; continuing from this "
                             "agent's own estimate");
    Recompute(r.step);
    if (r.own_range && !r.own_sent) EmitOwnContribution(r);
  }
  const bool complete = IsComplete(r);
  if (!complete) ++counters_.deadline_misses;
  if (!complete && r.roll_call && MissesALostMember(r)) {
    // A member died in the step: its contribution may have reached some peers and not
    // others, and nobody will ever repair that. Ask for the merge now rather than when the
    // step leaves the history (docs/PROTOCOL.md, "Beyond the history: one merge"); where
    // every agent misses the same contributions the merge changes nothing.
    merge_pending_ = true;
    Log(LogLevel::kWarn, "step " + std::to_string(r.step) +
                             " written without a lost member's contribution; the next "
                             "contribution asks the network for a merge");
  }
  const int dim = model_.StateDim();
  if (!IsValidInfoState(r.posterior, dim)) {
    // Never publish or write a non-finite estimate: say so and adopt a peer's next time.
    Log(LogLevel::kError, "step " + std::to_string(r.step) +
                              ": the estimate is not finite or not positive definite; "
                              "adopting a peer's posterior at the next step");
    needs_basis_ = true;
    r.written = true;
    written_ = r.step;
    open_ = false;
    records_.clear();
    return;
  }
  const Eif posterior(model_, r.posterior);
  const Vector2 p_estimate = posterior.PositionEstimate();  // x(k|k)
  // The agent moves only at a step it was measured at: an agent left out of the roll call
  // (frozen, rejoining, cut off from the target) holds its position, so whatever order its
  // backlog arrives in, its path is the same.
  if (r.own_range) {
    // The ring of this step: the roll call (or, without one, everyone fused), each at its
    // position of step k-1, the one its range was measured from.
    std::map<AgentId, Vector2> positions;
    positions[id_] = position_m_;
    std::vector<AgentId> ring_ids;
    if (r.roll_call) {
      ring_ids = *r.roll_call;
    } else {
      for (const auto& [peer_id, held] : r.held) ring_ids.push_back(peer_id);
    }
    for (AgentId member : ring_ids) {
      if (member == id_) continue;
      auto held = r.held.find(member);
      if (held != r.held.end()) {
        positions[member] = held->second.msg.p_sensor;
        continue;
      }
      auto peer = peers_.find(member);
      if (peer != peers_.end() && peer->second.last_position) {
        positions[member] = peer->second.last_position->second;
      }
    }
    // Alone: no other member alive here, and none in the ring (a restarted agent that has not
    // yet heard its peers is not alone: the roll call names them).
    const bool alone = MemberCount() == 1 &&
                       std::all_of(ring_ids.begin(), ring_ids.end(), [this](AgentId m) { return m == id_; });
    if (alone != alone_ && config_.agents.control_law != ControlLawKind::kStationary) {
      Log(alone ? LogLevel::kWarn : LogLevel::kInfo,
          alone ? "step " + std::to_string(r.step) +
                      ": alone: one range fixes only the distance to the target; standing still "
                      "(docs/ARCHITECTURE.md, \"A lone agent\")"
                : "step " + std::to_string(r.step) + ": no longer alone; back to the ring");
    }
    alone_ = alone;
    const MotionResult motion = MoveOnRing(config_, id_, p_estimate, position_m_, positions, alone);
    position_m_ = motion.position_m;
    angle_rad_ = motion.angle_rad;
  } else {
    angle_rad_ = AngleAbout(p_estimate, position_m_);
  }

  Publish(MakeState(r.step, r.posterior, r.fused, complete));

  AgentRow row;
  row.step = r.step;
  row.t_s = static_cast<double>(r.step) * config_.scenario.dt_s;
  row.estimate_m = p_estimate;
  row.covariance = posterior.PositionCovariance();
  row.position_m = position_m_;
  row.angle_rad = angle_rad_;
  row.alive = MemberCount();
  row.fused = r.fused;
  row.rejected = static_cast<long>(counters_.rejected);
  row.dropped = static_cast<long>(counters_.dropped);
  row.late = static_cast<long>(counters_.late);
  row.deadline_misses = static_cast<long>(counters_.deadline_misses);
  row.complete = complete;
  actions_.push_back(agent_action::WriteRow{row});
  if (!complete && r.roll_call) {
    std::vector<AgentId> missing;
    for (AgentId id : *r.roll_call) {
      if (r.held.count(id) == 0) missing.push_back(id);
    }
    LogOnce(LogLevel::kWarn, "incomplete",
            "step " + std::to_string(r.step) + ": fused without every member of the roll call "
            "(missing: " + Join(missing) + ") after " + FormatSeconds(now_s - r.start_s) +
            " s (" + (now_s >= r.deadline_s ? "its deadline" : "a member was lost in the step") +
            "); late contributions are fused into their step (logged once)");
  }

  r.written = true;
  written_ = r.step;
  open_ = false;
  Trim();
  if (written_ >= config_.scenario.steps) {
    Finish(kExitOk, "run over after step " + std::to_string(written_));
  }
}

void AgentProtocol::ApplyRange(Record& r, const RangeMsg& msg, bool unusable) {
  if (!r.roll_call) SetRollCall(r, msg.roll_call);
  if (msg.measured && !r.own_range) {
    RangeObservation z;
    z.agent_id = id_;
    z.range_m = msg.range_m;
    z.variance_m2 = msg.variance_m2;
    z.p_sensor = msg.p_sensor;
    r.own_range = z;
    r.own_unusable = unusable;
    if (!r.awaiting_basis) {
      EmitOwnContribution(r);
      if (r.written) {
        LogOnce(LogLevel::kInfo, "late range",
                "step " + std::to_string(r.step) + ": its range came after the step was written; "
                "the contribution is sent late and fused into its step (logged once)");
      }
    }
  }
}

void AgentProtocol::SetRollCall(Record& r, std::vector<AgentId> roll_call) {
  r.roll_call = std::move(roll_call);
  bool changed = false;
  for (auto it = r.held.begin(); it != r.held.end();) {
    if (!std::binary_search(r.roll_call->begin(), r.roll_call->end(), it->first)) {
      Reject("agent " + std::to_string(it->first), "not_in_roll_call");
      it = r.held.erase(it);
      changed = true;
      r.merge_base.reset();  // made from what it held
    } else {
      ++it;
    }
  }
  if (changed) Recompute(r.step);
}

void AgentProtocol::EmitOwnContribution(Record& r) {
  const RangeObservation& z = *r.own_range;
  const Eif prior(model_, r.prior);
  const Vector2 p_pred = prior.PositionEstimate();  // x(k|k-1): the linearisation point
  Contribution c;
  c.agent_id = id_;
  c.step = r.step;
  if (!r.own_unusable) {
    // eqs (4.49)-(4.51) at this agent's own prediction.
    c = ComputeContribution(r.step, z, p_pred, config_.sensing);
  }
  if (gate_sigma_ > 0.0 && !r.own_unusable) {
    // Innovation gate: |z - h(x(k|k-1))| against gate * sqrt(H P(k|k-1) H^T + R).
    RowVector2 H;
    const double innovation = z.range_m - MeasureRange(p_pred, z.p_sensor, config_.sensing, &H);
    const double S = (H * prior.PositionCovariance() * H.transpose())(0, 0) + z.variance_m2;
    const bool failed = innovation * innovation > gate_sigma_ * gate_sigma_ * S;
    gated_in_a_row_ = failed ? gated_in_a_row_ + 1 : 0;
    const auto how_far = [&] {  // only for a range that failed: a string a step costs
      return "step " + std::to_string(r.step) + ": the range " + std::to_string(z.range_m) + " m is " +
             std::to_string(std::abs(innovation) / std::sqrt(S)) + " sigma from the prediction (gate " +
             std::to_string(gate_sigma_) + ")";
    };
    if (failed && gated_in_a_row_ <= kGateRelentsAfter) {
      c.info_vector.setZero();
      c.info_matrix.setZero();
      ++counters_.by_reason["gated: own range failed the innovation gate"];
      LogOnce(LogLevel::kWarn, "gate", how_far() + ": sent as an empty contribution (logged once)");
    } else if (failed) {
      // The estimate is what is wrong (a mirror image that the ranges of some peers fit, or a
      // prior far off): without this, the gate would keep out the one range that disagrees
      // with it for good.
      ++counters_.by_reason["gate relented: own range fused after failing it " +
                            std::to_string(kGateRelentsAfter) + " steps in a row"];
      LogOnce(LogLevel::kWarn, "gate relents",
              how_far() + ", after " + std::to_string(kGateRelentsAfter) +
                  " in a row that failed the gate: the estimate is taken for wrong, and the range is "
                  "fused (logged once)");
    }
  }
  ContributionMsg msg;
  msg.run = options_.run;
  msg.agent_id = id_;
  msg.instance_token = options_.instance_token;
  msg.step = r.step;
  msg.info_vector = c.info_vector;
  msg.info_matrix = c.info_matrix;
  msg.p_sensor = r.own_unusable ? position_m_ : z.p_sensor;
  msg.basis = BaseOf(r);
  msg.merge_request = merge_pending_;
  merge_pending_ = false;
  actions_.push_back(agent_action::PublishContribution{msg});
  r.own_sent = true;
  Held held;
  held.msg = std::move(msg);
  held.contribution = c;
  Hold(r, std::move(held), /*count_late=*/false);
}

bool AgentProtocol::TryAdopt(Record& r) {
  if (!r.awaiting_basis) return false;
  for (const auto& [peer_id, held] : r.held) {
    if (peer_id == id_) continue;
    // The lowest-id contributor of this step: every rejoiner picks the same one.
    r.basis = held.msg.basis;
    r.awaiting_basis = false;
    needs_basis_ = false;
    ++counters_.adoptions;
    Log(LogLevel::kWarn, "step " + std::to_string(r.step) + ": adopted agent " +
                             std::to_string(peer_id) + "'s posterior of step " +
                             std::to_string(r.step - 1) + " (no usable history of its own)");
    Recompute(r.step);
    if (r.own_range && !r.own_sent) EmitOwnContribution(r);
    return true;
  }
  return false;
}

void AgentProtocol::Hold(Record& r, Held held, bool count_late) {
  const AgentId peer_id = held.msg.agent_id;
  if (r.roll_call && !std::binary_search(r.roll_call->begin(), r.roll_call->end(), peer_id)) {
    Reject("agent " + std::to_string(peer_id), "not_in_roll_call");
    return;
  }
  r.held.emplace(peer_id, std::move(held));
  if (r.written && count_late) ++counters_.late;
  if (r.awaiting_basis) {
    TryAdopt(r);
    return;
  }
  if (deferring_) {  // OnContributions: once for the whole batch (Advance, or at its end)
    dirty_from_ = std::min(dirty_from_.value_or(r.step), r.step);
    return;
  }
  Recompute(r.step);
}

InfoState AgentProtocol::BaseOf(Record& r) {
  // A merge requested by any contribution of this step: the covariance intersection of
  // every distinct posterior carried by the step's contributions, folded in ascending id.
  bool merge = false;
  for (const auto& [peer_id, held] : r.held) merge = merge || held.msg.merge_request;
  if (merge && r.merge_base && r.merge_base_held == r.held.size()) return *r.merge_base;
  if (merge) {
    std::vector<const InfoState*> distinct;
    for (const auto& [peer_id, held] : r.held) {
      bool seen = false;
      for (const InfoState* s : distinct) seen = seen || SameInfoState(*s, held.msg.basis);
      if (!seen) distinct.push_back(&held.msg.basis);
    }
    // The fold is a function of the distinct posteriors in this order alone: a contribution
    // that repeats one already held (most of a merged step's: the agents that agreed carry
    // the same posterior) leaves it as it was. In a run that fell behind, many contributions
    // of a merged step come late one by one, and folding them all again for each was a large
    // part of an agent's work (docs/BENCHMARKS.md, "A run that falls behind stays behind").
    const bool same = r.merge_base && r.merge_folded.size() == distinct.size() &&
                      std::equal(distinct.begin(), distinct.end(), r.merge_folded.begin(),
                                 [](const InfoState* a, const InfoState& b) { return SameInfoState(*a, b); });
    if (same) {
      r.merge_base_held = r.held.size();
      return *r.merge_base;
    }
    ++merges_computed_;
    InfoState merged = *distinct.front();
    for (std::size_t i = 1; i < distinct.size(); ++i) {
      merged = CovarianceIntersection(merged, *distinct[i]);
    }
    r.merge_folded.clear();
    for (const InfoState* s : distinct) r.merge_folded.push_back(*s);
    if (!r.merged && distinct.size() > 1) {
      r.merged = true;
      ++counters_.merges;
      Log(LogLevel::kWarn, "step " + std::to_string(r.step) + ": merged " +
                               std::to_string(distinct.size()) +
                               " distinct posteriors by covariance intersection (a peer's "
                               "history lost information)");
    }
    r.merge_base = merged;
    r.merge_base_held = r.held.size();
    return merged;
  }
  if (r.basis) return *r.basis;
  auto previous = records_.find(r.step - 1);
  if (previous != records_.end()) return previous->second.posterior;
  return initial_;  // step 1, or a join without history that found nobody to adopt from
}

void AgentProtocol::Recompute(StepIndex from) {
  for (auto it = records_.lower_bound(from); it != records_.end(); ++it) {
    Record& r = it->second;
    if (r.awaiting_basis) return;
    // The oldest record's predecessor has left the history: its prior stays as it was.
    const bool predecessor_gone = it == records_.begin() && r.step > 1 && !r.basis &&
                                  records_.find(r.step - 1) == records_.end() &&
                                  r.prior.y.size() > 0;
    bool merge = false;
    for (const auto& [peer_id, held] : r.held) merge = merge || held.msg.merge_request;
    if (!predecessor_gone || merge) {
      r.prior = Predict(model_, BaseOf(r));  // eqs (4.45)-(4.46)
    }
    std::vector<Contribution> contributions;
    contributions.reserve(r.held.size());
    for (const auto& [peer_id, held] : r.held) contributions.push_back(held.contribution);
    const InformationSum sum = SumContributions(std::move(contributions));
    // eqs (4.47)-(4.48): y(k|k) = y(k|k-1) + sum_j i_j(k), Y(k|k) = Y(k|k-1) + sum_j I_j(k).
    r.posterior = r.prior;
    r.posterior.y.head<2>() += sum.info_vector;
    r.posterior.Y.topLeftCorner<2, 2>() += sum.info_matrix;
    r.fused = sum.count;
  }
}

void AgentProtocol::Trim() {
  const auto keep = static_cast<std::size_t>(config_.network.history_steps);
  while (records_.size() > keep) {
    const Record& oldest = records_.begin()->second;
    if (!oldest.written) break;
    if (!IsComplete(oldest)) {
      merge_pending_ = true;
      LogOnce(LogLevel::kWarn, "left incomplete",
              "step " + std::to_string(oldest.step) +
                  " left the history without every contribution of its roll call; the next "
                  "contribution asks the network for a merge (logged once)");
    }
    records_.erase(records_.begin());
  }
  if (!records_.empty()) {
    const StepIndex oldest = records_.begin()->first;
    DropEarly(early_.begin(), early_.lower_bound(oldest), "too_old");
  }
}

// ---------------------------------------------------------------------------------------
// Identity, counting, output

bool AgentProtocol::AcceptIdentity(const ContributionMsg& msg, const SenderKey& from,
                                   double now_s) {
  const std::string who = "agent " + std::to_string(msg.agent_id);
  if (!ValidAgentId(msg.agent_id, config_)) {
    Reject(who, "unknown_agent_id");
    return false;
  }
  if (msg.agent_id == id_) {
    Reject(who, "agent_id_clash");  // someone else speaks for this agent's own id
    return false;
  }
  auto bound = writer_ids_.find(from);
  if (bound != writer_ids_.end() && bound->second != msg.agent_id) {
    Reject(who, "agent_id_clash");  // a writer that changes the id it speaks for
    return false;
  }
  Peer& peer = peers_[msg.agent_id];
  if (!peer.writer) {
    peer.writer = from;
    peer.instance_token = msg.instance_token;
    writer_ids_[from] = msg.agent_id;
    return true;
  }
  if (*peer.writer == from) return true;
  // Another writer claims an id: refused while the bound writer lives (impersonation);
  // once it is gone, the new writer is that agent restarted. A bound writer whose lapse is
  // within its grace is taken as gone.
  if (peer.alive && lapses_.Confirm(*peer.writer)) ApplyLiveliness(*peer.writer, false, now_s);
  if (peer.alive && options_.roll_call_membership && msg.step > peer.last_step + 1) {
    // No liveliness says that the bound writer is gone (docs/PROTOCOL.md, "Membership from
    // the roll call"): a writer that speaks for a step past one the bound writer missed is
    // the agent restarted. (A restart that the target saw within its grace of the old
    // writer's lapse keeps the id in every roll call.)
    ApplyLiveliness(*peer.writer, false, now_s, "a new writer speaks for it, and the old one missed a step");
  }
  if (peer.alive) {
    Reject(who, "agent_id_clash");
    return false;
  }
  writer_ids_.erase(*peer.writer);
  peer.writer = from;
  peer.lost_once = false;  // a new writer: the agent restarted
  peer.ended = false;
  peer.instance_token = msg.instance_token;
  writer_ids_[from] = msg.agent_id;
  Log(LogLevel::kInfo, who + " rejoined with a new writer " + ToString(from));
  return true;
}

void AgentProtocol::OnUnauthorised(AgentId claimed, const SenderKey& from) {
  if (finished_) return;
  Reject("agent " + std::to_string(claimed) + " (writer " + ToString(from) + ")", "not_authorised");
}

void AgentProtocol::OnUnknownIdsDropped(long total) {
  if (total <= unknown_ids_dropped_) return;
  const long fresh = total - unknown_ids_dropped_;
  unknown_ids_dropped_ = total;
  Reject("writers of ids outside 1.." + std::to_string(config_.agents.count), "unknown_agent_id", fresh);
}

void AgentProtocol::OnRelayRejected(const std::string& reason, std::int64_t count) {
  if (finished_) return;
  Reject("a relay of the tree exchange", reason, count);
}

std::optional<std::vector<AgentId>> AgentProtocol::RollCallOf(StepIndex k) const {
  if (auto r = records_.find(k); r != records_.end() && r->second.roll_call) return r->second.roll_call;
  if (auto p = pending_ranges_.find(k); p != pending_ranges_.end()) return p->second.msg.roll_call;
  return std::nullopt;
}

std::set<AgentId> AgentProtocol::LostPeers() const {
  std::set<AgentId> lost;
  for (const auto& [id, peer] : peers_) {
    if (peer.writer && !peer.alive) lost.insert(id);
  }
  return lost;
}

void AgentProtocol::Reject(const std::string& who, const std::string& reason, std::int64_t count) {
  counters_.rejected += count;
  counters_.by_reason["rejected: " + reason] += count;
  LogOnce(LogLevel::kWarn, who + "|rejected|" + reason,
          "rejected a message from " + who + ": " + reason + " (logged once)");
}

void AgentProtocol::Drop(const std::string& who, const std::string& reason) {
  ++counters_.dropped;
  ++counters_.by_reason["dropped: " + reason];
  LogOnce(LogLevel::kInfo, who + "|dropped|" + reason,
          "dropped a message from " + who + ": " + reason + " (logged once)");
}

AgentProtocol::EarlyIt AgentProtocol::DropEarly(EarlyIt first, EarlyIt last, const std::string& reason) {
  // Every contribution this agent received is fused, rejected or dropped, and counted: one it
  // will never reach the step of is not lost silently (docs/PROTOCOL.md, "Peer data is
  // untrusted").
  for (auto it = first; it != last; ++it) {
    for (const auto& entry : it->second) Drop("agent " + std::to_string(entry.first), reason);
  }
  return early_.erase(first, last);
}

void AgentProtocol::DropPendingRanges(std::map<StepIndex, PendingRange>::iterator last) {
  for (auto it = pending_ranges_.begin(); it != last; ++it) Drop("the target", "skipped_step");
  pending_ranges_.erase(pending_ranges_.begin(), last);
}

void AgentProtocol::Log(LogLevel level, std::string text) {
  FlushJoined();  // the log keeps the order of events
  actions_.push_back(agent_action::Log{level, std::move(text)});
}

void AgentProtocol::FlushJoined() {
  if (joined_.empty()) return;
  std::string text = AgentsNamed(joined_) + (joined_.size() == 1 ? " is a member" : " are members");
  text += "; members now " + std::to_string(Members().size());
  joined_.clear();
  actions_.push_back(agent_action::Log{LogLevel::kInfo, std::move(text)});
}

void AgentProtocol::LogOnce(LogLevel level, const std::string& key, std::string text) {
  if (logged_once_.insert(key).second) Log(level, std::move(text));
}

void AgentProtocol::Publish(const StateMsg& msg) {
  published_positions_.push_back(msg.position_m);
  const auto keep = static_cast<std::size_t>(2 * config_.network.history_steps + 4);
  if (published_positions_.size() > keep) {
    published_positions_.erase(published_positions_.begin(),
                               published_positions_.end() - static_cast<std::ptrdiff_t>(keep));
  }
  actions_.push_back(agent_action::PublishState{msg});
}

void AgentProtocol::Finish(int code, std::string reason) {
  if (finished_) return;
  finished_ = true;
  open_ = false;
  actions_.push_back(agent_action::Finish{code, std::move(reason)});
}

StateMsg AgentProtocol::MakeState(StepIndex step, const InfoState& posterior, int fused,
                                  bool complete) const {
  const Eif filter(model_, posterior);
  StateMsg msg;
  msg.run = options_.run;
  msg.agent_id = id_;
  msg.instance_token = options_.instance_token;
  msg.step = step;
  msg.position_m = position_m_;
  msg.angle_rad = angle_rad_;
  msg.estimate_m = filter.PositionEstimate();
  msg.covariance = filter.PositionCovariance();
  msg.alive = MemberCount();
  msg.fused = fused;
  msg.complete = complete;
  msg.deadline_misses = counters_.deadline_misses;
  msg.rejected = counters_.rejected;
  msg.dropped = counters_.dropped;
  msg.matched = matched_;
  return msg;
}

bool AgentProtocol::PublishedPosition(const Vector2& p) const {
  return std::find(published_positions_.begin(), published_positions_.end(), p) !=
         published_positions_.end();
}

double AgentProtocol::Patience() const {
  // Before its first range an agent also allows the target its own start timeout and a step.
  return config_.network.start_timeout_s + (ever_opened_ ? 0.0 : config_.network.step_timeout_s);
}

double AgentProtocol::ExpectedStart(StepIndex k) const {
  return clock_sync_->second +
         static_cast<double>(k - clock_sync_->first) * config_.scenario.period_s;
}

}  // namespace deif::protocol
