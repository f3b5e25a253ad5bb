// libFuzzer harness of the tree exchange's relay (common/protocol/tree_exchange.hpp;
// docs/SCALING.md; docs/TESTING.md, "Fuzzing").
//
// One relay of a small run gets a fuzzed sequence of events: batches from any sender (its
// fields, run token and contributions fuzzed: NaN, huge values, foreign ids, steps far
// away, too many items), its own contributions, roll calls, member sets and the clock.
// Besides never crashing: every contribution it hands to the step protocol or sends on is
// one the validators accept, of this run, and never its own back; every batch it sends is
// its own, of this run, within the size a sample may have, and goes up only when it has a
// parent; what it keeps stays bounded.
#include <algorithm>
#include <cstddef>
#include <cstdint>
#include <map>
#include <set>
#include <string>
#include <utility>
#include <vector>

#include "common/config/config.hpp"
#include "common/protocol/tree_exchange.hpp"
#include "common/protocol/validation.hpp"
#include "tests/fuzz/fuzz_input.hpp"

namespace {

using deif::AgentId;
using deif::Config;
using deif::StepIndex;
using deif::fuzz::FuzzInput;
using deif::fuzz::Violation;
namespace protocol = deif::protocol;

constexpr protocol::RunToken kRun = 99;

const Config& ConfigOf(std::uint8_t pick) {
  static std::map<std::uint8_t, Config> cache;
  const std::uint8_t key = pick % 6;
  auto it = cache.find(key);
  if (it != cache.end()) return it->second;
  const int agents = 3 + key * 2;  // 3..13
  const int fanout = 1 + key % 3;
  const std::string mode = key % 2 == 0 ? "lockstep" : "realtime";
  const std::string yaml = "scenario: {steps: 40, mode: " + mode + ", period_s: 0.1}\nagents: {count: " +
                           std::to_string(agents) + "}\nnetwork: {history_steps: 4, fusion_window_steps: 1, " +
                           "tree_fanout: " + std::to_string(fanout) + ", relay_wait_s: 0.02}\n";
  return cache.emplace(key, deif::ParseConfig(yaml, "fuzz-tree")).first->second;
}

protocol::SenderKey WriterOf(AgentId id) {
  protocol::SenderKey key{};
  key[0] = static_cast<std::uint8_t>(id);
  key[15] = 0x77;
  return key;
}

// A valid contribution (what the step protocol hands the relay as its own).
protocol::ContributionMsg ValidContribution(const Config& config, AgentId id, StepIndex step) {
  protocol::ContributionMsg c;
  c.run = kRun;
  c.agent_id = id;
  c.instance_token = 1;
  c.step = step;
  c.info_vector << 0.5, -0.25;
  c.info_matrix << 2.0, 0.5, 0.5, 3.0;
  c.p_sensor << 1.0, 2.0;
  const int dim = config.filter.motion_model.StateDim();
  c.basis.y = deif::StateVector::Zero(dim);
  c.basis.Y = deif::StateMatrix::Identity(dim, dim);
  return c;
}

// Mostly a valid contribution of a near step; sometimes any field fuzzed (a peer's).
protocol::ContributionMsg Contribution(FuzzInput& in, const Config& config, AgentId id, StepIndex step) {
  protocol::ContributionMsg c = ValidContribution(config, id, step);
  const std::uint8_t fuzz = in.Byte();
  if ((fuzz & 0x01u) != 0) c.info_vector = in.Vec2();
  if ((fuzz & 0x02u) != 0) c.info_matrix(0, 1) = in.Double();
  if ((fuzz & 0x04u) != 0) c.info_matrix(1, 1) = in.Double();
  if ((fuzz & 0x08u) != 0) c.p_sensor = in.Vec2();
  if ((fuzz & 0x10u) != 0) c.basis.y(0) = in.Double();
  if ((fuzz & 0x20u) != 0) c.run = in.U64();
  if ((fuzz & 0x40u) != 0) c.agent_id = in.SmallInt();
  if ((fuzz & 0x80u) != 0) c.step = in.Int();
  return c;
}

// `parent`: the relay's parent when the event came. The actions are carried out in order, so
// a batch sent up before a move in the same event went to the parent of that moment. Returns
// the parent after the moves the actions announce.
std::optional<AgentId> Check(const std::vector<protocol::TreeAction>& actions, std::optional<AgentId> parent,
                             const Config& config, AgentId self) {
  const auto valid = [&](const protocol::RelayedContribution& item) {
    return item.msg.run == kRun && protocol::ValidAgentId(item.msg.agent_id, config) &&
           protocol::ValidateContributionMsg(item.msg, config) == nullptr;
  };
  for (const protocol::TreeAction& action : actions) {
    if (const auto* deliver = std::get_if<protocol::tree_action::Deliver>(&action)) {
      if (!valid(deliver->item)) Violation("delivered a contribution the validators refuse");
      if (deliver->item.msg.agent_id == self && deliver->item.origin == WriterOf(self)) {
        Violation("delivered its own contribution back to itself");
      }
    } else if (const auto* move = std::get_if<protocol::tree_action::Reparent>(&action)) {
      if (move->silent && (move->parent == move->silent || *move->silent == self)) {
        Violation("moved under the parent it left as silent, or took itself for silent");
      }
      parent = move->parent;
    } else if (const auto* send = std::get_if<protocol::tree_action::Send>(&action)) {
      const protocol::BatchMsg& b = send->batch;
      if (b.run != kRun || b.sender_id != self) Violation("sent a batch that is not its own");
      if (b.items.size() > protocol::kSentBatchItems) Violation("sent a batch larger than a sample may be");
      if (!b.down && !parent) Violation("sent up without a parent");
      for (const auto& item : b.items) {
        if (!valid(item)) Violation("forwarded a contribution the validators refuse");
      }
    }
  }
  if (actions.size() > 100000) Violation("an event made an unbounded number of actions");
  return parent;
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  FuzzInput in(data, size);
  const Config& config = ConfigOf(in.Byte());
  const int n = config.agents.count;
  const AgentId self = 1 + static_cast<AgentId>(in.Byte() % n);
  protocol::TreeExchange relay(config, protocol::TreeExchange::Options{self, kRun, WriterOf(self)});
  double now = 0.0;
  StepIndex step = 1;
  while (!in.empty()) {
    const std::optional<AgentId> parent = relay.place().parent;
    switch (in.Byte() % 9) {
      case 0: {  // a batch from anyone
        protocol::BatchMsg batch;
        batch.run = in.Bool() ? kRun : in.U64();
        batch.sender_id = in.Bool() ? 1 + static_cast<AgentId>(in.Byte() % n) : in.SmallInt();
        batch.step = in.Bool() ? step : in.Int();
        batch.down = in.Bool();
        const std::size_t items = in.Byte() == 255 ? protocol::kMaxBatchItems + 1 : in.Byte() % 8;
        for (std::size_t i = 0; i < items; ++i) {
          const AgentId id = 1 + static_cast<AgentId>(in.Byte() % n);
          const StepIndex k = step - 2 + static_cast<StepIndex>(in.Byte() % 5);
          batch.items.push_back({in.Bool() ? WriterOf(id) : WriterOf(static_cast<AgentId>(in.Byte())),
                                 Contribution(in, config, id, k)});
        }
        relay.OnBatch(batch, now);
        break;
      }
      case 1:  // its own contribution of the current step
        relay.OnOwn(ValidContribution(config, self, step), now);
        break;
      case 2: {  // the roll call of a step (ids fuzzed)
        std::vector<AgentId> roll;
        for (AgentId id = 1; id <= n; ++id) {
          if (in.Bool()) roll.push_back(id);
        }
        relay.OnRollCall(in.Bool() ? step : in.Int(), roll, now);
        break;
      }
      case 3: {  // the members change (itself always added by the relay)
        std::set<AgentId> members;
        for (AgentId id = 1; id <= n; ++id) {
          if (in.Byte() % 4 != 0) members.insert(id);
        }
        relay.SetMembers(members, now);
        break;
      }
      case 4:  // time passes
        now += 0.001 * static_cast<double>(in.Byte());
        relay.OnTimer(now);
        break;
      case 5:  // the next step (within the run, as the step protocol's own are)
        step = 1 + (step + in.Byte() % 3) % config.scenario.steps;
        break;
      case 6: {  // a relay writer's liveliness: mostly the parent's, else anyone's
        const AgentId id = in.Bool() && relay.place().parent ? *relay.place().parent : in.SmallInt();
        relay.OnParentLiveliness(id, in.Bool(), now);
        break;
      }
      case 7:  // it was away itself (its loop stood still)
        relay.OnAway(now, 0.01 * static_cast<double>(in.Byte()));
        break;
      default:  // up to its next deadline
        if (const auto due = relay.NextDeadline()) {
          if (!(*due >= now - 1e-9)) Violation("a deadline that is not a time");
          now = std::max(now, *due);
        }
        relay.OnTimer(now);
        break;
    }
    if (Check(relay.TakeActions(), parent, config, self) != relay.place().parent) {
      Violation("moved without saying so (a Reparent action for every move)");
    }
  }
  return 0;
}
