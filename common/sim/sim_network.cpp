#include "common/sim/sim_network.hpp"

#include <algorithm>
#include <cmath>
#include <tuple>

#include "common/core/random.hpp"

namespace deif::sim {

namespace {

// A lost repair round is retried for at most this long before the sample is lost for good
// (a real writer would have long evicted it).
constexpr int kMaxRepairRounds = 1000;
// Samples a frozen process's socket buffer holds per writer (1 MiB of ~300-byte samples).
constexpr std::size_t kSocketBufferSamples = 3000;

}  // namespace

SimNetwork::SimNetwork(const Config& config, std::uint64_t seed)
    : config_(config), seed_(seed) {
  const auto nodes = static_cast<std::size_t>(config.agents.count) + 1;
  nodes_.assign(nodes, NodeState::kRunning);
  incarnation_.assign(nodes, 0);
  last_write_s_.assign(nodes, 0.0);
  Queued tick{0.0, seq_++, LivelinessChange{-1, -1, {}, false}};
  queue_.push(tick);  // reader -1 marks the periodic assertion tick
}

protocol::SenderKey SimNetwork::WriterOf(NodeId node) const {
  protocol::SenderKey key{};
  key[0] = 0xd5;  // "simulated"
  key[1] = static_cast<std::uint8_t>(node & 0xff);
  key[2] = static_cast<std::uint8_t>((node >> 8) & 0xff);
  key[3] = static_cast<std::uint8_t>(incarnation_[static_cast<std::size_t>(node)] & 0xff);
  key[15] = 0x02;
  return key;
}

double SimNetwork::Uniform() {
  return UniformDraw(seed_, NoiseStream::kNetwork, static_cast<std::int64_t>(draws_++), 0);
}

bool SimNetwork::IsRunning(NodeId node) const {
  return nodes_[static_cast<std::size_t>(node)] == NodeState::kRunning;
}

std::vector<NodeId> SimNetwork::Readers(NodeId from, const Message& message) const {
  std::vector<NodeId> readers;
  if (const auto* range = std::get_if<protocol::RangeMsg>(&message)) {
    if (range->agent_id >= 1 && range->agent_id <= config_.agents.count) readers.push_back(range->agent_id);
  } else if (std::holds_alternative<protocol::ContributionMsg>(message)) {
    for (NodeId agent = 1; agent <= config_.agents.count; ++agent) {
      if (agent != from) readers.push_back(agent);
    }
  } else {
    readers.push_back(kTargetNode);
  }
  return readers;
}

bool SimNetwork::Connected(NodeId a, NodeId b) const {
  for (const PartitionConfig& partition : config_.network_sim.partitions) {
    if (step_ < partition.from_step || step_ > partition.to_step) continue;
    const auto inside = [&partition](NodeId node) {
      if (node == kTargetNode) return partition.with_target;
      return std::find(partition.group.begin(), partition.group.end(), node) != partition.group.end();
    };
    if (inside(a) != inside(b)) return false;
  }
  return true;
}

std::size_t SimNetwork::HistoryDepth(const Message& message) const {
  if (std::holds_alternative<protocol::StateMsg>(message)) return 1;
  return static_cast<std::size_t>(config_.network.history_steps);
}

void SimNetwork::Schedule(double time_s, NetworkEvent event) {
  queue_.push(Queued{time_s, seq_++, std::move(event)});
}

void SimNetwork::Send(double now_s, NodeId from, const Message& message) {
  if (!IsRunning(from)) return;
  ++sent_;
  last_write_s_[static_cast<std::size_t>(from)] = now_s;
  if (std::holds_alternative<protocol::StateMsg>(message)) {
    latest_state_[from][incarnation_[static_cast<std::size_t>(from)]] = message;
  }
  for (NodeId to : Readers(from, message)) Transmit(now_s, from, to, message, true);
}

void SimNetwork::Transmit(double now_s, NodeId from, NodeId to, const Message& message,
                          bool first_try) {
  const NodeState reader = nodes_[static_cast<std::size_t>(to)];
  if (reader == NodeState::kDead) return;
  Channel& channel = channels_[{from, to}];
  if (reader == NodeState::kFrozen || !Connected(from, to)) {
    // A frozen reader's host still receives: the samples wait in its socket buffer and all
    // arrive when it resumes. Across a cut link only the writer's reliable history (its
    // last samples per key) can be repaired at the heal.
    channel.held.emplace_back(seq_++, message);
    const std::size_t depth =
        reader == NodeState::kFrozen ? kSocketBufferSamples : HistoryDepth(message);
    if (channel.held.size() > depth) {
      channel.held.erase(channel.held.begin(),
                         channel.held.end() - static_cast<std::ptrdiff_t>(depth));
    }
    return;
  }
  const NetworkSimConfig& net = config_.network_sim;
  double t = now_s + net.delay_min_s + Uniform() * (net.delay_max_s - net.delay_min_s);
  bool lost = Uniform() < net.loss;
  if (first_try && drop_filter_ && drop_filter_(from, to, message)) lost = true;
  if (lost) {
    ++lost_first_try_;
    // Repair: each round a heartbeat, an acknack and the data must all get through.
    const double p_round = std::pow(1.0 - net.loss, 3.0);
    int rounds = 0;
    do {
      t += config_.network.heartbeat_period_s;
      ++rounds;
    } while (Uniform() >= p_round && rounds < kMaxRepairRounds);
    if (rounds >= kMaxRepairRounds) return;
  }
  if (net.reorder > 0.0 && Uniform() < net.reorder) {
    t += net.delay_max_s + config_.network.heartbeat_period_s;  // held back behind others
  }
  t = std::max(t, channel.last_delivery_s);  // in order per writer and reader
  channel.last_delivery_s = t;
  const Delivery delivery{to, from, WriterOf(from), message};
  Schedule(t, delivery);
  if (net.duplicate > 0.0 && Uniform() < net.duplicate) Schedule(t, delivery);
}

std::optional<double> SimNetwork::NextEventTime() const {
  if (queue_.empty()) return std::nullopt;
  return queue_.top().time_s;
}

std::vector<NetworkEvent> SimNetwork::PopDue(double now_s) {
  std::vector<NetworkEvent> out;
  while (!queue_.empty() && queue_.top().time_s <= now_s) {
    Queued item = queue_.top();
    queue_.pop();
    if (auto* change = std::get_if<LivelinessChange>(&item.event)) {
      if (change->reader < 0) {  // the periodic tick
        AssertionTick(item.time_s);
        CheckLiveliness(item.time_s);
        const double period = config_.network.liveliness_lease_s /
                              static_cast<double>(config_.network.liveliness_assertions_per_lease);
        Schedule(item.time_s + period, item.event);
        continue;
      }
      if (IsRunning(change->reader)) {
        out.push_back(item.event);
      } else if (nodes_[static_cast<std::size_t>(change->reader)] == NodeState::kFrozen) {
        missed_while_frozen_[change->reader].push_back(*change);
      }
      continue;
    }
    auto& delivery = std::get<Delivery>(item.event);
    const NodeState reader = nodes_[static_cast<std::size_t>(delivery.to)];
    if (reader == NodeState::kDead) continue;
    if (reader == NodeState::kFrozen) {
      channels_[{delivery.from, delivery.to}].held.emplace_back(item.seq, delivery.message);
      continue;
    }
    Heard(delivery.to, delivery.from, item.time_s);
    out.push_back(item.event);
  }
  return out;
}

void SimNetwork::Heard(NodeId reader, NodeId writer, double now_s) {
  last_heard_s_[{reader, writer}] = now_s;
  bool& alive = believed_alive_[{reader, writer}];
  if (!alive) {
    alive = true;
    Schedule(now_s, LivelinessChange{reader, writer, WriterOf(writer), true});
  }
}

void SimNetwork::AssertionTick(double now_s) {
  // An idle writer asserts its liveliness to every reader it can reach (best effort).
  const double period = config_.network.liveliness_lease_s /
                        static_cast<double>(config_.network.liveliness_assertions_per_lease);
  const NodeId agents = config_.agents.count;
  for (NodeId writer = 0; writer <= agents; ++writer) {
    if (!IsRunning(writer)) continue;
    if (now_s - last_write_s_[static_cast<std::size_t>(writer)] < period) continue;
    for (NodeId reader = 0; reader <= agents; ++reader) {
      if (reader == writer || !IsRunning(reader) || !Connected(writer, reader)) continue;
      if (Uniform() >= config_.network_sim.loss) Heard(reader, writer, now_s);
    }
  }
}

void SimNetwork::CheckLiveliness(double now_s) {
  for (auto& [pair, alive] : believed_alive_) {
    if (!alive) continue;
    const auto& [reader, writer] = pair;
    if (!IsRunning(reader)) continue;
    if (now_s - last_heard_s_[pair] > config_.network.liveliness_lease_s) {
      alive = false;
      Schedule(now_s, LivelinessChange{reader, writer, WriterOf(writer), false});
    }
  }
}

void SimNetwork::SetStep(StepIndex step, double now_s) {
  if (step == step_) return;
  step_ = step;
  ReleaseHeld(now_s);
}

void SimNetwork::ReleaseHeld(double now_s) {
  // Everything that can now reach its reader goes out in the order it was first sent.
  std::vector<std::tuple<std::uint64_t, NodeId, NodeId, Message>> release;
  for (auto& [link, channel] : channels_) {
    if (channel.held.empty()) continue;
    const auto& [from, to] = link;
    if (!IsRunning(to) || !Connected(from, to)) continue;
    for (auto& [seq, message] : channel.held) release.emplace_back(seq, from, to, std::move(message));
    channel.held.clear();
  }
  std::sort(release.begin(), release.end(),
            [](const auto& a, const auto& b) { return std::get<0>(a) < std::get<0>(b); });
  for (const auto& [seq, from, to, message] : release) Transmit(now_s, from, to, message, false);
}

void SimNetwork::Kill(NodeId node, double /*now_s*/) {
  nodes_[static_cast<std::size_t>(node)] = NodeState::kDead;
  for (auto& [link, channel] : channels_) {
    if (link.second == node) channel.held.clear();
  }
}

void SimNetwork::Freeze(NodeId node, double /*now_s*/) {
  nodes_[static_cast<std::size_t>(node)] = NodeState::kFrozen;
}

void SimNetwork::Resume(NodeId node, double now_s) {
  nodes_[static_cast<std::size_t>(node)] = NodeState::kRunning;
  // Its own view of its writers' liveliness starts afresh (what it missed while frozen is
  // not a loss of theirs).
  for (auto& [pair, heard_s] : last_heard_s_) {
    if (pair.first == node) heard_s = now_s;
  }
  ReleaseHeld(now_s);
  // But a process that was replaced meanwhile is gone for it too.
  auto missed = missed_while_frozen_.find(node);
  if (missed != missed_while_frozen_.end()) {
    for (const LivelinessChange& change : missed->second) Schedule(now_s, change);
    missed_while_frozen_.erase(missed);
  }
}

void SimNetwork::Restart(NodeId node, double now_s) {
  // The old process is gone: every reader that saw it alive sees it lost now.
  for (auto& [pair, alive] : believed_alive_) {
    if (pair.second == node && alive) {
      alive = false;
      Schedule(now_s, LivelinessChange{pair.first, node, WriterOf(node), false});
    }
    if (pair.first == node) alive = false;
  }
  for (auto& [link, channel] : channels_) {
    if (link.first == node || link.second == node) {
      channel.held.clear();
      channel.last_delivery_s = now_s;
    }
  }
  ++incarnation_[static_cast<std::size_t>(node)];
  nodes_[static_cast<std::size_t>(node)] = NodeState::kRunning;
  last_write_s_[static_cast<std::size_t>(node)] = now_s;
  // Transient-local: a new reader of agent_state gets every live writer's latest state.
  if (node == kTargetNode) {
    for (NodeId agent = 1; agent <= config_.agents.count; ++agent) {
      if (!IsRunning(agent)) continue;
      auto states = latest_state_.find(agent);
      if (states == latest_state_.end() || states->second.empty()) continue;
      Transmit(now_s, agent, node, states->second.rbegin()->second, false);
    }
  }
}

}  // namespace deif::sim
