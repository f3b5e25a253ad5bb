#include "common/protocol/tree_exchange.hpp"

#include <algorithm>
#include <utility>

#include "common/protocol/validation.hpp"

namespace deif::protocol {

namespace {

bool IsMember(const std::vector<AgentId>& members, AgentId id) {
  return std::binary_search(members.begin(), members.end(), id);
}

// The parent of `id` in the tree of every id 1, 2, 3, ... (1 the root): always a lower id.
std::optional<AgentId> IdParent(AgentId id, int fanout) {
  if (id <= 1) return std::nullopt;
  return static_cast<AgentId>((id - 2) / fanout + 1);
}

}  // namespace

std::optional<AgentId> ParentInTree(const std::vector<AgentId>& members, AgentId id, int fanout) {
  if (fanout < 1 || members.empty() || !IsMember(members, id) || id == members.front()) return std::nullopt;
  for (auto up = IdParent(id, fanout); up; up = IdParent(*up, fanout)) {
    if (IsMember(members, *up)) return up;
  }
  return members.front();  // no member above it: under the root
}

TreePlace PlaceInTree(const std::vector<AgentId>& members, AgentId self, int fanout) {
  TreePlace place;
  if (fanout < 1 || !IsMember(members, self)) return place;
  place.parent = ParentInTree(members, self, fanout);
  for (AgentId m : members) {
    if (m != self && ParentInTree(members, m, fanout) == self) place.children.push_back(m);
  }
  return place;
}

std::vector<AgentId> SubtreeOf(const std::vector<AgentId>& members, AgentId id, int fanout) {
  std::vector<AgentId> out;
  if (fanout < 1 || !IsMember(members, id)) return out;
  for (AgentId m : members) {  // ascending
    std::optional<AgentId> at = m;
    while (at && *at > id) at = ParentInTree(members, *at, fanout);  // ancestors have lower ids
    if (at == id) out.push_back(m);
  }
  return out;
}

int HeightInTree(const std::vector<AgentId>& members, AgentId id, int fanout) {
  int height = 0;
  for (AgentId m : SubtreeOf(members, id, fanout)) {
    int hops = 0;
    for (std::optional<AgentId> at = m; at && *at != id; at = ParentInTree(members, *at, fanout)) ++hops;
    height = std::max(height, hops);
  }
  return height;
}

double RelayWaitS(const Config& config, int height, int depth) {
  // In lock-step nothing is gained by forwarding part of a step early: a relay waits for
  // its children up to a quarter of step_timeout_s (a lost child leaves the members sooner).
  // Partial batches and the late ones after them only cost samples.
  if (config.scenario.mode == StepMode::kLockStep) {
    return std::max(config.network.relay_wait_s, 0.25 * config.network.step_timeout_s);
  }
  // Real time: the waits of a relay and of its parent start within a hop of each other (as
  // each hears of the step), so a parent waits one share more than its children. A leaf
  // waits one share for its own contribution.
  const double deadline_s = config.network.deadline_fraction * config.scenario.period_s;
  const double share_s = std::min(config.network.relay_wait_s, deadline_s / (std::max(depth, 1) + 1));
  return std::max(height, 1) * share_s;
}

TreeExchange::TreeExchange(const Config& config, Options options)
    : config_(config),
      options_(options),
      fanout_(EffectiveTreeFanout(config)),
      wait_s_(RelayWaitS(config)),
      // Late ones are gathered for half a wait in lock-step (a sample per late child
      // overran a relay's history between 4 hosts), sent at once in real time, where every
      // hop of delay is a deadline missed (at 10 % loss, 3 hosts, 20 agents: 85 % of the
      // agent-steps complete against 71 %).
      late_gather_s_(config.scenario.mode == StepMode::kLockStep ? 0.5 * RelayWaitS(config) : 0.0),
      // Real time: what comes after its step's deadline is fused late wherever it goes, so it
      // goes with the next batch (at most a period later) rather than as a sample of its own
      // to every agent: at 64 agents on 4 hosts with 5 % loss, most batches down were such
      // samples, and the extra deliveries made the run fall behind and stay behind
      // (docs/BENCHMARKS.md, "Late batches at 64 agents with loss").
      deadline_s_(config.scenario.mode == StepMode::kLockStep
                      ? 0.0
                      : config.network.deadline_fraction * config.scenario.period_s),
      stale_gather_s_(config.scenario.mode == StepMode::kLockStep ? 0.0 : config.scenario.period_s),
      keep_(static_cast<StepIndex>(config.network.history_steps + config.network.fusion_window_steps)),
      parent_lapses_(config.network.liveliness_grace_s, config.network.participant_lease_s) {
  for (AgentId id = 1; id <= static_cast<AgentId>(config.agents.count); ++id) members_.insert(id);
  members_.insert(options_.self);
  given_ = members_;
  sorted_.assign(members_.begin(), members_.end());
  Place();
}

void TreeExchange::Place() {
  place_ = PlaceInTree(sorted_, options_.self, fanout_);
  child_subtrees_.clear();
  for (AgentId child : place_.children) child_subtrees_.push_back(SubtreeOf(sorted_, child, fanout_));
  wait_s_ = RelayWaitS(config_, HeightInTree(sorted_, options_.self, fanout_),
                       HeightInTree(sorted_, sorted_.front(), fanout_));
}

void TreeExchange::SetMembers(std::set<AgentId> members, double now_s) {
  members.insert(options_.self);
  given_ = std::move(members);
  // A silent parent the members lost is gone: nothing left to hold it out of.
  for (auto it = silent_.begin(); it != silent_.end();) {
    it = given_.count(it->first) > 0 ? std::next(it) : silent_.erase(it);
  }
  Rebuild(now_s);
}

void TreeExchange::OnParentLiveliness(AgentId id, bool alive, double now_s) {
  if (silent_.count(id) > 0) {
    // A parent left for its silence, heard on the watch its agent keeps in its partition: it
    // comes back once it has stayed alive for its relay lease and the grace, while the
    // members still have it (CheckSilence). A single message of it that a starved process
    // reads late also says "alive", and the lease runs out again soon after: it was still
    // frozen (docs/SCALING.md, "A parent heard again").
    if (!alive) {
      heard_again_.erase(id);
    } else if (given_.count(id) > 0) {
      heard_again_.emplace(id, now_s + EffectiveRelayLeaseS(config_) + config_.network.liveliness_grace_s);
    }
    CheckSilence(now_s);
    return;
  }
  if (!alive && place_.parent != id) return;  // only its parent's lapses (a return ends any)
  const std::optional<bool> change = parent_lapses_.Report(id, alive, now_s);
  NoteGraceGrown(id);
  if (change && !*change) LeaveSilent(id, now_s);  // no grace
  CheckSilence(now_s);
}

void TreeExchange::NoteGraceGrown(AgentId parent) {
  if (!parent_lapses_.TakeGrown()) return;
  actions_.push_back(tree_action::GraceGrown{parent, parent_lapses_.grace_factor(),
                                             parent_lapses_.GraceNow(config_.network.liveliness_grace_s)});
}

void TreeExchange::OnAway(double now_s, double hold_s) {
  parent_lapses_.HoldUntil(now_s + hold_s);
  // The roll calls and batches queued while it was away come now, in any order: the
  // parent's silence counts from here.
  if (parent_heard_s_ >= 0.0) parent_heard_s_ = now_s;
  roll_calls_unheard_ = 0;
}

void TreeExchange::LeaveSilent(AgentId parent, double now_s) {
  if (place_.parent != parent) return;  // it moved meanwhile
  silent_[parent] = now_s + options_.silent_hold_s;
  Rebuild(now_s, parent);
}

void TreeExchange::CheckSilence(double now_s) {
  for (AgentId parent : parent_lapses_.Due(now_s)) LeaveSilent(parent, now_s);
  bool back = false;
  for (auto it = heard_again_.begin(); it != heard_again_.end();) {
    if (silent_.count(it->first) == 0 || given_.count(it->first) == 0) {
      it = heard_again_.erase(it);  // back already, or the members lost it
      continue;
    }
    if (now_s < it->second) {
      ++it;
      continue;
    }
    // Alive since, and still a member: it only stalled (a process frozen or starved, or
    // renewals lost). It comes back before the end of its hold: meanwhile it took itself
    // for what it was and every agent missed its contribution. The loss counts as undone,
    // so its next lapses are held longer (once: the filter forgets the loss it held).
    const long undone = parent_lapses_.losses_undone();
    parent_lapses_.Report(it->first, true, now_s);
    if (parent_lapses_.losses_undone() == undone) parent_lapses_.NoteUndone(now_s);
    NoteGraceGrown(it->first);
    silent_.erase(it->first);
    ++parents_heard_again_;
    back = true;
    it = heard_again_.erase(it);
  }
  for (auto it = silent_.begin(); it != silent_.end();) {
    if (now_s >= it->second) {
      // Still a member when its hold ends: the parent lived, and the network lost the
      // renewals of its relay writer. Its lapses are held longer from now on (as an agent's
      // of its peers, docs/PROTOCOL.md, "Losses that are undone"). (A parent the members lost
      // left silent_ then, in SetMembers.)
      if (given_.count(it->first) > 0) {
        parent_lapses_.NoteUndone(now_s);
        NoteGraceGrown(it->first);
      }
      it = silent_.erase(it);
      back = true;
    } else {
      ++it;
    }
  }
  if (back) Rebuild(now_s);
}

void TreeExchange::Rebuild(double now_s, std::optional<AgentId> silent) {
  std::set<AgentId> members = given_;
  for (const auto& entry : silent_) members.erase(entry.first);
  members.insert(options_.self);
  if (members == members_) return;
  members_ = std::move(members);
  sorted_.assign(members_.begin(), members_.end());
  const TreePlace old = place_;
  const std::optional<AgentId> old_parent = place_.parent;
  Place();
  const bool new_child = std::any_of(place_.children.begin(), place_.children.end(), [&old](AgentId c) {
    return std::find(old.children.begin(), old.children.end(), c) == old.children.end();
  });
  if (place_.parent != old_parent) {
    actions_.push_back(tree_action::Reparent{place_.parent, silent});
    parent_heard_s_ = -1.0;  // a new parent: its silence counts from the next roll call
    roll_calls_unheard_ = 0;
    deaf_after_s_ = kDeafAfterS;
    // The new parent gets all this agent holds of the kept steps: the old one may have
    // died with it. A new root sends down what it holds and had only sent up.
    SendOutward(Requeue(unsent_up_, &StepState::sent_up, /*skip_from_above=*/true));
  }
  if (new_child) {
    // A new child has none of what this agent sent down before the move. The DDS history of
    // the relay topic (transient local, history_steps samples) gives it what was sent down;
    // this agent sends again only the newest steps, where its own batches may still be on
    // the way. All of the kept steps again was up to history_steps samples in one burst to
    // every child: over shared memory it overran the writer's segment, and a child that
    // lost one of them took nothing more until the writer's history let it go, 50 steps
    // later (docs/BENCHMARKS.md, "Losing a relay or the root at 64 agents").
    const StepIndex recent = static_cast<StepIndex>(config_.network.fusion_window_steps) + 2;
    SendDown(Requeue(unsent_down_, &StepState::sent_down, /*skip_from_above=*/false,
                     newest_ > recent ? newest_ - recent : 0));
  }
  // Children changed: steps waiting on a child that left may be ready now.
  FlushDue(now_s);
}

TreeExchange::StepState* TreeExchange::StateOf(StepIndex step, double now_s) {
  // step >= 1 and 0 <= newest_ <= scenario.steps: the differences cannot overflow.
  if (step < 1 || newest_ - step > keep_ || step - newest_ > keep_) return nullptr;
  StepState& s = steps_[step];
  if (s.first_s < 0.0) {
    s.first_s = now_s;
    unflushed_.insert(step);
  }
  return &s;
}

void TreeExchange::OnRollCall(StepIndex step, const std::vector<AgentId>& roll_call, double now_s) {
  if (step < 1 || step > config_.scenario.steps) return;
  heard_roll_call_ = true;
  if (step > parent_checked_step_) {  // a new step, of which something should come down
    parent_checked_step_ = step;
    CheckParentHeard(now_s);
  }
  newest_ = std::max(newest_, step);
  Trim();
  StepState* s = StateOf(step, now_s);
  if (s == nullptr) return;
  if (!s->roll_call) s->roll_call.emplace(roll_call.begin(), roll_call.end());
  TryFlush(step, now_s);
}

void TreeExchange::CheckParentHeard(double now_s) {
  if (!place_.parent) return;
  if (parent_heard_s_ < 0.0) parent_heard_s_ = now_s;  // the first roll call: counts from now
  // Counted from the first roll call unheard, not from the last batch, and afresh after a
  // gap in the roll calls themselves: after a silence of the whole network (a partition
  // that healed) the roll calls come in a burst, before the parent's batches of their steps.
  if (roll_calls_unheard_ > 0 && now_s - last_roll_call_s_ > kDeafAfterS) roll_calls_unheard_ = 0;
  last_roll_call_s_ = now_s;
  if (roll_calls_unheard_++ == 0) first_unheard_s_ = now_s;
  if (roll_calls_unheard_ < kDeafRollCalls || now_s - first_unheard_s_ < deaf_after_s_) return;
  // Its relay writer lives (no lapse), yet nothing of the last steps came down: this agent's
  // reader of it is made anew, a reader the parent's writer has no record of and that is
  // announced afresh (docs/SCALING.md, "A link down that hears nothing").
  actions_.push_back(tree_action::RemakeLinkDown{*place_.parent, now_s - parent_heard_s_});
  ++links_down_remade_;
  parent_heard_s_ = now_s;
  roll_calls_unheard_ = 0;
  deaf_after_s_ = std::min(kDeafAfterMaxS, 2.0 * deaf_after_s_);
}

void TreeExchange::OnOwn(const ContributionMsg& msg, double now_s) {
  if (msg.step < 1 || msg.step > config_.scenario.steps) return;
  newest_ = std::max(newest_, msg.step);
  Trim();
  StepState* s = StateOf(msg.step, now_s);
  if (s == nullptr) return;
  if (s->items.emplace(options_.self, RelayedContribution{options_.own_writer, msg}).second) {
    unsent_up_.emplace_back(msg.step, options_.self);
    unsent_down_.emplace_back(msg.step, options_.self);
  }
  s->reported.insert(options_.self);
  TryFlush(msg.step, now_s);
  OnTimer(now_s);
}

bool TreeExchange::Take(const RelayedContribution& item, bool from_above, double now_s) {
  const ContributionMsg& msg = item.msg;
  if (!ValidAgentId(msg.agent_id, config_)) {
    actions_.push_back(tree_action::Reject{"unknown_agent_id"});
    return false;
  }
  if (msg.run != options_.run) {
    actions_.push_back(tree_action::Reject{"other_run"});
    return false;
  }
  if (const char* reason = ValidateContributionMsg(msg, config_)) {
    actions_.push_back(tree_action::Reject{reason});
    return false;
  }
  const bool own = msg.agent_id == options_.self && item.origin == options_.own_writer;
  StepState* s = StateOf(msg.step, now_s);
  if (s == nullptr) {
    // Outside the steps relayed: the step protocol decides (it holds a joiner's first steps
    // and drops what is too old or too far ahead).
    if (!own) actions_.push_back(tree_action::Deliver{item});
    return false;
  }
  if (s->items.count(msg.agent_id) > 0) {
    return false;  // a second copy (another path, the DDS history of a new parent)
  }
  s->items.emplace(msg.agent_id, item);
  if (from_above) {
    s->from_above.insert(msg.agent_id);  // the parent has it: never sent back up
  } else {
    unsent_up_.emplace_back(msg.step, msg.agent_id);
  }
  unsent_down_.emplace_back(msg.step, msg.agent_id);
  if (!own) actions_.push_back(tree_action::Deliver{item});
  return true;
}

void TreeExchange::OnBatch(const BatchMsg& batch, double now_s) {
  if (batch.run != options_.run) {
    actions_.push_back(tree_action::Reject{"other_run"});
    return;
  }
  if (!ValidAgentId(batch.sender_id, config_) || batch.sender_id == options_.self) {
    actions_.push_back(tree_action::Reject{"unknown_relay"});
    return;
  }
  if (batch.items.size() > kMaxBatchItems) {
    actions_.push_back(tree_action::Reject{"oversized_batch"});
    return;
  }
  if (batch.step >= 1 && batch.step <= config_.scenario.steps && batch.step > newest_) {
    // The steps relayed follow the batches too, not only this agent's roll calls: an agent
    // that never hears the target (its range reader unmatched) still relays its subtree,
    // and beyond the kept steps it would forward nothing (docs/SCALING.md).
    newest_ = batch.step;
    Trim();
  }
  for (const RelayedContribution& item : batch.items) Take(item, batch.down, now_s);
  if (batch.down && place_.parent == batch.sender_id) {
    parent_heard_s_ = now_s;
    roll_calls_unheard_ = 0;
    deaf_after_s_ = kDeafAfterS;
  }
  if (batch.down) {
    // From the parent: passed on to the children, with what this agent holds, as the
    // actions are taken: the batches of one wake-up go on as one (FlushForwarded).
    forward_down_ = std::max(forward_down_.value_or(0), batch.step);
  } else if (batch.step > 0) {
    if (StepState* s = StateOf(batch.step, now_s)) {
      s->reported.insert(batch.sender_id);
      TryFlush(batch.step, now_s);
    }
  }
  OnTimer(now_s);
}

std::set<AgentId> TreeExchange::Expected(const StepState& s) const {
  std::set<AgentId> expected;
  // Its own contribution if the roll call has it; before the roll call of the step is in,
  // if it ever heard one: an agent that never hears the target makes no contribution, and
  // waiting for it held every step of its subtree back by a relay wait.
  if (s.roll_call ? s.roll_call->count(options_.self) > 0 : heard_roll_call_) expected.insert(options_.self);
  for (std::size_t c = 0; c < place_.children.size(); ++c) {
    const std::vector<AgentId>& below = child_subtrees_[c];
    if (!s.roll_call ||
        std::any_of(below.begin(), below.end(), [&s](AgentId id) { return s.roll_call->count(id) > 0; })) {
      expected.insert(place_.children[c]);
    }
  }
  return expected;
}

std::vector<AgentId> TreeExchange::ChildrenMissing() const {
  std::vector<AgentId> missing;
  if (config_.scenario.mode != StepMode::kLockStep || unflushed_.empty() || place_.children.empty()) return missing;
  const auto it = steps_.find(*unflushed_.begin());
  if (it == steps_.end()) return missing;
  for (AgentId child : Expected(it->second)) {
    if (child != options_.self && it->second.reported.count(child) == 0) missing.push_back(child);
  }
  return missing;
}

std::optional<double> TreeExchange::ChildrenWaitedForFromS(double after_s) const {
  if (ChildrenMissing().empty()) return std::nullopt;
  return steps_.at(*unflushed_.begin()).first_s + after_s;
}

std::set<AgentId> TreeExchange::ChildrenWaitedFor(double now_s, double after_s) const {
  const std::vector<AgentId> missing = ChildrenMissing();
  if (missing.empty() || now_s < steps_.at(*unflushed_.begin()).first_s + after_s) return {};
  return {missing.begin(), missing.end()};
}

void TreeExchange::TryFlush(StepIndex step, double now_s) {
  auto it = steps_.find(step);
  if (it == steps_.end() || Flushed(step)) return;
  StepState& s = it->second;
  const std::set<AgentId> expected = Expected(s);
  const bool all = std::includes(s.reported.begin(), s.reported.end(), expected.begin(), expected.end());
  if (!all && now_s < s.first_s + wait_s_) return;
  unflushed_.erase(step);
  if (!Root() && s.items.empty() && expected.empty()) return;  // nothing the parent waits for
  SendOutward(step);
}

void TreeExchange::SendOutward(StepIndex step) {
  if (Root()) {
    SendDown(step);
    return;
  }
  Send(/*down=*/false, step, Drain(unsent_up_, &StepState::sent_up));
}

void TreeExchange::SendDown(StepIndex step) {
  if (place_.children.empty()) {  // a leaf: nobody to send to (a new child gets it all then)
    unsent_down_.clear();
    return;
  }
  std::vector<RelayedContribution> items = Drain(unsent_down_, &StepState::sent_down);
  if (items.empty()) return;
  Send(/*down=*/true, step, std::move(items));
}

std::vector<RelayedContribution> TreeExchange::Drain(std::vector<std::pair<StepIndex, AgentId>>& queue,
                                                     std::set<AgentId> StepState::*sent) {
  std::vector<RelayedContribution> items;
  for (const auto& [step, id] : queue) {
    auto s = steps_.find(step);
    if (s == steps_.end()) continue;  // trimmed meanwhile
    auto item = s->second.items.find(id);
    if (item != s->second.items.end() && (s->second.*sent).insert(id).second) items.push_back(item->second);
  }
  queue.clear();
  return items;
}

StepIndex TreeExchange::Requeue(std::vector<std::pair<StepIndex, AgentId>>& queue,
                               std::set<AgentId> StepState::*sent, bool skip_from_above, StepIndex from) {
  StepIndex report = 0;
  // What is queued of older steps stays queued.
  queue.erase(std::remove_if(queue.begin(), queue.end(),
                             [from](const std::pair<StepIndex, AgentId>& e) { return e.first >= from; }),
              queue.end());
  for (auto& [step, s] : steps_) {
    if (Flushed(step)) report = step;
    if (step < from) continue;
    (s.*sent).clear();
    for (const auto& entry : s.items) {
      if (!skip_from_above || s.from_above.count(entry.first) == 0) queue.emplace_back(step, entry.first);
    }
  }
  return report;
}

void TreeExchange::Send(bool down, StepIndex step, std::vector<RelayedContribution> items) {
  // In samples of at most kSentBatchItems; the step is reported with the last.
  std::size_t begin = 0;
  do {
    const std::size_t end = std::min(items.size(), begin + kSentBatchItems);
    BatchMsg batch;
    batch.run = options_.run;
    batch.sender_id = options_.self;
    batch.down = down;
    batch.step = end == items.size() ? step : 0;
    batch.items.assign(items.begin() + static_cast<long>(begin), items.begin() + static_cast<long>(end));
    actions_.push_back(tree_action::Send{std::move(batch)});
    begin = end;
  } while (begin < items.size());
}

void TreeExchange::FlushDue(double now_s) {
  // The steps not yet flushed (one or two, of the history_steps kept): a copy, as each
  // flush leaves the set.
  const std::vector<StepIndex> open(unflushed_.begin(), unflushed_.end());
  for (StepIndex step : open) TryFlush(step, now_s);
}

void TreeExchange::OnTimer(double now_s) {
  CheckSilence(now_s);
  FlushDue(now_s);
  // What arrived for steps whose batch is gone goes on soon: in lock-step gathered for
  // half a wait (one late sample, not one per late child); in real time at once while its
  // step's deadline has not passed here, else with the next batch that way (the queue goes
  // whole with any batch), at most stale_gather_s_ later.
  bool late = false;
  bool urgent = config_.scenario.mode == StepMode::kLockStep;
  for (const auto& entry : Root() ? unsent_down_ : unsent_up_) {
    auto s = steps_.find(entry.first);
    if (s != steps_.end() && Flushed(entry.first)) {
      late = true;
      if (now_s < s->second.first_s + deadline_s_) urgent = true;
      if (urgent) break;
    }
  }
  if (!late) {
    late_since_.reset();
    return;
  }
  if (!late_since_) late_since_ = now_s;
  late_gather_now_s_ = urgent ? late_gather_s_ : stale_gather_s_;
  if (now_s >= *late_since_ + late_gather_now_s_) {
    late_since_.reset();
    forward_late_ = true;  // as the actions are taken (FlushForwarded)
  }
}

void TreeExchange::FlushForwarded() {
  if (forward_late_) {
    forward_late_ = false;
    SendOutward(0);
  }
  if (forward_down_) {
    const StepIndex step = *forward_down_;
    forward_down_.reset();
    SendDown(step);
  }
}

std::optional<double> TreeExchange::NextDeadline() const {
  std::optional<double> next;
  if (late_since_) next = *late_since_ + late_gather_now_s_;
  const auto sooner = [&next](double t) {
    if (!next || t < *next) next = t;
  };
  if (const std::optional<double> lapse = parent_lapses_.NextDue()) sooner(*lapse);
  for (const auto& entry : silent_) sooner(entry.second);
  for (const auto& entry : heard_again_) sooner(entry.second);
  for (StepIndex step : unflushed_) {  // each kept, with first_s set (StateOf)
    sooner(steps_.at(step).first_s + wait_s_);
  }
  return next;
}

std::vector<TreeAction> TreeExchange::TakeActions() {
  FlushForwarded();
  std::vector<TreeAction> out;
  out.swap(actions_);
  return out;
}

std::set<AgentId> TreeExchange::silent_parents() const {
  std::set<AgentId> out;
  for (const auto& entry : silent_) out.insert(entry.first);
  return out;
}

std::size_t TreeExchange::kept_items() const {
  std::size_t n = 0;
  for (const auto& entry : steps_) n += entry.second.items.size();
  return n;
}

void TreeExchange::Trim() {
  while (!steps_.empty() && steps_.begin()->first < newest_ - keep_) {
    unflushed_.erase(steps_.begin()->first);
    steps_.erase(steps_.begin());
  }
  // Queued items of steps no longer kept: a root never sends up, a leaf cut off from its
  // parent never sends down, and neither queue may grow with the run.
  const StepIndex oldest = newest_ - keep_;
  for (auto* queue : {&unsent_up_, &unsent_down_}) {
    queue->erase(std::remove_if(queue->begin(), queue->end(),
                                [oldest](const std::pair<StepIndex, AgentId>& e) { return e.first < oldest; }),
                 queue->end());
  }
}

}  // namespace deif::protocol
