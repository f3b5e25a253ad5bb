// A scripted network for the protocol tests: a real TargetProtocol and real AgentProtocols
// whose messages wait in one queue until the test delivers them, in order, or holds,
// drops, duplicates or reorders them. Time moves only when the test says so. (PX4's EKF
// fusion-logic tests drive the filter with a sensor simulator the same way.)
#pragma once

#include <deque>
#include <functional>
#include <map>
#include <memory>
#include <string>
#include <variant>
#include <vector>

#include "common/config/config.hpp"
#include "common/protocol/agent_protocol.hpp"
#include "common/protocol/target_protocol.hpp"

namespace deif::testing {

using protocol::AgentProtocol;
using protocol::ContributionMsg;
using protocol::RangeMsg;
using protocol::SenderKey;
using protocol::StateMsg;
using protocol::TargetProtocol;

using Message = std::variant<RangeMsg, ContributionMsg, StateMsg>;
inline constexpr int kTarget = 0;

struct Envelope {
  int from = 0;
  int to = 0;
  Message message;
};

inline SenderKey KeyOf(int node, int incarnation = 0) {
  SenderKey key{};
  key[0] = 0x7e;
  key[1] = static_cast<std::uint8_t>(node);
  key[2] = static_cast<std::uint8_t>(incarnation);
  return key;
}

class ScriptedNetwork {
 public:
  explicit ScriptedNetwork(const std::string& yaml, bool hold_for_faults = false)
      : config(ParseConfig(yaml, "inline")) {
    for (AgentId id = 1; id <= config.agents.count; ++id) {
      agents[id] = MakeAgent(id);
    }
    TargetProtocol::Options options;
    options.run = kRun;
    options.hold_for_faults = hold_for_faults;
    target = std::make_unique<TargetProtocol>(config, options);
  }

  static constexpr protocol::RunToken kRun = 42;
  // AgentProtocol::Options::peer_grace_s of the agents made after it is set (MakeAgent).
  double peer_grace_s = -1.0;
  // Makes every agent anew with this peer grace (before Start).
  void SetPeerGrace(double grace_s) {
    peer_grace_s = grace_s;
    for (auto& [id, agent] : agents) agent = MakeAgent(id);
  }

  // AgentProtocol::Options::roll_call_membership of the agents made after it is set.
  bool roll_call_membership = false;
  // Makes every agent anew with membership from the roll call (before Start): no peer's
  // liveliness reaches an agent then; tell only the target (Liveliness(kTarget, ...)).
  void SetRollCallMembership() {
    roll_call_membership = true;
    for (auto& [id, agent] : agents) agent = MakeAgent(id);
  }

  std::unique_ptr<AgentProtocol> MakeAgent(AgentId id, std::uint64_t token = 0) {
    AgentProtocol::Options options;
    options.run = kRun;
    options.peer_grace_s = peer_grace_s;
    options.roll_call_membership = roll_call_membership;
    options.instance_token = token == 0 ? static_cast<std::uint64_t>(id) : token;
    return std::make_unique<AgentProtocol>(config, id, options);
  }

  void Start() {
    for (auto& [id, agent] : agents) {
      agent->Start(now);
      Collect(id);
    }
    target->Start(now);
    CollectTarget();
  }

  // Freezes agent id (SIGSTOP): nothing reaches it, it sends nothing, and every other node
  // sees its writers lost. Returns the hold for Pump and RunUntil while it stays frozen.
  std::function<bool(const Envelope&)> Freeze(AgentId id) {
    const auto hold = [id](const Envelope& e) { return e.to == id || e.from == id; };
    frozen.insert(id);
    Pump(hold);
    for (const auto& entry : agents) {
      if (entry.first != id) Liveliness(entry.first, id, false);
    }
    Liveliness(kTarget, id, false);
    return hold;
  }

  // What agent id's transport reports it has matched (AgentProtocol::OnPeersMatched).
  void PeersMatched(AgentId id, int matched, int range_writers) {
    agents.at(id)->OnPeersMatched(matched, range_writers, now);
    Collect(id);
  }

  // Delivers queued messages in order until none is left; a message for which `hold`
  // returns true is set aside in `held` instead.
  void Pump(const std::function<bool(const Envelope&)>& hold = nullptr) {
    while (!queue.empty()) {
      Envelope e = std::move(queue.front());
      queue.pop_front();
      if (hold && hold(e)) {
        held.push_back(std::move(e));
        continue;
      }
      Deliver(e);
    }
  }

  // Delivers one envelope now.
  void Deliver(const Envelope& e) {
    if (e.to == kTarget) {
      if (dead.count(kTarget) == 0) {
        target->OnState(std::get<StateMsg>(e.message), KeyOf(e.from, incarnation[e.from]), now);
        CollectTarget();
      }
      return;
    }
    if (dead.count(e.to) > 0) return;
    AgentProtocol& agent = *agents.at(e.to);
    const SenderKey from = KeyOf(e.from, incarnation[e.from]);
    if (const auto* range = std::get_if<RangeMsg>(&e.message)) agent.OnRange(*range, from, now);
    if (const auto* c = std::get_if<ContributionMsg>(&e.message)) agent.OnContribution(*c, from, now);
    Collect(e.to);
  }

  // Delivers contributions to agent `to` at once, as a relay's batch does
  // (AgentProtocol::OnContributions).
  void DeliverBatch(AgentId to, const std::vector<Envelope>& batch) {
    std::vector<std::pair<ContributionMsg, SenderKey>> contributions;
    for (const Envelope& e : batch) {
      contributions.emplace_back(std::get<ContributionMsg>(e.message), KeyOf(e.from, incarnation[e.from]));
    }
    agents.at(to)->OnContributions(contributions, now);
    Collect(to);
  }

  void ReleaseHeld() {
    std::deque<Envelope> release;
    release.swap(held);
    for (Envelope& e : release) queue.push_back(std::move(e));
  }

  // Moves time on and fires every due timer.
  void AdvanceTime(double dt_s) {
    now += dt_s;
    for (auto& [id, agent] : agents) {
      if (dead.count(id) > 0 || frozen.count(id) > 0) continue;
      agent->OnTimer(now);
      Collect(id);
    }
    if (dead.count(kTarget) == 0) {
      target->OnTimer(now);
      CollectTarget();
    }
  }

  // Tells `reader` that `writer`'s liveliness changed.
  void Liveliness(int reader, int writer, bool alive) {
    const SenderKey key = KeyOf(writer, incarnation[writer]);
    if (reader == kTarget) {
      target->OnWriterLiveliness(key, alive, now);
      CollectTarget();
    } else {
      agents.at(reader)->OnWriterLiveliness(key, alive, now);
      Collect(reader);
    }
  }
  // Tells `reader` that the process of `node` ended (the transport saw its ports' locks go).
  void ProcessEnded(int reader, int node) {
    const SenderKey key = KeyOf(node, incarnation[node]);
    if (reader == kTarget) {
      target->OnProcessEnded(key, now);
      CollectTarget();
    } else {
      agents.at(reader)->OnProcessEnded(key, now);
      Collect(reader);
    }
  }
  // Everyone sees `writer` lost (a kill).
  // What it had queued dies with it (its peers see it lost a lease after its last message).
  // lapse = false: nobody sees a lapse (yet).
  void Kill(int node, bool lapse = true) {
    dead.insert(node);
    for (auto it = queue.begin(); it != queue.end();) it = it->from == node ? queue.erase(it) : it + 1;
    if (!lapse) return;
    for (auto& [id, agent] : agents) {
      if (id != node && dead.count(id) == 0) Liveliness(id, node, false);
    }
    if (node != kTarget) Liveliness(kTarget, node, false);
  }

  // Delivers messages one at a time until every live agent wrote `step` (moving time on
  // only when nothing is queued); messages for which `hold` returns true are set aside.
  void RunUntil(StepIndex step, const std::function<bool(const Envelope&)>& hold = nullptr) {
    for (int guard = 0; guard < 1000000; ++guard) {
      bool all = true;
      for (auto& [id, agent] : agents) {
        if (dead.count(id) == 0 && frozen.count(id) == 0 && agent->last_written_step() < step &&
            !agent->finished()) {
          all = false;
        }
      }
      if (all) return;
      if (queue.empty()) {
        AdvanceTime(0.01);
        continue;
      }
      Envelope e = std::move(queue.front());
      queue.pop_front();
      if (hold && hold(e)) {
        held.push_back(std::move(e));
        continue;
      }
      Deliver(e);
    }
  }

  std::vector<ContributionMsg> ContributionsOf(AgentId id) const {
    std::vector<ContributionMsg> out;
    auto it = published_contributions.find(id);
    if (it != published_contributions.end()) out = it->second;
    return out;
  }

  Config config;
  std::map<AgentId, std::unique_ptr<AgentProtocol>> agents;
  std::unique_ptr<TargetProtocol> target;
  std::deque<Envelope> queue;
  std::deque<Envelope> held;
  std::set<int> dead;
  std::set<int> frozen;  // no timers (a SIGSTOPped process); hold its messages yourself
  std::map<int, int> incarnation;
  std::map<AgentId, std::vector<AgentRow>> rows;
  std::map<AgentId, std::vector<ContributionMsg>> published_contributions;
  std::map<AgentId, std::vector<StateMsg>> published_states;
  std::map<AgentId, std::vector<std::string>> logs;
  std::map<AgentId, int> exit_codes;
  std::vector<TargetRow> truth;
  std::vector<RangeRow> ranges;
  std::vector<StepIndex> holds;
  double now = 0.0;

 private:
  void Collect(AgentId id) {
    for (auto& action : agents.at(id)->TakeActions()) {
      if (auto* c = std::get_if<protocol::agent_action::PublishContribution>(&action)) {
        published_contributions[id].push_back(c->msg);
        for (auto& [peer, agent] : agents) {
          if (peer != id) queue.push_back({id, peer, c->msg});
        }
      } else if (auto* s = std::get_if<protocol::agent_action::PublishState>(&action)) {
        published_states[id].push_back(s->msg);
        queue.push_back({id, kTarget, s->msg});
      } else if (auto* r = std::get_if<protocol::agent_action::WriteRow>(&action)) {
        rows[id].push_back(r->row);
      } else if (auto* l = std::get_if<protocol::agent_action::Log>(&action)) {
        logs[id].push_back(l->text);
      } else if (auto* f = std::get_if<protocol::agent_action::Finish>(&action)) {
        exit_codes[id] = f->exit_code;
      }
    }
  }

  void CollectTarget() {
    for (auto& action : target->TakeActions()) {
      if (auto* r = std::get_if<protocol::target_action::PublishRange>(&action)) {
        queue.push_back({kTarget, r->msg.agent_id, r->msg});
      } else if (auto* t = std::get_if<protocol::target_action::WriteTruthRow>(&action)) {
        truth.push_back(t->row);
      } else if (auto* rr = std::get_if<protocol::target_action::WriteRangeRow>(&action)) {
        ranges.push_back(rr->row);
      } else if (auto* h = std::get_if<protocol::target_action::Hold>(&action)) {
        holds.push_back(h->step);
      } else if (auto* l = std::get_if<protocol::target_action::Log>(&action)) {
        logs[kTarget].push_back(l->text);
      } else if (auto* f = std::get_if<protocol::target_action::Finish>(&action)) {
        exit_codes[kTarget] = f->exit_code;
      }
    }
  }
};

}  // namespace deif::testing
