// The tree exchange (common/protocol/tree_exchange.hpp; docs/SCALING.md): topology, that
// every contribution reaches every agent once with 2 (N - 1) batches a step, late children,
// a lost relay, and bad batches.
#include <catch2/catch.hpp>

#include <algorithm>
#include <map>
#include <memory>
#include <set>
#include <vector>

#include "common/config/config.hpp"
#include "common/protocol/tree_exchange.hpp"

namespace protocol = deif::protocol;
using deif::AgentId;
using deif::StepIndex;
using protocol::BatchMsg;
using protocol::ContributionMsg;
using protocol::TreeExchange;

namespace {

constexpr protocol::RunToken kRun = 77;

// Real time, so that relays wait relay_wait_s (RelayWaitS).
deif::Config ConfigFor(int agents, int fanout, double wait_s = 0.02) {
  return deif::ParseConfig("scenario: {mode: realtime, period_s: 0.1}\nagents: {count: " + std::to_string(agents) +
                               "}\nnetwork: {exchange: tree, tree_fanout: " + std::to_string(fanout) +
                               ", relay_wait_s: " + std::to_string(wait_s) + "}\n",
                           "inline");
}

protocol::SenderKey WriterOf(AgentId id) {
  protocol::SenderKey key{};
  key[0] = static_cast<std::uint8_t>(id);
  key[15] = 0xC0;
  return key;
}

ContributionMsg Contribution(AgentId id, StepIndex step) {
  ContributionMsg c;
  c.run = kRun;
  c.agent_id = id;
  c.instance_token = 1000 + static_cast<std::uint64_t>(id);
  c.step = step;
  c.info_vector << 0.1 * id, -0.2;
  c.info_matrix << 2.0, 0.5, 0.5, 3.0;
  c.p_sensor << 1.0, static_cast<double>(id);
  c.basis.y = deif::StateVector::Zero(2);
  c.basis.Y = deif::StateMatrix::Identity(2, 2);
  return c;
}

std::vector<AgentId> Range(AgentId first, AgentId last) {
  std::vector<AgentId> ids;
  for (AgentId id = first; id <= last; ++id) ids.push_back(id);
  return ids;
}

// Agents wired as their places say: an up batch reaches the sender's parent, a down batch
// each of its children, at once.
struct Network {
  Network(const deif::Config& c, const std::vector<AgentId>& ids) : config(c) {
    for (AgentId id : ids) {
      agents.emplace(id, std::make_unique<TreeExchange>(config, TreeExchange::Options{id, kRun, WriterOf(id)}));
    }
    SetMembers(std::set<AgentId>(ids.begin(), ids.end()), 0.0);
  }
  void SetMembers(const std::set<AgentId>& members, double now_s) {
    for (auto& [id, agent] : agents) {
      if (members.count(id) > 0) agent->SetMembers(members, now_s);
    }
    Pump(now_s);
  }
  // Every live agent's timer at now_s (the waits that are over), then what it sends.
  void Tick(double now_s) {
    for (auto& [id, agent] : agents) {
      if (dead.count(id) == 0) agent->OnTimer(now_s);
    }
    Pump(now_s);
  }
  void Pump(double now_s) {
    for (bool more = true; more;) {
      more = false;
      for (auto& [id, agent] : agents) {
        if (dead.count(id) > 0) {
          agent->TakeActions();
          continue;
        }
        for (protocol::TreeAction& action : agent->TakeActions()) {
          more = true;
          if (auto* send = std::get_if<protocol::tree_action::Send>(&action)) {
            (send->batch.down ? down_samples : up_samples) += 1;
            std::vector<AgentId> to;
            if (send->batch.down) {
              // To whoever has the sender for its parent (a child reads its parent's relay
              // writer), which the sender may not yet count among its children.
              for (auto& [r, other] : agents) {
                if (other->place().parent == id) to.push_back(r);
              }
            } else if (agent->place().parent) {
              to = {*agent->place().parent};
            }
            for (AgentId r : to) {
              if (dead.count(r) == 0) inbox.emplace_back(r, send->batch);
            }
          } else if (auto* deliver = std::get_if<protocol::tree_action::Deliver>(&action)) {
            ++delivered[id][{deliver->item.msg.step, deliver->item.msg.agent_id}];
            CHECK(deliver->item.origin == WriterOf(deliver->item.msg.agent_id));
          } else if (auto* reparent = std::get_if<protocol::tree_action::Reparent>(&action)) {
            reparents[id].push_back(reparent->parent.value_or(0));
            silent[id].push_back(reparent->silent.value_or(0));
          } else if (auto* reject = std::get_if<protocol::tree_action::Reject>(&action)) {
            rejects[id].push_back(reject->reason);
          }
        }
      }
      std::vector<std::pair<AgentId, BatchMsg>> now;
      now.swap(inbox);
      for (auto& [r, batch] : now) {
        agents.at(r)->OnBatch(batch, now_s);
        more = true;
      }
    }
  }
  // Roll call `roll` and the own contribution of every measured live agent at step k.
  void Step(StepIndex k, const std::vector<AgentId>& roll, double now_s) {
    for (auto& [id, agent] : agents) {
      if (dead.count(id) == 0) agent->OnRollCall(k, roll, now_s);
    }
    for (AgentId id : roll) {
      if (dead.count(id) == 0) agents.at(id)->OnOwn(Contribution(id, k), now_s);
    }
    Pump(now_s);
  }
  const deif::Config& config;
  std::map<AgentId, std::unique_ptr<TreeExchange>> agents;
  std::set<AgentId> dead;
  std::vector<std::pair<AgentId, BatchMsg>> inbox;
  std::map<AgentId, std::map<std::pair<StepIndex, AgentId>, int>> delivered;
  std::map<AgentId, std::vector<AgentId>> reparents;  // 0: became the root
  std::map<AgentId, std::vector<AgentId>> silent;     // with each move: the parent left silent, or 0
  std::map<AgentId, std::vector<std::string>> rejects;
  int up_samples = 0, down_samples = 0;
};

}  // namespace

TEST_CASE("The tree of the members: id i's parent is id (i - 2) / F + 1", "[protocol][tree]") {
  const std::vector<AgentId> ten = Range(1, 10);
  CHECK_FALSE(protocol::PlaceInTree(ten, 1, 3).parent.has_value());
  CHECK(protocol::PlaceInTree(ten, 1, 3).children == std::vector<AgentId>{2, 3, 4});
  CHECK(*protocol::PlaceInTree(ten, 7, 3).parent == 2);
  CHECK(*protocol::PlaceInTree(ten, 10, 3).parent == 3);
  CHECK(protocol::PlaceInTree(ten, 3, 3).children == std::vector<AgentId>{8, 9, 10});
  CHECK(protocol::PlaceInTree(ten, 4, 3).children.empty());
  CHECK(protocol::SubtreeOf(ten, 2, 3) == std::vector<AgentId>{2, 5, 6, 7});
  CHECK(protocol::SubtreeOf(ten, 1, 3) == ten);
  // Gaps in the ids: a member's parent is its nearest ancestor that is a member. With
  // fan-out 2 the ids' tree is 1 > {2, 3}, 2 > {4, 5}, 3 > {6, 7}, 4 > {8, 9}, 6 > {12, 13}.
  const std::vector<AgentId> gaps{1, 2, 4, 7, 9, 12};
  CHECK(*protocol::PlaceInTree(gaps, 7, 2).parent == 1);   // 3 is not a member
  CHECK(*protocol::PlaceInTree(gaps, 12, 2).parent == 1);  // nor 6, nor 3
  CHECK(*protocol::PlaceInTree(gaps, 9, 2).parent == 4);
  CHECK(protocol::PlaceInTree(gaps, 1, 2).children == std::vector<AgentId>{2, 7, 12});
  CHECK(protocol::SubtreeOf(gaps, 2, 2) == std::vector<AgentId>{2, 4, 9});
  // Without the root, the lowest member is the root, and those with no member above them
  // hang under it.
  const std::vector<AgentId> rootless{2, 3, 4, 5, 6, 7};
  CHECK_FALSE(protocol::PlaceInTree(rootless, 2, 2).parent.has_value());
  CHECK(protocol::PlaceInTree(rootless, 2, 2).children == std::vector<AgentId>{3, 4, 5});
  CHECK(*protocol::PlaceInTree(rootless, 7, 2).parent == 3);
  CHECK(protocol::SubtreeOf(rootless, 2, 2) == rootless);
  // Fan-out 1 is a chain.
  CHECK(protocol::SubtreeOf(ten, 8, 1) == std::vector<AgentId>{8, 9, 10});
  CHECK(protocol::PlaceInTree(ten, 5, 99).parent == AgentId{1});
  CHECK(protocol::SubtreeOf(ten, 11, 3).empty());
}

TEST_CASE("A lost member moves only its own children", "[protocol][tree]") {
  // 64 agents, fan-out 8: 1 > 2..9, 2 > 10..17, 3 > 18..25, ...
  const std::vector<AgentId> all = Range(1, 64);
  auto parents = [](const std::vector<AgentId>& members) {
    std::map<AgentId, std::optional<AgentId>> out;
    for (AgentId id : members) out[id] = protocol::ParentInTree(members, id, 8);
    return out;
  };
  const auto before = parents(all);
  CHECK(*before.at(10) == 2);
  CHECK(*before.at(64) == 8);
  // A relay lost: its 8 children move to its parent, nobody else moves.
  std::vector<AgentId> without2 = all;
  without2.erase(std::find(without2.begin(), without2.end(), 2));
  int moved = 0;
  for (const auto& [id, parent] : parents(without2)) {
    if (parent == before.at(id)) continue;
    ++moved;
    CHECK(id >= 10);
    CHECK(id <= 17);
    CHECK(*parent == 1);
  }
  CHECK(moved == 8);
  // The root lost: the lowest member, 2, is the root, and the other relays hang under it.
  std::vector<AgentId> without1(all.begin() + 1, all.end());
  const auto after = parents(without1);
  CHECK_FALSE(after.at(2).has_value());
  for (AgentId id = 3; id <= 9; ++id) CHECK(*after.at(id) == 2);
  for (AgentId id = 10; id <= 64; ++id) CHECK(after.at(id) == before.at(id));
  // A leaf lost: nobody moves.
  std::vector<AgentId> without40 = all;
  without40.erase(std::find(without40.begin(), without40.end(), 40));
  for (const auto& [id, parent] : parents(without40)) CHECK(parent == before.at(id));
}

TEST_CASE("The auto fan-out holds every agent within two levels below the root", "[protocol][tree]") {
  // Worked by hand from 1 + F + F^2 >= N, F >= 4.
  const std::vector<std::pair<int, int>> expected = {{2, 4},  {17, 4},  {21, 4}, {22, 5}, {31, 5},  {32, 6},
                                                     {64, 8}, {73, 8}, {74, 9}, {128, 11}, {512, 23}};
  for (const auto& [n, fanout] : expected) {
    INFO("agents " << n);
    CHECK(deif::EffectiveTreeFanout(ConfigFor(n, 0)) == fanout);
  }
  // A fan-out set by hand is kept.
  CHECK(deif::EffectiveTreeFanout(ConfigFor(64, 3)) == 3);
  // And the property itself, on the tree every agent builds: depth <= 2 at every N, and
  // depth 2 would not hold with one child fewer per relay (above the floor of 4).
  for (int n = 2; n <= 512; ++n) {
    const int fanout = deif::EffectiveTreeFanout(ConfigFor(n, 0));
    const std::vector<AgentId> members = Range(1, n);
    auto depth_of = [&members](AgentId id, int f) {
      int depth = 0;
      for (auto parent = protocol::ParentInTree(members, id, f); parent;
           parent = protocol::ParentInTree(members, *parent, f)) {
        ++depth;
      }
      return depth;
    };
    int deepest = 0, deepest_narrower = 0;
    for (AgentId id : members) {
      deepest = std::max(deepest, depth_of(id, fanout));
      deepest_narrower = std::max(deepest_narrower, depth_of(id, fanout - 1));
    }
    INFO("agents " << n << ", fan-out " << fanout);
    CHECK(deepest <= 2);
    if (fanout > deif::kMinAutoFanout) CHECK(deepest_narrower > 2);
  }
}

TEST_CASE("Every contribution reaches every agent once, in 2 (N - 1) batches a step", "[protocol][tree]") {
  const int n = GENERATE(2, 5, 13, 40);
  const int fanout = GENERATE(1, 2, 4);
  const deif::Config config = ConfigFor(n, fanout);
  Network net(config, Range(1, n));
  for (StepIndex k = 1; k <= 3; ++k) {
    net.up_samples = net.down_samples = 0;
    net.Step(k, Range(1, n), 10.0 * static_cast<double>(k));
    // Each non-root sends one batch up; each agent with children one down.
    CHECK(net.up_samples == n - 1);
    int relays = 0;
    for (const auto& [id, agent] : net.agents) relays += agent->place().children.empty() ? 0 : 1;
    CHECK(net.down_samples == relays);
    for (AgentId a = 1; a <= n; ++a) {
      for (AgentId j = 1; j <= n; ++j) {
        const int times = net.delivered[a][{k, j}];
        CHECK(times == (a == j ? 0 : 1));  // never its own back
      }
    }
  }
  for (const auto& [id, rejects] : net.rejects) CHECK(rejects.empty());
}

TEST_CASE("A relay forwards without a slow child, then the child's batch as it arrives", "[protocol][tree]") {
  const deif::Config config = ConfigFor(7, 2, 0.05);
  // 1 is the root; 2 relays 4 and 5; 3 relays 6 and 7.
  TreeExchange relay(config, TreeExchange::Options{2, kRun, WriterOf(2)});
  relay.SetMembers({1, 2, 3, 4, 5, 6, 7}, 0.0);
  relay.TakeActions();
  relay.OnRollCall(1, Range(1, 7), 1.0);
  relay.OnOwn(Contribution(2, 1), 1.0);
  BatchMsg from5{kRun, 5, 1, false, {{WriterOf(5), Contribution(5, 1)}}};
  relay.OnBatch(from5, 1.01);
  // Waiting for 4: nothing goes up before the wait is over. The wait is a share of the
  // deadline (0.8 x 0.1 s) per level in a tree 2 levels deep, 0.08 / 3 s, less than the
  // relay_wait_s of 0.05 s; 2 is one level above its children.
  for (const auto& a : relay.TakeActions()) CHECK_FALSE(std::holds_alternative<protocol::tree_action::Send>(a));
  REQUIRE(relay.NextDeadline().has_value());
  CHECK(*relay.NextDeadline() == Approx(1.0 + 0.08 / 3.0));
  relay.OnTimer(1.0 + 0.08 / 3.0);
  std::vector<protocol::TreeAction> actions = relay.TakeActions();
  REQUIRE(actions.size() == 1);
  const auto& up = std::get<protocol::tree_action::Send>(actions[0]).batch;
  CHECK_FALSE(up.down);
  CHECK(up.step == 1);
  REQUIRE(up.items.size() == 2);
  // 4's batch, late but before the step's deadline (0.08 s after the relay heard of it):
  // delivered here and, in real time, sent up at once as a batch of late ones.
  BatchMsg from4{kRun, 4, 1, false, {{WriterOf(4), Contribution(4, 1)}}};
  relay.OnBatch(from4, 1.05);
  actions = relay.TakeActions();
  int sends = 0, delivers = 0;
  for (const auto& a : actions) {
    if (const auto* s = std::get_if<protocol::tree_action::Send>(&a)) {
      ++sends;
      CHECK_FALSE(s->batch.down);
      CHECK(s->batch.step == 0);
      REQUIRE(s->batch.items.size() == 1);
      CHECK(s->batch.items[0].msg.agent_id == 4);
    }
    if (std::holds_alternative<protocol::tree_action::Deliver>(a)) ++delivers;
  }
  CHECK(sends == 1);
  CHECK(delivers == 1);
}

TEST_CASE("In real time a late item past its step's deadline goes with the next batch, or a period later",
          "[protocol][tree]") {
  const deif::Config config = ConfigFor(7, 2, 0.05);  // period 0.1 s, deadline 0.08 s
  // 2 relays 4 and 5.
  const auto late_sends = [](std::vector<protocol::TreeAction> actions) {
    std::vector<BatchMsg> sends;
    for (auto& a : actions) {
      if (auto* s = std::get_if<protocol::tree_action::Send>(&a)) sends.push_back(s->batch);
    }
    return sends;
  };
  const auto items_of = [](const BatchMsg& batch) {
    std::vector<std::pair<StepIndex, AgentId>> items;
    for (const auto& item : batch.items) items.emplace_back(item.msg.step, item.msg.agent_id);
    return items;
  };
  TreeExchange relay(config, TreeExchange::Options{2, kRun, WriterOf(2)});
  relay.SetMembers({1, 2, 3, 4, 5, 6, 7}, 0.0);
  relay.TakeActions();
  relay.OnRollCall(1, Range(1, 7), 1.0);
  relay.OnOwn(Contribution(2, 1), 1.0);
  relay.OnBatch(BatchMsg{kRun, 5, 1, false, {{WriterOf(5), Contribution(5, 1)}}}, 1.01);
  relay.OnTimer(1.0 + 0.08 / 3.0);
  std::vector<BatchMsg> sent = late_sends(relay.TakeActions());
  REQUIRE(sent.size() == 1);  // step 1 without 4
  CHECK(sent[0].step == 1);

  SECTION("with the next step's batch") {
    // 4's batch of step 1 comes 0.09 s after the relay heard of step 1: past its deadline.
    relay.OnBatch(BatchMsg{kRun, 4, 1, false, {{WriterOf(4), Contribution(4, 1)}}}, 1.09);
    CHECK(late_sends(relay.TakeActions()).empty());
    REQUIRE(relay.NextDeadline().has_value());
    CHECK(*relay.NextDeadline() == Approx(1.09 + 0.1));  // at most a period
    // Step 2 comes, complete: its batch carries 4's late item of step 1 too.
    relay.OnRollCall(2, Range(1, 7), 1.1);
    relay.OnOwn(Contribution(2, 2), 1.1);
    relay.OnBatch(BatchMsg{kRun, 4, 2, false, {{WriterOf(4), Contribution(4, 2)}}}, 1.101);
    relay.OnBatch(BatchMsg{kRun, 5, 2, false, {{WriterOf(5), Contribution(5, 2)}}}, 1.102);
    sent = late_sends(relay.TakeActions());
    REQUIRE(sent.size() == 1);
    CHECK(sent[0].step == 2);
    const std::vector<std::pair<StepIndex, AgentId>> expected{{1, 4}, {2, 2}, {2, 4}, {2, 5}};
    std::vector<std::pair<StepIndex, AgentId>> got = items_of(sent[0]);
    std::sort(got.begin(), got.end());
    CHECK(got == expected);
    // Nothing is left to go late.
    relay.OnTimer(1.3);
    CHECK(late_sends(relay.TakeActions()).empty());
  }
  SECTION("a period later when no batch goes") {
    relay.OnBatch(BatchMsg{kRun, 4, 1, false, {{WriterOf(4), Contribution(4, 1)}}}, 1.09);
    CHECK(late_sends(relay.TakeActions()).empty());
    relay.OnTimer(1.18);
    CHECK(late_sends(relay.TakeActions()).empty());
    REQUIRE(relay.NextDeadline().has_value());
    CHECK(*relay.NextDeadline() == Approx(1.19));
    relay.OnTimer(*relay.NextDeadline());
    sent = late_sends(relay.TakeActions());
    REQUIRE(sent.size() == 1);
    CHECK(sent[0].step == 0);
    CHECK(items_of(sent[0]) == std::vector<std::pair<StepIndex, AgentId>>{{1, 4}});
  }
  SECTION("at once with a late item that may still make its step") {
    relay.OnBatch(BatchMsg{kRun, 4, 1, false, {{WriterOf(4), Contribution(4, 1)}}}, 1.09);
    CHECK(late_sends(relay.TakeActions()).empty());
    // Step 2's batch went without 5; 5's item of step 2 comes within step 2's deadline.
    relay.OnRollCall(2, Range(1, 7), 1.1);
    relay.OnOwn(Contribution(2, 2), 1.1);
    relay.OnBatch(BatchMsg{kRun, 4, 2, false, {{WriterOf(4), Contribution(4, 2)}}}, 1.101);
    relay.OnTimer(1.1 + 0.08 / 3.0);
    sent = late_sends(relay.TakeActions());
    REQUIRE(sent.size() == 1);
    CHECK(sent[0].step == 2);
    relay.OnBatch(BatchMsg{kRun, 5, 2, false, {{WriterOf(5), Contribution(5, 2)}}}, 1.15);
    sent = late_sends(relay.TakeActions());
    REQUIRE(sent.size() == 1);
    CHECK(sent[0].step == 0);
    CHECK(items_of(sent[0]) == std::vector<std::pair<StepIndex, AgentId>>{{2, 5}});
  }
}

TEST_CASE("The height of an agent in the tree: the most hops up to it from below", "[protocol][tree]") {
  // Fan-out 2 over 1..7: 1 above 2 and 3, 2 above 4 and 5, 3 above 6 and 7.
  const std::vector<AgentId> all = Range(1, 7);
  CHECK(protocol::HeightInTree(all, 1, 2) == 2);
  CHECK(protocol::HeightInTree(all, 2, 2) == 1);
  CHECK(protocol::HeightInTree(all, 7, 2) == 0);
  CHECK(protocol::HeightInTree(all, 9, 2) == 0);  // not a member
  // Without 2, its children hang under 1: 1 is still two levels above 6 and 7.
  CHECK(protocol::HeightInTree({1, 3, 4, 5, 6, 7}, 1, 2) == 2);
  CHECK(protocol::HeightInTree({1, 4, 5}, 1, 2) == 1);
  // 64 agents with fan-out 4: 1 above 2-5; 2 above 6-9, 5 above 18-21; 6 above 22-25, 16
  // above 58-61; 17 is a leaf (its children would be 66-69).
  CHECK(protocol::HeightInTree(Range(1, 64), 1, 4) == 3);
  CHECK(protocol::HeightInTree(Range(1, 64), 2, 4) == 2);
  CHECK(protocol::HeightInTree(Range(1, 64), 5, 4) == 1);
  CHECK(protocol::HeightInTree(Range(1, 64), 16, 4) == 1);
  CHECK(protocol::HeightInTree(Range(1, 64), 17, 4) == 0);
}

TEST_CASE("In real time a parent waits one share of the deadline more than its children", "[protocol][tree]") {
  // Period 0.1 s, deadline 0.08 s; a tree 3 levels deep gives each level 0.02 s at most.
  const deif::Config config = ConfigFor(64, 4, 0.05);
  CHECK(protocol::RelayWaitS(config, 3, 3) == Approx(0.06));  // the root: 0.02 s left for the way down
  CHECK(protocol::RelayWaitS(config, 1, 3) == Approx(0.02));
  CHECK(protocol::RelayWaitS(config, 0, 3) == Approx(0.02));  // a leaf waits for its own contribution
  // relay_wait_s below the share is the share.
  CHECK(protocol::RelayWaitS(ConfigFor(64, 4, 0.01), 2, 3) == Approx(0.02));
  // Lock-step: a quarter of the step timeout at every height.
  const deif::Config lockstep = deif::ParseConfig("network: {relay_wait_s: 0.01, step_timeout_s: 2}\n", "inline");
  CHECK(protocol::RelayWaitS(lockstep, 3, 3) == Approx(0.5));

  // The root of 7 agents (fan-out 2, 2 levels, share 0.08 / 3 s) with one child's batch in
  // waits two shares for the other.
  const deif::Config seven = ConfigFor(7, 2, 0.05);  // outlives the exchange
  TreeExchange root(seven, TreeExchange::Options{1, kRun, WriterOf(1)});
  root.OnRollCall(1, Range(1, 7), 1.0);
  root.OnOwn(Contribution(1, 1), 1.0);
  root.OnBatch(BatchMsg{kRun, 2, 1, false, {{WriterOf(2), Contribution(2, 1)}}}, 1.01);
  for (const auto& a : root.TakeActions()) CHECK_FALSE(std::holds_alternative<protocol::tree_action::Send>(a));
  REQUIRE(root.NextDeadline().has_value());
  CHECK(*root.NextDeadline() == Approx(1.0 + 2.0 * 0.08 / 3.0));
  root.OnTimer(1.04);  // past one share, within two
  for (const auto& a : root.TakeActions()) CHECK_FALSE(std::holds_alternative<protocol::tree_action::Send>(a));
  root.OnTimer(1.0 + 2.0 * 0.08 / 3.0);
  int sends = 0;
  for (const auto& a : root.TakeActions()) {
    if (const auto* send = std::get_if<protocol::tree_action::Send>(&a)) {
      ++sends;
      CHECK(send->batch.down);
      CHECK(send->batch.items.size() == 2);
    }
  }
  CHECK(sends == 1);
}

TEST_CASE("What comes down or late between two takes of the actions goes on as one batch", "[protocol][tree]") {
  // 2 relays 4 and 5 under the root 1 (fan-out 2, 7 agents).
  const deif::Config config = ConfigFor(7, 2);
  TreeExchange relay(config, TreeExchange::Options{2, kRun, WriterOf(2)});
  relay.OnRollCall(1, Range(1, 7), 1.0);
  relay.TakeActions();
  // Two batches from the parent before the actions are taken (one wake-up): one batch down.
  relay.OnBatch(BatchMsg{kRun, 1, 0, true, {{WriterOf(1), Contribution(1, 1)}}}, 1.001);
  relay.OnBatch(BatchMsg{kRun, 1, 1, true, {{WriterOf(3), Contribution(3, 1)}}}, 1.002);
  int downs = 0, delivers = 0;
  for (const auto& a : relay.TakeActions()) {
    if (const auto* send = std::get_if<protocol::tree_action::Send>(&a)) {
      ++downs;
      CHECK(send->batch.down);
      CHECK(send->batch.step == 1);
      CHECK(send->batch.items.size() == 2);
    }
    delivers += std::holds_alternative<protocol::tree_action::Deliver>(a) ? 1 : 0;
  }
  CHECK(downs == 1);
  CHECK(delivers == 2);
  // Its batch up gone without its children's (the wait over), both come late in one
  // wake-up: one batch up with both.
  relay.OnOwn(Contribution(2, 1), 1.003);
  relay.OnTimer(1.05);
  relay.TakeActions();
  relay.OnBatch(BatchMsg{kRun, 4, 1, false, {{WriterOf(4), Contribution(4, 1)}}}, 1.06);
  relay.OnBatch(BatchMsg{kRun, 5, 1, false, {{WriterOf(5), Contribution(5, 1)}}}, 1.061);
  int ups = 0;
  for (const auto& a : relay.TakeActions()) {
    if (const auto* send = std::get_if<protocol::tree_action::Send>(&a)) {
      ups += send->batch.down ? 0 : 1;
      if (!send->batch.down) CHECK(send->batch.items.size() == 2);
    }
  }
  CHECK(ups == 1);
}

TEST_CASE("A relay that never hears the target relays its subtree at once, however long the run",
          "[protocol][tree]") {
  // GIVEN agent 2 of 7 (fan-out 2: children 4 and 5, parent 1) whose range reader never
  // matched the target's writer: no roll call and no own contribution ever reach it
  const deif::Config config = ConfigFor(7, 2, 0.05);
  REQUIRE(config.scenario.steps >= 150);
  TreeExchange relay(config, TreeExchange::Options{2, kRun, WriterOf(2)});
  for (StepIndex k = 1; k <= 150; ++k) {
    const double now_s = 0.1 * static_cast<double>(k);
    for (AgentId child : {4, 5}) {
      BatchMsg up;
      up.run = kRun;
      up.sender_id = child;
      up.step = k;
      up.items = {protocol::RelayedContribution{WriterOf(child), Contribution(child, k)}};
      relay.OnBatch(up, now_s);
    }
    // THEN the children's step goes up as soon as both are in, without waiting for a
    // contribution of its own that never comes (at the same instant: no timer ran)
    std::set<AgentId> sent_up;
    for (const auto& a : relay.TakeActions()) {
      if (const auto* send = std::get_if<protocol::tree_action::Send>(&a)) {
        if (send->batch.down) continue;
        for (const auto& item : send->batch.items) {
          if (item.msg.step == k) sent_up.insert(item.msg.agent_id);
        }
      }
    }
    CHECK(sent_up == std::set<AgentId>{4, 5});
    // AND the parent's batch of the step goes down to the children, past the kept steps too
    BatchMsg down;
    down.run = kRun;
    down.sender_id = 1;
    down.step = k;
    down.down = true;
    down.items = {protocol::RelayedContribution{WriterOf(1), Contribution(1, k)},
                  protocol::RelayedContribution{WriterOf(3), Contribution(3, k)}};
    relay.OnBatch(down, now_s);
    std::set<AgentId> sent_down;
    for (const auto& a : relay.TakeActions()) {
      if (const auto* send = std::get_if<protocol::tree_action::Send>(&a)) {
        if (!send->batch.down) continue;
        for (const auto& item : send->batch.items) {
          if (item.msg.step == k) sent_down.insert(item.msg.agent_id);
        }
      }
    }
    CHECK(sent_down == std::set<AgentId>{1, 3, 4, 5});
  }
  CHECK(relay.kept_items() <= static_cast<std::size_t>(4 * (config.network.history_steps +
                                                            config.network.fusion_window_steps + 1)));
}

TEST_CASE("In lock-step a relay gathers late contributions for half a wait", "[protocol][tree]") {
  const deif::Config config = deif::ParseConfig(
      "agents: {count: 7}\nnetwork: {exchange: tree, tree_fanout: 2, step_timeout_s: 2}\n", "inline");
  TreeExchange relay(config, TreeExchange::Options{2, kRun, WriterOf(2)});
  relay.OnRollCall(1, Range(1, 7), 1.0);
  relay.OnOwn(Contribution(2, 1), 1.0);
  relay.OnBatch(BatchMsg{kRun, 5, 1, false, {{WriterOf(5), Contribution(5, 1)}}}, 1.0);
  REQUIRE(relay.NextDeadline().has_value());
  CHECK(*relay.NextDeadline() == Approx(1.5));  // a quarter of step_timeout_s
  relay.OnTimer(1.5);
  relay.TakeActions();
  relay.OnBatch(BatchMsg{kRun, 4, 1, false, {{WriterOf(4), Contribution(4, 1)}}}, 2.0);
  for (const auto& a : relay.TakeActions()) CHECK_FALSE(std::holds_alternative<protocol::tree_action::Send>(a));
  REQUIRE(relay.NextDeadline().has_value());
  CHECK(*relay.NextDeadline() == Approx(2.25));
  relay.OnTimer(2.25);
  int sends = 0;
  for (const auto& a : relay.TakeActions()) sends += std::holds_alternative<protocol::tree_action::Send>(a);
  CHECK(sends == 1);
}

TEST_CASE("In lock-step a relay waits a quarter of the step timeout at least", "[protocol][tree]") {
  CHECK(protocol::RelayWaitS(deif::ParseConfig("network: {relay_wait_s: 0.01, step_timeout_s: 2}\n", "inline")) ==
        Approx(0.5));
  CHECK(protocol::RelayWaitS(deif::ParseConfig("network: {relay_wait_s: 0.9, step_timeout_s: 2}\n", "inline")) ==
        Approx(0.9));
  CHECK(protocol::RelayWaitS(ConfigFor(4, 2, 0.01)) == Approx(0.01));
}

TEST_CASE("A relay waits only for children with a measured agent below them", "[protocol][tree]") {
  const deif::Config config = ConfigFor(7, 2);
  TreeExchange relay(config, TreeExchange::Options{2, kRun, WriterOf(2)});
  relay.SetMembers({1, 2, 3, 4, 5, 6, 7}, 0.0);
  relay.TakeActions();
  relay.OnRollCall(1, {1, 2, 3, 5}, 1.0);  // 4 not measured
  relay.OnOwn(Contribution(2, 1), 1.0);
  CHECK(relay.TakeActions().empty());
  relay.OnBatch(BatchMsg{kRun, 5, 1, false, {{WriterOf(5), Contribution(5, 1)}}}, 1.001);
  bool sent = false;
  for (const auto& a : relay.TakeActions()) {
    if (const auto* s = std::get_if<protocol::tree_action::Send>(&a)) sent = s->batch.step == 1 && s->batch.items.size() == 2;
  }
  CHECK(sent);  // at once, not after relay_wait_s
}

TEST_CASE("When a relay is lost its subtree moves to a new parent and what it held is sent again",
          "[protocol][tree]") {
  const deif::Config config = ConfigFor(13, 3, 0.05);
  Network net(config, Range(1, 13));
  net.Step(1, Range(1, 13), 1.0);
  // Relay 2 (children 5, 6, 7) dies after its children sent it step 2's contributions and
  // before it forwarded them.
  net.dead.insert(2);
  net.Step(2, Range(1, 13), 2.0);
  for (AgentId a : {1, 3, 4}) CHECK(net.delivered[a][{2, 5}] == 0);
  // The members without 2: its children 5, 6 and 7 now hang under its parent, 1; nobody
  // else moves.
  std::set<AgentId> members;
  for (AgentId a = 1; a <= 13; ++a) {
    if (a != 2) members.insert(a);
  }
  net.Tick(2.1);  // the waits for 2 are over
  net.SetMembers(members, 3.0);
  net.Tick(3.1);
  for (AgentId a : {5, 6, 7}) {
    REQUIRE(net.reparents[a].size() == 1);
    CHECK(net.reparents[a].back() == 1);
  }
  for (AgentId a : {1, 3, 4, 8, 9, 10, 11, 12, 13}) CHECK(net.reparents[a].empty());
  for (AgentId a : members) {
    for (AgentId j : members) {
      INFO("agent " << a << " of " << j);
      if (a != j) CHECK(net.delivered[a][{2, j}] == 1);
    }
  }
}

TEST_CASE("Children whose parent falls silent move up after the grace, before the members lose it",
          "[protocol][tree]") {
  // 13 agents, fan-out 3: 1 > {2, 3, 4}, 2 > {5, 6, 7}. Every agent's membership loses a dead
  // agent only after the lease of all writers (2.08 s at 64 agents); the relay writer's lease
  // is short (network.relay_lease_s): its children move at once.
  const deif::Config config = ConfigFor(13, 3);
  const double grace = config.network.liveliness_grace_s;
  Network net(config, Range(1, 13));
  net.Step(1, Range(1, 13), 1.0);
  net.dead.insert(2);
  for (AgentId c : {5, 6, 7}) net.agents.at(c)->OnParentLiveliness(2, false, 2.0);
  net.Tick(2.0 + 0.5 * grace);  // within the grace: a stalled parent, maybe
  for (AgentId c : {5, 6, 7}) CHECK(net.reparents[c].empty());
  net.Tick(2.0 + grace);
  for (AgentId c : {5, 6, 7}) {
    REQUIRE(net.reparents[c] == std::vector<AgentId>{1});
    CHECK(net.silent[c] == std::vector<AgentId>{2});
    CHECK(net.agents.at(c)->members().count(2) == 0);
  }
  for (AgentId a : {1, 3, 4, 8, 9, 10, 11, 12, 13}) CHECK(net.reparents[a].empty());
  // The next step, the roll call still with 2 (the target has not lost it either): every
  // live agent has every other live agent's contribution, 5, 6 and 7 included.
  net.Step(3, Range(1, 13), 2.5);
  net.Tick(2.6);
  for (AgentId a = 1; a <= 13; ++a) {
    for (AgentId j = 1; j <= 13; ++j) {
      if (a == 2 || j == 2 || a == j) continue;
      INFO("agent " << a << " of " << j);
      CHECK(net.delivered[a][{3, j}] == 1);
    }
  }
  // The members lose 2 later: the tree is the one the children already hang in.
  std::set<AgentId> members;
  for (AgentId a = 1; a <= 13; ++a) {
    if (a != 2) members.insert(a);
  }
  net.SetMembers(members, 4.5);
  net.Tick(20.0);  // long after the hold
  for (AgentId c : {5, 6, 7}) CHECK(net.reparents[c] == std::vector<AgentId>{1});
}

TEST_CASE("The root's children make the lowest of them the root when the root falls silent",
          "[protocol][tree]") {
  // 7 agents, fan-out 2: 1 > {2, 3}, 2 > {4, 5}, 3 > {6, 7}.
  const deif::Config config = ConfigFor(7, 2);
  Network net(config, Range(1, 7));
  net.Step(1, Range(1, 7), 1.0);
  net.dead.insert(1);
  for (AgentId c : {2, 3}) net.agents.at(c)->OnParentLiveliness(1, false, 2.0);
  net.Tick(3.0);
  CHECK(net.reparents[2] == std::vector<AgentId>{0});  // the root now
  CHECK(net.reparents[3] == std::vector<AgentId>{2});
  for (AgentId a : {4, 5, 6, 7}) CHECK(net.reparents[a].empty());
  net.Step(2, Range(1, 7), 3.5);
  net.Tick(3.6);
  for (AgentId a = 2; a <= 7; ++a) {
    for (AgentId j = 2; j <= 7; ++j) {
      INFO("agent " << a << " of " << j);
      if (a != j) CHECK(net.delivered[a][{2, j}] == 1);
    }
  }
}

TEST_CASE("A parent's lapse within the grace, or another relay's, moves nobody; a silent parent "
          "that lives comes back after the hold",
          "[protocol][tree]") {
  const deif::Config config = ConfigFor(13, 3);
  const double grace = config.network.liveliness_grace_s;
  TreeExchange child(config, TreeExchange::Options{5, kRun, WriterOf(5), /*silent_hold_s=*/1.0});
  child.SetMembers(std::set<AgentId>{1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12, 13}, 0.0);
  child.TakeActions();
  REQUIRE(child.place().parent == AgentId{2});
  std::vector<protocol::tree_action::GraceGrown> grown;
  const auto moves = [&child, &grown] {
    std::vector<std::pair<AgentId, AgentId>> out;  // (new parent or 0, silent parent or 0)
    for (const auto& a : child.TakeActions()) {
      if (const auto* r = std::get_if<protocol::tree_action::Reparent>(&a)) {
        out.emplace_back(r->parent.value_or(0), r->silent.value_or(0));
      } else if (const auto* g = std::get_if<protocol::tree_action::GraceGrown>(&a)) {
        grown.push_back(*g);
      }
    }
    return out;
  };
  child.OnParentLiveliness(2, false, 1.0);
  child.OnParentLiveliness(2, true, 1.0 + 0.5 * grace);  // back within the grace
  child.OnTimer(1.0 + 2.0 * grace);
  CHECK(moves().empty());
  child.OnParentLiveliness(3, false, 2.0);  // not its parent
  child.OnTimer(2.0 + 2.0 * grace);
  CHECK(moves().empty());
  // Silent past the grace: under 1 until the hold is over, then back under 2, which the
  // members never lost (a parent that stalled, not one that died).
  child.OnParentLiveliness(2, false, 3.0);
  REQUIRE(child.NextDeadline().has_value());
  CHECK(*child.NextDeadline() <= 3.0 + grace);
  child.OnTimer(3.0 + grace);
  CHECK(moves() == std::vector<std::pair<AgentId, AgentId>>{{1, 2}});
  child.OnTimer(3.0 + grace + 0.5);
  CHECK(moves().empty());
  child.OnTimer(3.0 + grace + 1.0);
  CHECK(moves() == std::vector<std::pair<AgentId, AgentId>>{{2, 0}});
  CHECK(child.place().parent == AgentId{2});
  // That parent lived: the network lost its renewals, so its lapses are held twice as long
  // from now on (docs/PROTOCOL.md, "Losses that are undone"), and the same silence moves nobody.
  CHECK(child.parent_losses_undone() == 1);
  // Said once, for the agent to log: parent 2, twice the grace.
  REQUIRE(grown.size() == 1);
  CHECK(grown[0].parent == AgentId{2});
  CHECK(grown[0].factor == 2.0);
  CHECK(grown[0].grace_s == Approx(2.0 * grace));
  child.OnParentLiveliness(2, false, 6.0);
  child.OnTimer(6.0 + 1.5 * grace);
  CHECK(moves().empty());
  child.OnParentLiveliness(2, true, 6.0 + 1.5 * grace);
  child.OnTimer(6.0 + 3.0 * grace);
  CHECK(moves().empty());
  // A longer one still does.
  child.OnParentLiveliness(2, false, 7.0);
  child.OnTimer(7.0 + 2.0 * grace);
  CHECK(moves() == std::vector<std::pair<AgentId, AgentId>>{{1, 2}});
  CHECK(grown.size() == 1);  // nothing undone since
}

TEST_CASE("A silent parent heard again comes back once it stays alive while the members have it; a "
          "dead one stays out for the hold",
          "[protocol][tree]") {
  const deif::Config config = ConfigFor(13, 3);
  const double grace = config.network.liveliness_grace_s;
  const double hold = 10.0;
  TreeExchange child(config, TreeExchange::Options{5, kRun, WriterOf(5), hold});
  const std::set<AgentId> all{1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12, 13};
  child.SetMembers(all, 0.0);
  child.TakeActions();
  REQUIRE(child.place().parent == AgentId{2});
  const auto moves = [&child] {
    std::vector<std::pair<AgentId, AgentId>> out;  // (new parent or 0, silent parent or 0)
    for (const auto& a : child.TakeActions()) {
      if (const auto* r = std::get_if<protocol::tree_action::Reparent>(&a)) {
        out.emplace_back(r->parent.value_or(0), r->silent.value_or(0));
      }
    }
    return out;
  };
  // Parent 2 frozen: its relay writer lapses, the child leaves it for 1.
  child.OnParentLiveliness(2, false, 1.0);
  child.OnTimer(1.0 + grace);
  CHECK(moves() == std::vector<std::pair<AgentId, AgentId>>{{1, 2}});
  CHECK(child.silent_parents() == std::set<AgentId>{2});
  // A message of it read late says "alive" while it is still frozen, and its lease runs out
  // again: it stays out.
  const double settle = config.network.liveliness_lease_s + grace;  // relay_lease_s 0: the lease
  child.OnParentLiveliness(2, true, 1.5 + grace);
  child.OnParentLiveliness(2, false, 1.5 + grace + 0.3);
  child.OnTimer(1.5 + grace + settle + 0.1);
  CHECK(moves().empty());
  CHECK(child.silent_parents() == std::set<AgentId>{2});
  // It resumes 2 s later, long before the hold is over, and stays alive: once it has been
  // alive for its relay lease and the grace, the child is back under it.
  child.OnParentLiveliness(2, true, 3.0);
  REQUIRE(child.NextDeadline().has_value());
  CHECK(*child.NextDeadline() <= 3.0 + settle);
  child.OnTimer(3.0 + 0.5 * settle);
  CHECK(moves().empty());
  child.OnTimer(3.0 + settle);
  CHECK(moves() == std::vector<std::pair<AgentId, AgentId>>{{2, 0}});
  CHECK(child.place().parent == AgentId{2});
  CHECK(child.silent_parents().empty());
  CHECK(child.parents_heard_again() == 1);
  CHECK(child.parent_losses_undone() == 1);  // its next lapse is held twice as long
  // Another relay's writer coming alive moves nobody.
  child.OnParentLiveliness(3, true, 3.5);
  CHECK(moves().empty());
  // Parent 2 lapses again for longer than the doubled grace: left again.
  child.OnParentLiveliness(2, false, 4.0);
  child.OnTimer(4.0 + 2.0 * grace);
  CHECK(moves() == std::vector<std::pair<AgentId, AgentId>>{{1, 2}});
  // The members lose it (it died): its writer is never heard again, and even a report of it
  // alive (a copy of an old announcement) after the members lost it brings nothing back.
  std::set<AgentId> without_2 = all;
  without_2.erase(2);
  child.SetMembers(without_2, 6.0);
  CHECK(moves().empty());  // already out of its tree
  child.OnParentLiveliness(2, true, 6.5);
  child.OnTimer(6.5 + settle);
  CHECK(moves().empty());
  child.OnTimer(4.0 + 2.0 * grace + hold + 1.0);
  CHECK(moves().empty());
  CHECK(child.place().parent == AgentId{1});
  CHECK(child.parents_heard_again() == 1);
}

TEST_CASE("After this agent was away, its parent's lapse counts only once it outlasts the hold",
          "[protocol][tree]") {
  const deif::Config config = ConfigFor(13, 3);
  TreeExchange child(config, TreeExchange::Options{5, kRun, WriterOf(5)});
  child.SetMembers(std::set<AgentId>{1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12, 13}, 0.0);
  child.TakeActions();
  const auto moved = [&child] {
    for (const auto& a : child.TakeActions()) {
      if (std::holds_alternative<protocol::tree_action::Reparent>(a)) return true;
    }
    return false;
  };
  child.OnAway(10.0, 2.0);  // frozen until 10.0: its parent's writer lapses in its view
  child.OnParentLiveliness(2, false, 10.1);
  child.OnTimer(11.0);
  CHECK_FALSE(moved());
  child.OnParentLiveliness(2, true, 11.5);  // its batches reach the agent again
  child.OnTimer(13.0);
  CHECK_FALSE(moved());
  CHECK(child.place().parent == AgentId{2});
  // A parent that stays silent past the hold is left.
  child.OnAway(20.0, 2.0);
  child.OnParentLiveliness(2, false, 20.1);
  child.OnTimer(21.9);
  CHECK_FALSE(moved());
  child.OnTimer(22.0);
  CHECK(moved());
  CHECK(child.place().parent == AgentId{1});
}

TEST_CASE("A relay with a new child sends again only its newest steps", "[protocol][tree]") {
  // 15 agents, fan-out 2: 1 > {2, 3}, 2 > {4, 5}, 4 > {8, 9}, 5 > {10, 11}.
  const deif::Config config = ConfigFor(15, 2);
  TreeExchange relay(config, TreeExchange::Options{2, kRun, WriterOf(2)});
  relay.SetMembers(std::set<AgentId>{1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12, 13, 14, 15}, 0.0);
  relay.TakeActions();
  double t = 1.0;
  for (StepIndex k = 1; k <= 10; ++k, t += 0.1) {
    relay.OnRollCall(k, Range(1, 15), t);
    relay.OnOwn(Contribution(2, k), t);
    relay.OnBatch(BatchMsg{kRun, 4, k, false, {{WriterOf(4), Contribution(4, k)}}}, t);
    relay.OnBatch(BatchMsg{kRun, 5, k, false, {{WriterOf(5), Contribution(5, k)}}}, t);
    relay.OnBatch(BatchMsg{kRun, 1, k, true, {{WriterOf(1), Contribution(1, k)}}}, t);  // sent on down
    relay.TakeActions();
  }
  // 4 is lost: its children 8 and 9 are 2's now. What 2 sent down before reaches them from
  // the relay topic's history; 2 sends again the newest fusion_window_steps + 2 steps only.
  relay.SetMembers(std::set<AgentId>{1, 2, 3, 5, 6, 7, 8, 9, 10, 11, 12, 13, 14, 15}, t);
  REQUIRE(relay.place().children == std::vector<AgentId>{5, 8, 9});
  const StepIndex from = 10 - (config.network.fusion_window_steps + 2);
  std::set<StepIndex> steps;
  for (const auto& a : relay.TakeActions()) {
    if (const auto* s = std::get_if<protocol::tree_action::Send>(&a)) {
      CHECK(s->batch.down);
      for (const auto& item : s->batch.items) steps.insert(item.msg.step);
    }
  }
  std::set<StepIndex> expected;
  for (StepIndex k = from; k <= 10; ++k) expected.insert(k);
  CHECK(steps == expected);
}

TEST_CASE("Bad batches and items are refused and never delivered", "[protocol][tree]") {
  const deif::Config config = ConfigFor(5, 2);
  TreeExchange relay(config, TreeExchange::Options{2, kRun, WriterOf(2)});
  relay.SetMembers({1, 2, 3, 4, 5}, 0.0);
  relay.TakeActions();
  const auto reasons = [&relay] {
    std::vector<std::string> out;
    for (const auto& a : relay.TakeActions()) {
      CHECK_FALSE(std::holds_alternative<protocol::tree_action::Deliver>(a));
      if (const auto* r = std::get_if<protocol::tree_action::Reject>(&a)) out.push_back(r->reason);
    }
    return out;
  };
  BatchMsg other_run{kRun + 1, 4, 1, false, {{WriterOf(4), Contribution(4, 1)}}};
  CHECK(reasons().empty());
  relay.OnBatch(other_run, 1.0);
  CHECK(reasons() == std::vector<std::string>{"other_run"});
  relay.OnBatch(BatchMsg{kRun, 9, 1, false, {}}, 1.0);
  CHECK(reasons() == std::vector<std::string>{"unknown_relay"});
  relay.OnBatch(BatchMsg{kRun, 2, 1, false, {}}, 1.0);  // claims to be this agent
  CHECK(reasons() == std::vector<std::string>{"unknown_relay"});
  BatchMsg huge{kRun, 4, 1, false, {}};
  huge.items.assign(protocol::kMaxBatchItems + 1, {WriterOf(4), Contribution(4, 1)});
  relay.OnBatch(huge, 1.0);
  CHECK(reasons() == std::vector<std::string>{"oversized_batch"});
  ContributionMsg bad = Contribution(4, 1);
  bad.info_matrix(0, 1) = 7.0;  // asymmetric
  ContributionMsg stranger = Contribution(6, 1);  // no agent 6 in a run of 5
  relay.OnBatch(BatchMsg{kRun, 4, 1, false, {{WriterOf(4), bad}, {WriterOf(6), stranger}}}, 1.0);
  const std::vector<std::string> got = reasons();
  REQUIRE(got.size() == 2);
  CHECK(got[1] == "unknown_agent_id");
  // The valid one still gets through afterwards (a refused copy does not block it).
  relay.OnBatch(BatchMsg{kRun, 4, 1, false, {{WriterOf(4), Contribution(4, 1)}}}, 1.0);
  int delivered = 0;
  for (const auto& a : relay.TakeActions()) delivered += std::holds_alternative<protocol::tree_action::Deliver>(a);
  CHECK(delivered == 1);
  // This agent's own contribution coming back down is not delivered to it; one by another
  // writer under its id is (the step protocol refuses it as a clash).
  relay.OnOwn(Contribution(2, 2), 2.0);
  relay.TakeActions();
  relay.OnBatch(BatchMsg{kRun, 1, 2, true, {{WriterOf(2), Contribution(2, 2)}}}, 2.0);
  delivered = 0;
  for (const auto& a : relay.TakeActions()) delivered += std::holds_alternative<protocol::tree_action::Deliver>(a);
  CHECK(delivered == 0);
  relay.OnBatch(BatchMsg{kRun, 1, 3, true, {{WriterOf(9), Contribution(2, 3)}}}, 3.0);
  delivered = 0;
  for (const auto& a : relay.TakeActions()) delivered += std::holds_alternative<protocol::tree_action::Deliver>(a);
  CHECK(delivered == 1);
}

TEST_CASE("What a relay keeps stays bounded however long the run", "[protocol][tree]") {
  // The root (which never sends up) and a leaf whose parent never sends down, 2000 steps.
  const deif::Config config = deif::ParseConfig(
      "scenario: {steps: 5000, mode: realtime, period_s: 0.1}\nagents: {count: 3}\n"
      "network: {exchange: tree, tree_fanout: 2, history_steps: 5, fusion_window_steps: 1}\n",
      "inline");
  TreeExchange root(config, TreeExchange::Options{1, kRun, WriterOf(1)});
  TreeExchange leaf(config, TreeExchange::Options{3, kRun, WriterOf(3)});
  std::size_t root_sent = 0, leaf_sent = 0;
  for (StepIndex k = 1; k <= 2000; ++k) {
    const double t = 0.1 * static_cast<double>(k);
    root.OnRollCall(k, {1, 2, 3}, t);
    root.OnOwn(Contribution(1, k), t);
    root.OnBatch(BatchMsg{kRun, 2, k, false, {{WriterOf(2), Contribution(2, k)}}}, t);
    root.OnBatch(BatchMsg{kRun, 3, k, false, {{WriterOf(3), Contribution(3, k)}}}, t);
    leaf.OnRollCall(k, {1, 2, 3}, t);
    leaf.OnOwn(Contribution(3, k), t);
    root.OnTimer(t + 0.05);
    leaf.OnTimer(t + 0.05);
    for (const auto& a : root.TakeActions()) root_sent += std::holds_alternative<protocol::tree_action::Send>(a);
    for (const auto& a : leaf.TakeActions()) leaf_sent += std::holds_alternative<protocol::tree_action::Send>(a);
    REQUIRE(root.kept_items() <= 3 * 7);  // history + window + 1 steps of 3 contributions
    REQUIRE(root.queued() <= 2 * 3 * 7);
    REQUIRE(leaf.kept_items() <= 3 * 7);
    REQUIRE(leaf.queued() <= 2 * 3 * 7);
  }
  CHECK(root_sent == 2000);  // one down batch a step
  CHECK(leaf_sent == 2000);  // one up batch a step
}

TEST_CASE("In lock-step a relay names the children whose batch it still waits for after a while, "
          "and none in real time",
          "[protocol][tree]") {
  // GIVEN 7 agents in lock-step, fan-out 2: 1 > {2, 3}, 2 > {4, 5}, 3 > {6, 7}; agent 5 dead
  const deif::Config lockstep = deif::ParseConfig(
      "agents: {count: 7}\nnetwork: {exchange: tree, tree_fanout: 2, step_timeout_s: 2}\n", "inline");
  Network net(lockstep, Range(1, 7));
  net.dead.insert(5);
  // WHEN step 1 begins at t = 1 and every live agent contributes
  net.Step(1, Range(1, 7), 1.0);
  const TreeExchange& relay = *net.agents.at(2);
  // THEN relay 2 holds its batch (it waits for 5), and names 5 once it has waited 0.1 s
  REQUIRE(relay.ChildrenWaitedForFromS(0.1));
  CHECK(*relay.ChildrenWaitedForFromS(0.1) == Approx(1.1));
  CHECK(relay.ChildrenWaitedFor(1.05, 0.1).empty());
  CHECK(relay.ChildrenWaitedFor(1.2, 0.1) == std::set<AgentId>{5});
  // ... and relay 3, whose children both sent theirs, names nobody
  CHECK_FALSE(net.agents.at(3)->ChildrenWaitedForFromS(0.1));
  // WHEN the members lose 5 (its process ended) THEN relay 2 waits for nobody and sends on
  std::set<AgentId> members{1, 2, 3, 4, 6, 7};
  net.SetMembers(members, 1.3);
  net.Tick(1.3);
  CHECK(relay.ChildrenWaitedFor(1.4, 0.1).empty());
  for (AgentId a : members) CHECK(net.delivered[a][{1, 4}] == (a == 4 ? 0 : 1));
  // AND GIVEN the same in real time THEN no relay names anyone: its wait is short
  const deif::Config realtime = ConfigFor(7, 2);  // the network keeps a reference to it
  Network rt(realtime, Range(1, 7));
  rt.dead.insert(5);
  rt.Step(1, Range(1, 7), 1.0);
  CHECK_FALSE(rt.agents.at(2)->ChildrenWaitedForFromS(0.1));
}

TEST_CASE("A child that hears nothing from a live parent makes its link down anew, less and less often",
          "[protocol][tree]") {
  // 13 agents, fan-out 3: agent 5's parent is 2. Its relay writer lives (no lapse), but no
  // batch of it comes down: the child's reader of it is made anew (docs/SCALING.md, "A link
  // down that hears nothing").
  const deif::Config config = ConfigFor(13, 3);
  TreeExchange child(config, TreeExchange::Options{5, kRun, WriterOf(5)});
  std::vector<AgentId> all;
  for (AgentId a = 1; a <= 13; ++a) all.push_back(a);
  child.SetMembers(std::set<AgentId>(all.begin(), all.end()), 0.0);
  child.TakeActions();
  REQUIRE(child.place().parent == AgentId{2});
  const auto remakes = [&child] {
    std::vector<double> out;  // silent_s of each
    for (const auto& a : child.TakeActions()) {
      if (const auto* r = std::get_if<protocol::tree_action::RemakeLinkDown>(&a)) {
        CHECK(r->parent == 2);
        out.push_back(r->silent_s);
      }
    }
    return out;
  };
  const auto down = [](AgentId sender, StepIndex step) {
    BatchMsg b;
    b.run = kRun;
    b.sender_id = sender;
    b.step = step;
    b.down = true;
    return b;
  };
  // Roll calls every 0.1 s with a batch from the parent each step: never.
  StepIndex k = 1;
  double t = 1.0;
  for (; k <= 20; ++k, t += 0.1) {
    child.OnRollCall(k, all, t);
    child.OnBatch(down(2, k), t + 0.01);
  }
  CHECK(remakes().empty());
  // Nothing from the parent from now on (a batch from another agent does not count): the
  // first roll call 1 s after the last batch makes it anew.
  const double last_heard = t - 0.1 + 0.01;
  // Roll calls every 0.1 s, from `from` while before `until`, none of which may remake it;
  // then one at `until`, which must. Returns the silence it reported.
  const auto silent_until = [&](double from, double until) {
    for (t = from; t < until - 0.05; ++k, t += 0.1) {
      child.OnRollCall(k, all, t);
      child.OnBatch(down(3, k), t + 0.01);
      CHECK(remakes().empty());
    }
    child.OnRollCall(k++, all, until);
    t = until;
    const auto made = remakes();
    REQUIRE(made.size() == 1);
    return made[0];
  };
  // (Counted from the first roll call without one, 0.09 s after the batch.)
  CHECK(silent_until(t, last_heard + 1.12) == Approx(1.12));
  CHECK(child.links_down_remade() == 1);
  // Still nothing: the next one after 2 s of roll calls, not 1.
  CHECK(silent_until(t + 0.1, t + 2.12) == Approx(2.12));
  // A batch from the parent: heard again, and back to 1 s.
  child.OnBatch(down(2, k - 1), t + 0.01);
  CHECK(silent_until(t + 0.1, t + 0.01 + 1.12) == Approx(1.12));
  // This agent itself away for 3 s (frozen): the roll calls queued meanwhile come at once
  // on its return, before its parent's batches; the silence counts from its return.
  child.OnBatch(down(2, k - 1), t + 0.01);
  child.OnAway(t + 3.0, 0.6);
  for (int i = 0; i < 10; ++i) child.OnRollCall(k++, all, t + 3.0);
  CHECK(remakes().empty());
  // The network silent for 3 s (a partition, healed): the roll calls come in a burst, before
  // the parent's batches of their steps: not a deaf link either.
  child.OnBatch(down(2, k - 1), t + 3.01);
  for (int i = 0; i < 10; ++i) child.OnRollCall(k++, all, t + 6.0 + 0.001 * i);
  CHECK(remakes().empty());
  child.OnBatch(down(2, k - 1), t + 6.05);
  // The same with one roll call unheard just before the silence (the last step before a
  // partition): the burst after it is not a second of roll calls without a batch.
  child.OnRollCall(k++, all, t + 6.1);
  for (int i = 0; i < 10; ++i) child.OnRollCall(k++, all, t + 9.0 + 0.001 * i);
  CHECK(remakes().empty());
  CHECK(child.links_down_remade() == 3);
}
