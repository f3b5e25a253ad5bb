#include "common/protocol/target_protocol.hpp"

#include <algorithm>
#include <limits>

#include "common/protocol/validation.hpp"

namespace deif::protocol {

namespace {

std::string Describe(const FaultConfig& fault) {
  if (fault.action == FaultAction::kRestartTarget) return "restart the target";
  return std::string(ToString(fault.action)) + " agent " + std::to_string(fault.agent_id);
}

}  // namespace

TargetProtocol::TargetProtocol(const Config& config, Options options)
    : config_(config),
      options_(options),
      core_(config),
      lapses_(config.network.liveliness_grace_s, config.network.participant_lease_s) {}

void TargetProtocol::Start(double now_s) {
  start_s_ = now_s;
  last_new_agent_s_ = now_s;
  Log(LogLevel::kInfo, "waiting for " + std::to_string(config_.agents.count) + " agents");
  Advance(now_s);
}

void TargetProtocol::OnState(const StateMsg& msg, const SenderKey& from, double now_s) {
  if (phase_ == Phase::kDone) return;
  if (msg.run != options_.run) {
    Reject("a process of another run", "other_run");
    return;
  }
  const std::string who = "agent " + std::to_string(msg.agent_id);
  if (const char* reason = ValidateState(msg, config_)) {
    Reject(who, reason);
    return;
  }
  Agent& agent = agents_[msg.agent_id];
  if (!agent.writer) {
    agent.writer = from;
    writer_ids_[from] = msg.agent_id;
    agent.instance_token = msg.instance_token;
  } else if (*agent.writer != from) {
    if (agent.alive && lapses_.Confirm(*agent.writer)) {
      ApplyLiveliness(*agent.writer, false, now_s);  // its lapse was within the grace
    }
    if (agent.alive) {
      Reject(who, "agent_id_clash");  // another live writer holds this id
      return;
    }
    writer_ids_.erase(*agent.writer);
    agent.writer = from;
    writer_ids_[from] = msg.agent_id;
    agent.instance_token = msg.instance_token;
    agent.latest.reset();  // a restarted agent: its new state replaces the old one
    Log(LogLevel::kInfo, who + " restarted (new writer " + ToString(from) + ")");
  }
  if (!agent.latest || msg.step >= agent.latest->step) agent.latest = msg;
  if (!agent.alive) {
    agent.alive = true;
    last_new_agent_s_ = now_s;
    Log(LogLevel::kInfo, who + " seen at step " + std::to_string(msg.step));
  }
  Advance(now_s);
}

void TargetProtocol::OnWriterLiveliness(const SenderKey& writer, bool alive, double now_s) {
  const double grace_s = started() || options_.start_grace_s < 0.0 ? config_.network.liveliness_grace_s
                                                                   : options_.start_grace_s;
  if (const std::optional<bool> change = lapses_.Report(writer, alive, now_s, grace_s)) {
    ApplyLiveliness(writer, *change, now_s);
  }
  if (lapses_.TakeGrown()) {
    const auto bound = writer_ids_.find(writer);
    const std::string who =
        bound != writer_ids_.end() ? "agent " + std::to_string(bound->second) : "an agent's writer";
    Log(LogLevel::kWarn, GraceGrownLine(who, lapses_.grace_factor(), lapses_.GraceNow(grace_s)));
  }
}

void TargetProtocol::OnProcessEnded(const SenderKey& participant, double now_s) {
  std::vector<SenderKey> ended;
  for (const auto& [writer, id] : writer_ids_) {
    const auto agent = agents_.find(id);
    if (agent != agents_.end() && agent->second.alive && SameProcess(writer, participant)) ended.push_back(writer);
  }
  for (const SenderKey& writer : ended) {
    lapses_.Confirm(writer);
    ApplyLiveliness(writer, false, now_s, kProcessEnded);
  }
}

void TargetProtocol::ConfirmLapses(double now_s) {
  for (const SenderKey& writer : lapses_.Due(now_s)) ApplyLiveliness(writer, false, now_s);
}

void TargetProtocol::ApplyLiveliness(const SenderKey& writer, bool alive, double now_s, const char* why) {
  auto bound = writer_ids_.find(writer);
  if (bound == writer_ids_.end()) return;
  Agent& agent = agents_[bound->second];
  if (agent.alive == alive) return;
  agent.alive = alive;
  const std::string who = "agent " + std::to_string(bound->second);
  if (alive) {
    last_new_agent_s_ = now_s;
    Log(LogLevel::kInfo, who + " alive again");
  } else {
    Log(LogLevel::kWarn, who + " lost (" + why + "): not measured or waited for any more");
  }
  Advance(now_s);
}

void TargetProtocol::OnGo(StepIndex step, double now_s) {
  if (phase_ != Phase::kHolding || step != step_) return;
  phase_ = Phase::kApplyingFaults;
  // Half the agents' patience: an agent gives up after network.start_timeout_s without a
  // range, and its last range came before the hold, so the step must go out before that
  // (docs/PROTOCOL.md, "The target", faults).
  hold_deadline_s_ = now_s + 0.5 * config_.network.start_timeout_s;
  Advance(now_s);
}

void TargetProtocol::OnRangeReaders(std::set<SenderKey> readers) { range_readers_ = std::move(readers); }

bool TargetProtocol::RangesReach(const Agent& agent) const {
  if (!range_readers_ || !agent.writer) return true;
  for (const SenderKey& reader : *range_readers_) {
    if (SameProcess(reader, *agent.writer)) return true;
  }
  return false;
}

void TargetProtocol::OnTimer(double now_s) {
  ConfirmLapses(now_s);
  Advance(now_s);
}

std::set<AgentId> TargetProtocol::Unreached() const {
  std::set<AgentId> unreached;
  for (AgentId id : AliveAgents()) {
    if (!RangesReach(agents_.at(id))) unreached.insert(id);
  }
  return unreached;
}

std::set<AgentId> TargetProtocol::AliveAgents() const {
  std::set<AgentId> alive;
  for (const auto& [id, agent] : agents_) {
    if (agent.alive && agent.latest) alive.insert(id);
  }
  return alive;
}

std::vector<TargetAction> TargetProtocol::TakeActions() {
  std::vector<TargetAction> out;
  out.swap(actions_);
  return out;
}

std::optional<double> TargetProtocol::NextDeadline() const {
  const std::optional<double> phase = PhaseDeadline();
  const std::optional<double> lapse = phase_ == Phase::kDone ? std::nullopt : lapses_.NextDue();
  if (phase && lapse) return std::min(*phase, *lapse);
  return phase ? phase : lapse;
}

std::optional<double> TargetProtocol::PhaseDeadline() const {
  const double settle_s = std::max(1.0, 2.0 * config_.network.participant_announcement_s);
  switch (phase_) {
    case Phase::kWaitingForAgents: {
      const double timeout_s = WaitingSince() + config_.network.start_timeout_s;
      // A resuming target also wakes when the agents have settled.
      bool resuming = options_.start_step.has_value();
      for (const auto& [id, agent] : agents_) {
        resuming = resuming || (agent.latest && agent.latest->step > 0);
      }
      const double settled_s = std::max(start_s_, last_new_agent_s_) + settle_s;
      return resuming ? std::min(timeout_s, settled_s) : timeout_s;
    }
    case Phase::kStepping:
      if (RealTime()) {
        return step_start_s_ + config_.scenario.period_s;
      }
      return step_start_s_ + StepWait();
    case Phase::kApplyingFaults:
      return hold_deadline_s_;
    case Phase::kHolding:
    case Phase::kDone:
      break;
  }
  return std::nullopt;
}

// ---------------------------------------------------------------------------------------

void TargetProtocol::Advance(double now_s) {
  for (;;) {
    switch (phase_) {
      case Phase::kWaitingForAgents: {
        const std::set<AgentId> alive = AliveAgents();
        StepIndex newest = 0;
        for (AgentId id : alive) newest = std::max(newest, agents_.at(id).latest->step);
        const bool resuming = options_.start_step.has_value() || newest > 0;
        // A restarted target finds running agents over a few announcements: it waits until
        // no new agent has appeared for a while.
        const double settle_s = std::max(1.0, 2.0 * config_.network.participant_announcement_s);
        // Everyone is here, and every agent hears every other: its reader matched the
        // contribution writers of all (its own included). Agents that do not report it
        // (matched < 0) are not waited for.
        bool all_matched = true;
        for (AgentId id : alive) {
          const int matched = agents_.at(id).latest->matched;
          all_matched = all_matched && (matched < 0 || matched >= config_.agents.count) &&
                        RangesReach(agents_.at(id));
        }
        const bool everyone =
            alive.size() >= static_cast<std::size_t>(config_.agents.count) && all_matched;
        const bool settled = resuming && now_s - start_s_ >= settle_s &&
                             now_s - last_new_agent_s_ >= settle_s && !alive.empty();
        const bool timed_out = now_s - WaitingSince() >= config_.network.start_timeout_s;
        // A real-time target that resumes a run does not start as soon as everyone is
        // here: the agents' newest states (their clock went on meanwhile) may still be in
        // the backlog it is reading, and it must start after the newest.
        const bool wait_for_newest = RealTime() && resuming;
        if ((everyone && !wait_for_newest) || settled || (timed_out && !alive.empty())) {
          // The step after the newest the agents wrote, and never before start_step. In real
          // time the world went on while this target was down, and the agents stepped on
          // their clock: it resumes after the newest they wrote, not at the step it was
          // killed before (docs/PROTOCOL.md, "Resuming in real time"). A target restarted in
          // place is given the step it had reached: the agents it finds may have restarted
          // too and report no step yet (docs/RUNNING.md, "Restarting in place").
          first_step_ = std::max(options_.start_step.value_or(1), newest + 1);
          std::string who;
          for (AgentId id : alive) who += " " + std::to_string(id);
          Log(LogLevel::kInfo, std::to_string(alive.size()) + " of " +
                                   std::to_string(config_.agents.count) + " agents present:" +
                                   who + "; starting at step " + std::to_string(first_step_));
          if (first_step_ > config_.scenario.steps) {
            Finish(kExitOk, "nothing left to do: the agents finished step " + std::to_string(newest));
            return;
          }
          BeginStep(first_step_, now_s);
          continue;
        }
        if (timed_out) {
          Finish(kExitRuntimeError, "no agent appeared within " +
                                        std::to_string(config_.network.start_timeout_s) +
                                        " s (network.start_timeout_s)");
        }
        return;
      }
      case Phase::kStepping: {
        if (!RealTime() && AliveAgents().empty()) {
          // Lock-step: the world waits for its sensors. With every agent lost (a machine
          // starved, or all killed) racing on would leave nothing to rejoin; after
          // start_timeout_s without one the run ends with an error.
          if (!all_lost_since_s_) {
            all_lost_since_s_ = now_s;
            Log(LogLevel::kWarn, "step " + std::to_string(step_) +
                                     ": no agent alive; waiting up to " +
                                     std::to_string(config_.network.start_timeout_s) +
                                     " s (network.start_timeout_s) for one");
          }
          if (now_s - *all_lost_since_s_ >= config_.network.start_timeout_s) {
            Finish(kExitRuntimeError, "no agent alive for " +
                                          std::to_string(config_.network.start_timeout_s) +
                                          " s (network.start_timeout_s) at step " +
                                          std::to_string(step_));
          }
          return;
        }
        all_lost_since_s_.reset();
        if (!StepDone(now_s)) return;
        const StepIndex next = step_ + 1;
        if (next > config_.scenario.steps) {
          Finish(kExitOk, "run over after step " + std::to_string(step_));
          return;
        }
        BeginStep(next, now_s);
        continue;
      }
      case Phase::kApplyingFaults: {
        if (!FaultsApplied(now_s)) return;
        PublishStep(step_);
        phase_ = Phase::kStepping;
        step_start_s_ = now_s;
        continue;
      }
      case Phase::kHolding:
      case Phase::kDone:
        return;
    }
  }
}

double TargetProtocol::WaitingSince() const {
  // The start timeout counts from the last agent that appeared, not from the target's start:
  // on 2 cores 129 processes take 60 to 100 s to discover each other, and a timeout counted
  // from the start began a 128-agent run with 57 agents while the others were still
  // arriving every few seconds (docs/PROTOCOL.md, "The target").
  return std::max(start_s_, last_new_agent_s_);
}

bool TargetProtocol::StepDone(double now_s) const {
  if (RealTime()) return now_s >= step_start_s_ + config_.scenario.period_s;
  for (const auto& [id, agent] : agents_) {
    if (agent.alive && agent.latest && agent.latest->step < step_) {
      if (now_s < step_start_s_ + StepWait()) return false;
    }
  }
  return true;
}

double TargetProtocol::StepWait() const {
  // An agent waits up to step_timeout_s for its peers, then publishes its state: the target
  // waits that long and a lease more, so a late state still lands in this step.
  return config_.network.step_timeout_s + config_.network.liveliness_lease_s;
}

bool TargetProtocol::FaultsApplied(double now_s) const {
  bool applied = true;
  for (const FaultConfig* fault : FaultsAt(step_)) {
    if (fault->action == FaultAction::kRestartTarget) continue;
    auto it = agents_.find(fault->agent_id);
    const bool alive = it != agents_.end() && it->second.alive;
    switch (fault->action) {
      case FaultAction::kKill:
      case FaultAction::kStop:
        applied = applied && !alive;  // its peers must see it gone before the step
        break;
      case FaultAction::kCont:
        // Back, and caught up with the step before this one.
        applied = applied && alive && it->second.latest && it->second.latest->step >= step_ - 1;
        break;
      case FaultAction::kRestartTarget:
        break;
    }
  }
  return applied || now_s >= hold_deadline_s_;
}

std::vector<const FaultConfig*> TargetProtocol::FaultsAt(StepIndex k) const {
  std::vector<const FaultConfig*> faults;
  for (const FaultConfig& fault : config_.faults) {
    if (fault.step != k) continue;
    // A target restarted for this step's fault does not hold for it again.
    if (fault.action == FaultAction::kRestartTarget && options_.start_step &&
        *options_.start_step == k) {
      continue;
    }
    faults.push_back(&fault);
  }
  return faults;
}

void TargetProtocol::BeginStep(StepIndex k, double now_s) {
  // Real time: a step's tick is the previous tick plus one period (no drift); the first
  // step's tick is now.
  const double tick_s = RealTime() && phase_ == Phase::kStepping
                            ? step_start_s_ + config_.scenario.period_s
                            : now_s;
  step_ = k;
  const std::vector<const FaultConfig*> faults = FaultsAt(k);
  if (!faults.empty() && options_.hold_for_faults) {
    std::string text;
    for (const FaultConfig* fault : faults) text += (text.empty() ? "" : "; ") + Describe(*fault);
    actions_.push_back(target_action::Hold{k, text});
    if (!RealTime()) {
      Log(LogLevel::kInfo, "step " + std::to_string(k) + " held for: " + text);
      phase_ = Phase::kHolding;
      return;
    }
  }
  PublishStep(k);
  phase_ = Phase::kStepping;
  step_start_s_ = RealTime() ? tick_s : now_s;
}

void TargetProtocol::PublishStep(StepIndex k) {
  const Vector2 p_true = core_.TruthAt(k);
  const double t_s = core_.TimeAt(k);
  // The roll call: lock-step measures the agents that finished the previous step (those
  // still catching up are told the roll call and follow); real time measures every agent
  // alive, from its latest position.
  std::vector<AgentId> roll_call;
  for (const auto& [id, agent] : agents_) {
    if (!agent.alive || !agent.latest) continue;
    if (RealTime() || agent.latest->step == k - 1) roll_call.push_back(id);
  }
  TruthMsg truth;
  truth.run = options_.run;
  truth.step = k;
  truth.t_s = t_s;
  truth.p_true = p_true;
  actions_.push_back(target_action::PublishTruth{truth});
  actions_.push_back(target_action::WriteTruthRow{TargetRow{k, t_s, p_true}});
  std::size_t next_member = 0;
  for (AgentId id = 1; id <= config_.agents.count; ++id) {
    RangeMsg msg;
    msg.run = options_.run;
    msg.agent_id = id;
    msg.step = k;
    msg.t_s = t_s;
    msg.roll_call = roll_call;
    msg.measured = next_member < roll_call.size() && roll_call[next_member] == id;
    if (msg.measured) {
      ++next_member;
      msg.p_sensor = agents_.at(id).latest->position_m;  // its latest published position
      // eqs (2.1), (5.5): z_j = f(||x - p_j||) + v_j, drawn from (seed, step, id) alone.
      msg.range_m = core_.NoisyRange(k, id, p_true, msg.p_sensor);
      msg.variance_m2 = config_.filter.range_variance_m2;
      actions_.push_back(target_action::WriteRangeRow{
          RangeRow{k, id, msg.range_m, msg.variance_m2, msg.p_sensor}});
    }
    actions_.emplace_back(std::in_place_type<target_action::PublishRange>, target_action::PublishRange{msg});
  }
  if (roll_call.empty() && logged_once_.insert("empty roll call").second) {
    Log(LogLevel::kWarn, "step " + std::to_string(k) + ": no agent alive to measure (logged once)");
  }
}

void TargetProtocol::OnUnauthorised(AgentId claimed, const SenderKey& from) {
  if (phase_ == Phase::kDone) return;
  Reject("agent " + std::to_string(claimed) + " (writer " + ToString(from) + ")", "not_authorised");
}

void TargetProtocol::Reject(const std::string& who, const std::string& reason) {
  ++rejected_["rejected: " + reason];
  if (logged_once_.insert(who + "|" + reason).second) {
    Log(LogLevel::kWarn, "rejected a state from " + who + ": " + reason + " (logged once)");
  }
}

void TargetProtocol::Log(LogLevel level, std::string text) {
  actions_.push_back(target_action::Log{level, std::move(text)});
}

void TargetProtocol::Finish(int code, std::string reason) {
  if (phase_ == Phase::kDone) return;
  phase_ = Phase::kDone;
  actions_.push_back(target_action::Finish{code, std::move(reason)});
}

}  // namespace deif::protocol
