// libFuzzer harness of the agent's step protocol (common/protocol/agent_protocol.hpp;
// docs/TESTING.md, "Fuzzing").
//
// A small run (2 to 4 agents, a few steps, a short history) of real AgentProtocols and a
// real TargetProtocol over a network the fuzz input drives, one byte an event: deliver the
// next message, deliver one out of order, drop or duplicate one, move time on (or to the
// next deadline), change a writer's liveliness, kill or restart a process, report matched
// peers, or inject a message built from a real one with fuzzed fields (NaN, infinities,
// huge values, odd roll calls, other runs, steps and ids) and a fuzzed sender key. At the
// end the network is drained so the run can finish. What must hold throughout:
// - no crash, no sanitizer report, no hang;
// - no agent writes a row, or publishes a state, with a non-finite estimate or covariance;
// - memory stays bounded: the input (and so the number of events) is capped, and so is
//   the queue of messages in flight.
#include <algorithm>
#include <array>
#include <cmath>
#include <cstddef>
#include <cstdint>
#include <deque>
#include <map>
#include <memory>
#include <optional>
#include <set>
#include <string>
#include <variant>
#include <vector>

#include "common/config/config.hpp"
#include "common/protocol/agent_protocol.hpp"
#include "common/protocol/messages.hpp"
#include "common/protocol/target_protocol.hpp"
#include "tests/fuzz/fuzz_input.hpp"

namespace {

using deif::AgentId;
using deif::Config;
using deif::StepIndex;
using deif::Vector2;
using deif::fuzz::FuzzInput;
using deif::fuzz::Violation;
namespace protocol = deif::protocol;
using protocol::AgentProtocol;
using protocol::ContributionMsg;
using protocol::RangeMsg;
using protocol::SenderKey;
using protocol::StateMsg;
using protocol::TargetProtocol;

constexpr std::size_t kMaxInput = 4096;     // bytes; also -max_len in tests/fuzz/CMakeLists.txt
constexpr std::size_t kMaxQueue = 2048;     // messages in flight
constexpr int kDrainRounds = 2000;          // events after the input to let the run finish
constexpr protocol::RunToken kRun = 42;
constexpr int kTarget = 0;

// One config per variant byte: lock-step or real time, the two motion models, gate on or
// off, 2..4 agents, a history of 2 or 5 steps, a fusion window of 1 or 2.
const Config& ConfigOf(std::uint8_t variant) {
  static std::map<std::uint8_t, Config> cache;
  auto it = cache.find(variant);
  if (it != cache.end()) return it->second;
  const int agents = 2 + (variant >> 4) % 3;
  const std::string yaml =
      std::string("scenario: {steps: ") + ((variant & 0x40u) != 0 ? "16" : "6") +
      ", mode: " + ((variant & 1u) != 0 ? "realtime" : "lockstep") + ", period_s: 0.05}\n" +
      "filter: {motion_model: " + ((variant & 2u) != 0 ? "constant_velocity" : "random_walk") +
      ", innovation_gate_sigma: " + ((variant & 4u) != 0 ? "0" : "20") + "}\n" +
      "agents: {count: " + std::to_string(agents) + "}\n" +
      "network: {step_timeout_s: 0.5, start_timeout_s: 2.0, history_steps: " +
      ((variant & 8u) != 0 ? "5" : "2") + ", fusion_window_steps: " +
      ((variant & 0x80u) != 0 ? "2" : "1") + "}\n";
  return cache.emplace(variant, deif::ParseConfig(yaml, "fuzz")).first->second;
}

SenderKey KeyOf(int node, int incarnation) {
  SenderKey key{};
  key[0] = 0x7e;
  key[1] = static_cast<std::uint8_t>(node);
  key[2] = static_cast<std::uint8_t>(incarnation);
  return key;
}

using Message = std::variant<RangeMsg, ContributionMsg, StateMsg>;

struct Envelope {
  int to = 0;
  SenderKey from{};
  Message message;
};

bool Finite(const Vector2& v) { return std::isfinite(v.x()) && std::isfinite(v.y()); }
bool Finite(const deif::Matrix2& m) { return m.allFinite(); }

class Network {
 public:
  // peer_grace_s: AgentProtocol::Options::peer_grace_s (< 0: the config's grace); relayed:
  // contributions arrive as a relay's batches do (AgentProtocol::OnContributions);
  // roll_call: AgentProtocol::Options::roll_call_membership, and a process's death or restart
  // reaches the agents by no liveliness but the target's.
  Network(const Config& config, double peer_grace_s, bool relayed, bool roll_call = false)
      : config_(config), peer_grace_s_(peer_grace_s), relayed_(relayed), roll_call_(roll_call) {
    for (AgentId id = 1; id <= config.agents.count; ++id) StartAgent(id);
    StartTarget(std::nullopt);
  }

  // ---- the events
  void DeliverAt(std::size_t index) {
    if (queue_.empty()) return;
    index %= queue_.size();
    Envelope e = std::move(queue_[index]);
    queue_.erase(queue_.begin() + static_cast<std::ptrdiff_t>(index));
    Deliver(e);
  }
  void DropAt(std::size_t index) {
    if (!queue_.empty()) queue_.erase(queue_.begin() + static_cast<std::ptrdiff_t>(index % queue_.size()));
  }
  void DuplicateAt(std::size_t index) {
    if (!queue_.empty()) Push(Envelope(queue_[index % queue_.size()]));
  }
  bool QueueEmpty() const { return queue_.empty(); }

  void AdvanceTime(double dt_s) {
    now_ += dt_s;
    FireTimers();
  }
  // Moves time to the earliest deadline any process asked for.
  bool AdvanceToNextDeadline() {
    std::optional<double> next;
    for (auto& [id, agent] : agents_) {
      if (dead_.count(id) > 0) continue;
      const auto d = agent->NextDeadline();
      if (d && (!next || *d < *next)) next = d;
    }
    if (dead_.count(kTarget) == 0) {
      const auto d = target_->NextDeadline();
      if (d && (!next || *d < *next)) next = d;
    }
    if (!next) return false;
    now_ = std::max(now_, *next);
    FireTimers();
    return true;
  }

  void Liveliness(int reader, const SenderKey& writer, bool alive) {
    if (dead_.count(reader) > 0) return;
    if (reader == kTarget) {
      target_->OnWriterLiveliness(writer, alive, now_);
      CollectTarget();
    } else {
      agents_.at(reader)->OnWriterLiveliness(writer, alive, now_);
      Collect(reader);
    }
  }
  void PeersMatched(AgentId id, int matched, int range_writers) {
    if (dead_.count(id) > 0) return;
    agents_.at(id)->OnPeersMatched(matched, range_writers, now_);
    Collect(id);
  }

  // A process dies: what it had queued dies with it, everyone sees its writers lost.
  void Kill(int node) {
    if (dead_.count(node) > 0) return;
    dead_.insert(node);
    const SenderKey key = Key(node);
    queue_.erase(std::remove_if(queue_.begin(), queue_.end(),
                                [&](const Envelope& e) { return e.from == key; }),
                 queue_.end());
    for (int reader = 0; reader <= config_.agents.count; ++reader) {
      if (reader != node && Hears(reader, node)) Liveliness(reader, key, false);
    }
  }
  // A dead process starts again with new writers.
  void Restart(int node, StepIndex start_step) {
    if (dead_.count(node) == 0) return;
    dead_.erase(node);
    ++incarnation_[node];
    if (node == kTarget) {
      StartTarget(start_step);
    } else {
      StartAgent(node);
    }
    for (int reader = 0; reader <= config_.agents.count; ++reader) {
      if (reader != node && Hears(reader, node)) Liveliness(reader, Key(node), true);
    }
  }
  // Whether `reader` hears the liveliness of `node`'s writers: with the roll call an agent
  // hears only the target's.
  bool Hears(int reader, int node) const { return !roll_call_ || reader == kTarget || node == kTarget; }

  void Inject(int to, const SenderKey& from, Message message) {
    Deliver(Envelope{to, from, std::move(message)});
  }

  // ---- what the fuzz input mutates
  SenderKey Key(int node) { return KeyOf(node, incarnation_[node]); }
  const Config& config() const { return config_; }
  std::optional<RangeMsg> last_range(AgentId id) const {
    auto it = last_range_.find(id);
    return it == last_range_.end() ? std::nullopt : std::optional<RangeMsg>(it->second);
  }
  const std::optional<ContributionMsg>& last_contribution() const { return last_contribution_; }
  const std::optional<StateMsg>& last_state() const { return last_state_; }
  const std::vector<Vector2>& positions(AgentId id) { return positions_[id]; }
  StepIndex newest_step() const { return newest_step_; }
  bool AllFinished() const {
    for (const auto& [id, agent] : agents_) {
      if (dead_.count(id) == 0 && !agent->finished()) return false;
    }
    return true;
  }

 private:
  void StartAgent(AgentId id) {
    AgentProtocol::Options options;
    options.run = kRun;
    options.instance_token = 1000u * static_cast<unsigned>(incarnation_[id]) + static_cast<unsigned>(id);
    options.peer_grace_s = peer_grace_s_;
    options.roll_call_membership = roll_call_;
    agents_[id] = std::make_unique<AgentProtocol>(config_, id, options);
    agents_[id]->Start(now_);
    Collect(id);
  }
  void StartTarget(std::optional<StepIndex> start_step) {
    TargetProtocol::Options options;
    options.run = kRun;
    if (start_step && *start_step >= 1 && *start_step <= config_.scenario.steps) {
      options.start_step = start_step;
    }
    target_ = std::make_unique<TargetProtocol>(config_, options);
    target_->Start(now_);
    CollectTarget();
  }

  void FireTimers() {
    for (auto& [id, agent] : agents_) {
      if (dead_.count(id) > 0) continue;
      agent->OnTimer(now_);
      Collect(id);
    }
    if (dead_.count(kTarget) == 0) {
      target_->OnTimer(now_);
      CollectTarget();
    }
  }

  void Deliver(const Envelope& e) {
    if (dead_.count(e.to) > 0) return;
    if (e.to == kTarget) {
      if (const auto* state = std::get_if<StateMsg>(&e.message)) {
        target_->OnState(*state, e.from, now_);
        CollectTarget();
      }
      return;
    }
    AgentProtocol& agent = *agents_.at(e.to);
    if (const auto* range = std::get_if<RangeMsg>(&e.message)) agent.OnRange(*range, e.from, now_);
    if (const auto* c = std::get_if<ContributionMsg>(&e.message)) {
      if (relayed_) {
        agent.OnContributions({{*c, e.from}}, now_);
      } else {
        agent.OnContribution(*c, e.from, now_);
      }
    }
    Collect(e.to);
  }

  void Push(Envelope e) {
    if (queue_.size() < kMaxQueue) queue_.push_back(std::move(e));
  }

  void Collect(AgentId id) {
    const SenderKey from = Key(id);
    for (auto& action : agents_.at(id)->TakeActions()) {
      if (auto* c = std::get_if<protocol::agent_action::PublishContribution>(&action)) {
        last_contribution_ = c->msg;
        for (AgentId peer = 1; peer <= config_.agents.count; ++peer) {
          if (peer != id) Push(Envelope{peer, from, c->msg});
        }
      } else if (auto* s = std::get_if<protocol::agent_action::PublishState>(&action)) {
        if (!Finite(s->msg.estimate_m) || !Finite(s->msg.covariance) || !Finite(s->msg.position_m)) {
          Violation("agent " + std::to_string(id) + " published a state with a non-finite estimate at step " +
                    std::to_string(s->msg.step));
        }
        last_state_ = s->msg;
        auto& mine = positions_[id];
        mine.push_back(s->msg.position_m);
        if (mine.size() > 8) mine.erase(mine.begin());
        Push(Envelope{kTarget, from, s->msg});
      } else if (auto* r = std::get_if<protocol::agent_action::WriteRow>(&action)) {
        if (!Finite(r->row.estimate_m) || !Finite(r->row.covariance) || !Finite(r->row.position_m) ||
            !std::isfinite(r->row.angle_rad)) {
          Violation("agent " + std::to_string(id) + " wrote a non-finite row at step " +
                    std::to_string(r->row.step));
        }
      }
    }
  }

  void CollectTarget() {
    const SenderKey from = Key(kTarget);
    for (auto& action : target_->TakeActions()) {
      if (auto* r = std::get_if<protocol::target_action::PublishRange>(&action)) {
        last_range_[r->msg.agent_id] = r->msg;
        newest_step_ = std::max(newest_step_, r->msg.step);
        Push(Envelope{r->msg.agent_id, from, r->msg});
      }
    }
  }

  const Config& config_;
  const double peer_grace_s_;
  const bool relayed_;
  const bool roll_call_;
  std::map<AgentId, std::unique_ptr<AgentProtocol>> agents_;
  std::unique_ptr<TargetProtocol> target_;
  std::map<int, int> incarnation_;
  std::set<int> dead_;
  std::deque<Envelope> queue_;
  double now_ = 0.0;
  std::map<AgentId, RangeMsg> last_range_;
  std::optional<ContributionMsg> last_contribution_;
  std::optional<StateMsg> last_state_;
  std::map<AgentId, std::vector<Vector2>> positions_;
  StepIndex newest_step_ = 0;
};

// ---- fuzzed messages: a real one (or a plain one) with the fields a mask picks replaced

SenderKey FuzzKey(FuzzInput& in, Network& net) {
  const std::uint8_t kind = in.Byte();
  if (kind < 192) return net.Key(kind % (net.config().agents.count + 1));  // a known writer
  SenderKey key{};
  for (auto& b : key) b = in.Byte();
  return key;
}

std::vector<AgentId> FuzzRollCall(FuzzInput& in, const Config& config) {
  std::vector<AgentId> ids;
  const std::uint8_t shape = in.Byte();
  if (shape < 128) {  // a plausible roll call: a subset of the ids, ascending
    for (AgentId id = 1; id <= config.agents.count; ++id) {
      if (((shape >> (id - 1)) & 1u) != 0) ids.push_back(id);
    }
    return ids;
  }
  const std::size_t n = shape % 8;
  for (std::size_t i = 0; i < n; ++i) ids.push_back(in.SmallInt());
  return ids;
}

StepIndex FuzzStep(FuzzInput& in, StepIndex near) {
  const std::uint8_t kind = in.Byte();
  if (kind < 200) return near + static_cast<StepIndex>(kind % 7) - 3;
  return in.Int();
}

RangeMsg FuzzRange(FuzzInput& in, Network& net, AgentId to) {
  const Config& config = net.config();
  RangeMsg msg;
  if (auto last = net.last_range(to)) {
    msg = *last;
  } else {
    msg.run = kRun;
    msg.agent_id = to;
    msg.step = 1;
    msg.measured = true;
    msg.range_m = 2.0;
    msg.variance_m2 = config.filter.range_variance_m2;
    for (AgentId id = 1; id <= config.agents.count; ++id) msg.roll_call.push_back(id);
  }
  const std::uint16_t mask = in.U16();
  if (mask & 1u) msg.run = in.Bool() ? kRun + 1 : in.U64();
  if (mask & 2u) msg.agent_id = in.SmallInt();
  if (mask & 4u) msg.step = FuzzStep(in, msg.step);
  if (mask & 8u) msg.t_s = in.Double();
  if (mask & 16u) msg.measured = in.Bool();
  if (mask & 32u) msg.range_m = in.Double();
  if (mask & 64u) msg.variance_m2 = in.Double();
  if (mask & 128u) {
    const auto& mine = net.positions(to);
    msg.p_sensor = !mine.empty() && in.Bool() ? mine[in.Byte() % mine.size()] : in.Vec2();
  }
  if (mask & 256u) msg.roll_call = FuzzRollCall(in, config);
  return msg;
}

ContributionMsg FuzzContribution(FuzzInput& in, Network& net) {
  const Config& config = net.config();
  ContributionMsg msg;
  if (net.last_contribution()) {
    msg = *net.last_contribution();
  } else {
    msg.run = kRun;
    msg.agent_id = 1;
    msg.step = 1;
    const int dim = config.filter.motion_model.StateDim();
    msg.basis.y = deif::StateVector::Zero(dim);
    msg.basis.Y = deif::StateMatrix::Identity(dim, dim);
  }
  const std::uint16_t mask = in.U16();
  if (mask & 1u) msg.run = in.Bool() ? kRun + 1 : in.U64();
  if (mask & 2u) msg.agent_id = in.Bool() ? 1 + in.Byte() % config.agents.count : in.SmallInt();
  if (mask & 4u) msg.instance_token = in.U64();
  if (mask & 8u) msg.step = FuzzStep(in, msg.step);
  if (mask & 16u) msg.info_vector = in.Vec2();
  if (mask & 32u) msg.info_matrix(in.Byte() % 4) = in.Double();
  if (mask & 64u) msg.info_matrix(in.Byte() % 4) = in.Double();
  if (mask & 128u) msg.p_sensor = in.Vec2();
  if (mask & 256u) {
    const Eigen::Index n = msg.basis.y.size();
    if (n > 0) msg.basis.y(in.Byte() % n) = in.Double();
  }
  if (mask & 512u) {
    const Eigen::Index n = msg.basis.Y.rows();
    if (n > 0) {
      const Eigen::Index r = in.Byte() % n;
      const Eigen::Index c = in.Byte() % n;
      msg.basis.Y(r, c) = in.Double();
      if (in.Bool()) msg.basis.Y(c, r) = msg.basis.Y(r, c);
    }
  }
  if (mask & 1024u) {
    // A basis of another dimension: 0 to 4, what the state types (and the wire, 2 or 4)
    // can hold at all (common/core/types.hpp).
    const int n = in.Byte() % (deif::kMaxStateDim + 1);
    msg.basis.y = deif::StateVector::Zero(n);
    msg.basis.Y = deif::StateMatrix::Identity(n, n);
  }
  if (mask & 2048u) msg.merge_request = !msg.merge_request;
  return msg;
}

StateMsg FuzzState(FuzzInput& in, Network& net) {
  StateMsg msg;
  if (net.last_state()) {
    msg = *net.last_state();
  } else {
    msg.run = kRun;
    msg.agent_id = 1;
  }
  const std::uint16_t mask = in.U16();
  if (mask & 1u) msg.run = in.Bool() ? kRun + 1 : in.U64();
  if (mask & 2u) msg.agent_id = in.SmallInt();
  if (mask & 4u) msg.instance_token = in.U64();
  if (mask & 8u) msg.step = FuzzStep(in, msg.step);
  if (mask & 16u) msg.position_m = in.Vec2();
  if (mask & 32u) msg.angle_rad = in.Double();
  if (mask & 64u) msg.estimate_m = in.Vec2();
  if (mask & 128u) msg.matched = in.SmallInt();
  if (mask & 256u) msg.alive = in.SmallInt();
  return msg;
}

double FuzzDelay(FuzzInput& in) {
  const std::uint8_t b = in.Byte();
  if (b < 200) return b * 0.005;                 // up to 1 s
  if (b < 250) return (b - 199) * 0.5;           // up to 25 s: beyond every timeout
  return b == 255 ? 1e9 : 1e-9 * (b - 249);      // a very long silence, or almost nothing
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  if (size > kMaxInput) return -1;  // not added to the corpus
  FuzzInput in(data, size);
  const Config& config = ConfigOf(in.Byte());
  const int nodes = config.agents.count + 1;
  const std::uint8_t mode = in.Byte();
  constexpr double kPeerGraces[] = {-1.0, 0.3, 1.0, 5.0};
  Network net(config, kPeerGraces[mode % 4], (mode & 4u) != 0, (mode & 8u) != 0);

  while (!in.empty()) {
    const std::uint8_t op = in.Byte();
    switch (op % 16) {
      case 0:
      case 1:
      case 2:
      case 3:
        // In order; when nothing is in flight, time moves on to the next deadline.
        if (net.QueueEmpty()) {
          net.AdvanceToNextDeadline();
        } else {
          net.DeliverAt(0);
        }
        break;
      case 4: net.DeliverAt(in.Byte()); break;
      case 5: net.DropAt(in.Byte()); break;
      case 6: net.DuplicateAt(in.Byte()); break;
      case 7: net.AdvanceTime(FuzzDelay(in)); break;
      case 8: {
        const int reader = in.Byte() % nodes;
        const SenderKey writer = FuzzKey(in, net);
        net.Liveliness(reader, writer, in.Bool());
        break;
      }
      case 9: {
        const AgentId to = 1 + in.Byte() % config.agents.count;
        const SenderKey from = FuzzKey(in, net);
        net.Inject(to, from, FuzzRange(in, net, to));
        break;
      }
      case 10:
      case 11: {
        const AgentId to = 1 + in.Byte() % config.agents.count;
        const SenderKey from = FuzzKey(in, net);
        net.Inject(to, from, FuzzContribution(in, net));
        break;
      }
      case 12: {
        const SenderKey from = FuzzKey(in, net);
        net.Inject(kTarget, from, FuzzState(in, net));
        break;
      }
      case 13: net.Kill(in.Byte() % nodes); break;
      case 14: net.Restart(in.Byte() % nodes, net.newest_step() + in.Byte() % 3); break;
      case 15: net.PeersMatched(1 + in.Byte() % config.agents.count, in.SmallInt(), in.SmallInt()); break;
    }
  }
  // Let the run finish: deliver everything, and move time on when nothing is in flight.
  for (int round = 0; round < kDrainRounds && !net.AllFinished(); ++round) {
    if (net.QueueEmpty()) {
      if (!net.AdvanceToNextDeadline()) net.AdvanceTime(1.0);
    } else {
      net.DeliverAt(0);
    }
  }
  return 0;
}
