// The tree exchange of contributions (docs/SCALING.md, network.exchange: tree) as a pure
// state machine, like AgentProtocol: events in (this agent's own contribution, a batch from
// a child or from the parent, a roll call, the members, the clock), actions out (send a
// batch up or down, hand a contribution to the step protocol, move to another parent).
//
// The members form a tree (PlaceInTree below): that of every id of the run with fan-out F,
// in which a lost member's children hang under its parent. Every agent computes it from the
// same membership, so no election is needed. A step's contributions go up, each relay sending
// its subtree's as one batch once it holds its own and one batch of the step from each
// child that has a measured agent below it (or after its wait, RelayWaitS, whichever comes
// first); the root sends all of them down as one batch, which every relay passes on to its
// children. So a step costs 2 (N - 1) deliveries instead of N (N - 1).
//
// Contributions are forwarded unchanged, never summed: each reaches every agent's step
// protocol (AgentProtocol::OnContribution), which validates it and fuses it in ascending id
// exactly as when it comes direct, so the estimates are those of the all-to-all exchange,
// bit for bit. What comes after a relay's batch of its step is forwarded as it arrives.
// When the tree changes (a member lost or back), a relay with a new parent sends it what it
// holds of the steps it keeps; the DDS history of the relay topics (transient local) gives a
// new child what its new parent sent before.
#pragma once

#include <cstdint>
#include <map>
#include <optional>
#include <set>
#include <string>
#include <utility>
#include <variant>
#include <vector>

#include "common/config/config.hpp"
#include "common/protocol/lapse_filter.hpp"
#include "common/protocol/messages.hpp"

namespace deif::protocol {

// The tree of the members (ascending ids) is the tree of every id 1, 2, 3, ... with fan-out
// F (id i's parent is id (i - 2) / F + 1), in which a member's parent is its nearest
// ancestor that is a member, and a member with none hangs under the lowest member, the root.
// So a lost member moves only its own children (to its parent), and the rest of the tree
// stands: each move is announced to every participant (docs/SCALING.md).
// The parent of member `id`; nullopt for the root, or when `id` is not a member.
std::optional<AgentId> ParentInTree(const std::vector<AgentId>& members, AgentId id, int fanout);
// An agent's place in the tree of `members` (`self` among them).
struct TreePlace {
  std::optional<AgentId> parent;  // nullopt: the root
  std::vector<AgentId> children;
};
TreePlace PlaceInTree(const std::vector<AgentId>& members, AgentId self, int fanout);
// The ids of the subtree under `id` (itself included, ascending); empty if `id` is not a member.
std::vector<AgentId> SubtreeOf(const std::vector<AgentId>& members, AgentId id, int fanout);
// The height of `id` in the tree of `members`: the most hops from a member below it up to it
// (0: a leaf, or not a member). The root's is the depth of the tree.
int HeightInTree(const std::vector<AgentId>& members, AgentId id, int fanout);

// How long a relay of `height` levels above its lowest descendant waits for its children's
// batches of a step, in a tree `depth` levels deep (docs/SCALING.md, "Waiting"). In lock-step
// at least a quarter of network.step_timeout_s, whatever the height. In real time a share of
// the step's deadline per level below it, so that a parent outwaits its children: max(height,
// 1) x min(network.relay_wait_s, deadline / (depth + 1)), the deadline being
// network.deadline_fraction x scenario.period_s; the root's wait leaves a share for the way
// down. (With one wait for every relay, a parent gave up on its children as they gave up on
// theirs, and each late batch that reached the root went down to every agent as one more
// sample: at 56 and 64 agents, 13 to 35 batches down per agent and step instead of 1.)
double RelayWaitS(const Config& config, int height = 1, int depth = 1);

namespace tree_action {
struct Send {  // batch.down: to the children (deif/relay_down), else to the parent
  BatchMsg batch;
};
struct Deliver {  // a peer's contribution for the step protocol
  RelayedContribution item;
};
struct Reparent {  // this agent's parent is now `parent` (nullopt: it is the root)
  std::optional<AgentId> parent;
  std::optional<AgentId> silent;  // the parent it left because it fell silent (OnParentLiveliness)
};
// Nothing came down from the parent (alive: no lapse) through TreeExchange::kDeafRollCalls
// roll calls and for `silent_s`: this agent's link down from it is made anew (its reader of
// the relay topic), as after a move.
struct RemakeLinkDown {
  AgentId parent = 0;
  double silent_s = 0.0;
};
// A lapse of the parent's relay writer was undone (it came back, or was still a member when
// its hold ended): lapses of a parent are now held for `factor` x the grace, `grace_s`
// (docs/PROTOCOL.md, "Losses that are undone").
struct GraceGrown {
  AgentId parent = 0;
  double factor = 1.0;
  double grace_s = 0.0;
};
struct Reject {  // an invalid batch or item, counted like any rejected message
  std::string reason;
  std::int64_t count = 1;
};
}  // namespace tree_action

using TreeAction = std::variant<tree_action::Send, tree_action::Deliver, tree_action::Reparent,
                                tree_action::Reject, tree_action::RemakeLinkDown, tree_action::GraceGrown>;

class TreeExchange {
 public:
  struct Options {
    AgentId self = 1;
    RunToken run = 1;
    SenderKey own_writer{};  // this agent's writer of deif/contribution
    // How long a parent that fell silent stays out of this agent's tree: at least until the
    // members would have lost it (the lease of every agent's writers plus the grace), so
    // that a parent that only stalled comes back into the tree then, and a dead one is gone.
    double silent_hold_s = 5.0;
  };
  // The config must outlive the exchange (network.tree_fanout, relay_wait_s, history_steps,
  // fusion_window_steps, agents.count). Starts in the tree of every agent of the run
  // (1..agents.count): the one a run has once all its agents are up, so that relays need
  // not move while discovery goes on (each move is announced to every participant).
  TreeExchange(const Config& config, Options options);

  // The members the tree is made of (this agent is added); a change may move this agent to
  // another parent (a Reparent action, then what it holds is sent to the new one).
  void SetMembers(std::set<AgentId> members, double now_s);
  // The liveliness of agent `id`'s relay writer to its children (network.relay_lease_s)
  // changed. When the parent's lapses and it stays silent for network.liveliness_grace_s
  // more, this agent moves under the next member up at once and leaves the parent out of its
  // tree for silent_hold_s: every agent's membership loses a dead agent only after the
  // lease of every agent's writers, which grows with N (docs/SCALING.md, "Losing a relay").
  // A parent it left so that is alive again for network.relay_lease_s plus the grace,
  // while the members still have it, comes back into its tree then.
  void OnParentLiveliness(AgentId id, bool alive, double now_s);
  // A parent it left for its silence stays out of its tree for silent_hold_s, or until it
  // has been alive again (OnParentLiveliness) for its relay lease plus the grace: the caller
  // keeps listening to the liveliness of the relay writers of these parents (docs/SCALING.md,
  // "A parent heard again").
  std::set<AgentId> silent_parents() const;
  // Silent parents that came back into the tree because they were heard again.
  long parents_heard_again() const { return parents_heard_again_; }
  // This agent itself was away (frozen or starved) until now: a lapse of its parent's relay
  // writer within hold_s from now counts only if it lasts until then (as
  // AgentProtocol::OnAway).
  void OnAway(double now_s, double hold_s);
  // The target's roll call of `step`: which subtrees have a contribution to wait for.
  void OnRollCall(StepIndex step, const std::vector<AgentId>& roll_call, double now_s);
  // This agent's own contribution.
  void OnOwn(const ContributionMsg& msg, double now_s);
  // A batch from a child (up) or from the parent (down).
  void OnBatch(const BatchMsg& batch, double now_s);
  void OnTimer(double now_s);

  // In lock-step, the children whose batch of the oldest step this relay has not sent on yet
  // has not come after_s after it first heard of the step: a child killed during a step
  // would hold the step back by this relay's whole wait (a quarter of step_timeout_s), so the
  // transport looks for the end of their processes (docs/PROTOCOL.md, "A process that
  // ended"). Empty in real time, where the wait is short.
  std::set<AgentId> ChildrenWaitedFor(double now_s, double after_s) const;
  // When ChildrenWaitedFor becomes non-empty if nothing comes meanwhile (nullopt: it will not).
  std::optional<double> ChildrenWaitedForFromS(double after_s) const;
  // When OnTimer should next be called (nullopt: only events move it on).
  std::optional<double> NextDeadline() const;
  // The actions so far. What came down from the parent, and what came late, goes on here:
  // everything that arrived since the last call as one batch each way (at 64 agents in real
  // time, a batch down per late one from each child multiplied down the tree until the run
  // could not keep up; taken after each wake-up's samples, those of one wake-up go as one).
  std::vector<TreeAction> TakeActions();

  // The parent's relay lapses undone (docs/PROTOCOL.md, "Losses that are undone").
  long parent_losses_undone() const { return parent_lapses_.losses_undone(); }
  const TreePlace& place() const { return place_; }
  // A parent that is not silent (its relay writer lives) but from which nothing comes down
  // (docs/SCALING.md, "A link down that hears nothing"): after kDeafRollCalls roll calls
  // over kDeafAfterS, then twice as long after each remake, until a batch comes.
  static constexpr int kDeafRollCalls = 5;
  static constexpr double kDeafAfterS = 1.0;
  static constexpr double kDeafAfterMaxS = 30.0;
  long links_down_remade() const { return links_down_remade_; }
  const std::set<AgentId>& members() const { return members_; }
  // What it holds: contributions of the kept steps, and queued entries not yet sent.
  std::size_t kept_items() const;
  std::size_t queued() const { return unsent_up_.size() + unsent_down_.size(); }

 private:
  struct StepState {
    std::optional<std::set<AgentId>> roll_call;
    std::set<AgentId> reported;  // itself (own contribution) and children that sent step k
    std::map<AgentId, RelayedContribution> items;  // by origin id: the first valid one
    std::set<AgentId> sent_up, sent_down;
    std::set<AgentId> from_above;  // came down from the parent
    double first_s = -1.0;  // when this agent first heard of the step
  };

  bool Root() const { return !place_.parent.has_value(); }
  // The tree of the members less the silent parents; moves this agent if its place changed.
  void Rebuild(double now_s, std::optional<AgentId> silent = std::nullopt);
  void Place();  // place_, child_subtrees_ and wait_s_ from sorted_
  void CheckSilence(double now_s);
  // A GraceGrown action if the parent lapses' factor grew since the last one.
  void NoteGraceGrown(AgentId parent);
  // Lock-step: the children whose batch of the oldest step not yet sent on has not come.
  std::vector<AgentId> ChildrenMissing() const;
  void LeaveSilent(AgentId parent, double now_s);  // if it is still the parent
  // The step's state, or nullptr for a step outside what is kept (too old or too far ahead).
  StepState* StateOf(StepIndex step, double now_s);
  // Stores a new item (false: a duplicate, or not storable) and queues it to be sent down,
  // and up unless it came from above; delivers it unless it is this agent's own.
  bool Take(const RelayedContribution& item, bool from_above, double now_s);
  std::set<AgentId> Expected(const StepState& s) const;
  void TryFlush(StepIndex step, double now_s);
  void FlushDue(double now_s);  // TryFlush of every step not yet flushed
  // Its batch of the step is sent (up, or down from the root).
  bool Flushed(StepIndex step) const { return unflushed_.count(step) == 0; }
  // Sends what is waiting to go outward (up, or down from the root) with `step`.
  void SendOutward(StepIndex step);
  // Sends down the items of every kept step not yet sent down, with `step`.
  void SendDown(StepIndex step);
  void Send(bool down, StepIndex step, std::vector<RelayedContribution> items);
  // The queued items not yet sent that way, marked sent; the queue emptied.
  std::vector<RelayedContribution> Drain(std::vector<std::pair<StepIndex, AgentId>>& queue,
                                         std::set<AgentId> StepState::*sent);
  // Queues again every kept item of the steps from `from` on (but those that came from
  // above, with skip_from_above) as not yet sent that way; returns the newest step whose
  // batch was sent.
  StepIndex Requeue(std::vector<std::pair<StepIndex, AgentId>>& queue, std::set<AgentId> StepState::*sent,
                    bool skip_from_above, StepIndex from = 0);
  void Trim();

  const Config& config_;
  const Options options_;
  const int fanout_;
  double wait_s_;  // RelayWaitS of this agent's place in the tree
  const double late_gather_s_;
  // Real time: a late item of a step whose deadline has passed here (the step's first_s +
  // the deadline) can no longer make that step; it waits for the next batch sent that way,
  // at most stale_gather_s_ (docs/SCALING.md, "Waiting"). 0 in lock-step: unused.
  const double deadline_s_;
  const double stale_gather_s_;
  const StepIndex keep_;  // steps kept behind (and ahead of) the newest roll call

  std::set<AgentId> given_;    // the members as last set (SetMembers)
  std::set<AgentId> members_;  // those of the tree: given_ less the silent parents
  std::map<AgentId, double> silent_;  // a parent that fell silent -> when it may come back
  // A silent parent whose relay writer lives again -> when it comes back if it stays alive.
  std::map<AgentId, double> heard_again_;
  long parents_heard_again_ = 0;
  BasicLapseFilter<AgentId> parent_lapses_;  // the parent's relay writer's lapses, held for the grace
  std::vector<AgentId> sorted_;
  TreePlace place_;
  std::vector<std::vector<AgentId>> child_subtrees_;  // SubtreeOf each of place_.children
  std::map<StepIndex, StepState> steps_;
  std::set<StepIndex> unflushed_;  // the kept steps whose batch is not sent yet (the others are)
  StepIndex newest_ = 0;  // the newest step of a roll call, of this agent's own or of a batch
  bool heard_roll_call_ = false;  // a roll call of the target has reached this agent
  std::optional<double> late_since_;  // late items wait to go on since then
  double late_gather_now_s_ = 0.0;    // ... for this long: late_gather_s_ or stale_gather_s_
  std::optional<StepIndex> forward_down_;  // what came down goes on to the children (the newest step)
  bool forward_late_ = false;              // what came late goes on outward
  void FlushForwarded();                   // both, at TakeActions
  // Items (step, origin id) stored and not yet sent up / down, in arrival order.
  std::vector<std::pair<StepIndex, AgentId>> unsent_up_, unsent_down_;
  std::vector<TreeAction> actions_;
  // What came down from the current parent: when last (or when it became the parent), the
  // roll calls since, and how long a silence makes the link down anew now.
  void CheckParentHeard(double now_s);
  double parent_heard_s_ = -1.0;
  int roll_calls_unheard_ = 0;
  double first_unheard_s_ = 0.0;  // when the first of those came
  double last_roll_call_s_ = 0.0;  // when the newest counted came
  StepIndex parent_checked_step_ = 0;  // the newest roll call counted
  double deaf_after_s_ = kDeafAfterS;
  long links_down_remade_ = 0;
};

}  // namespace deif::protocol
