// A simulated network with the semantics the step protocol relies on from DDS, in virtual
// time and deterministic from a seed (docs/PROTOCOL.md, "The simulated network"):
//
// - Topics: a range goes from the target to the agent it is keyed to; a contribution from
//   an agent to every other agent; a state from an agent to the target.
// - Reliable, in order per writer and reader: a lost message is repaired after heartbeat
//   periods (each repair round needs a heartbeat, an acknack and the data to get through),
//   and later messages of the same writer wait behind it, as a reliable DDS reader does.
// - History: a writer keeps the last network.history_steps samples per key (the state
//   writer only the last one); what a partitioned or frozen reader missed beyond that is
//   lost for good, the rest arrives when it can.
// - Liveliness: a reader sees a writer alive while it hears from it (data or, when the
//   writer is idle, an assertion; assertions are best effort) within the lease.
// - Faults: per-message loss, uniform delay, duplicates, reordering, partitions by step
//   window and group (network_sim:), and nodes killed, frozen, resumed or restarted.
#pragma once

#include <cstdint>
#include <functional>
#include <map>
#include <optional>
#include <queue>
#include <set>
#include <variant>
#include <vector>

#include "common/config/config.hpp"
#include "common/protocol/messages.hpp"

namespace deif::sim {

using NodeId = int;  // 0: the target; 1..N: the agents
inline constexpr NodeId kTargetNode = 0;

using Message = std::variant<protocol::RangeMsg, protocol::ContributionMsg, protocol::StateMsg>;

// What the network hands to a node.
struct Delivery {
  NodeId to = 0;
  NodeId from = 0;
  protocol::SenderKey writer{};
  Message message;
};
struct LivelinessChange {
  NodeId reader = 0;
  NodeId writer_node = 0;
  protocol::SenderKey writer{};
  bool alive = false;
};
using NetworkEvent = std::variant<Delivery, LivelinessChange>;

// A scripted drop: return true to lose this message on its first transmission (tests).
using DropFilter = std::function<bool(NodeId from, NodeId to, const Message&)>;

class SimNetwork {
 public:
  SimNetwork(const Config& config, std::uint64_t seed);

  // The writer identity of a node's messages (changes when the node restarts).
  protocol::SenderKey WriterOf(NodeId node) const;

  void Send(double now_s, NodeId from, const Message& message);

  // The time of the next event, if any.
  std::optional<double> NextEventTime() const;
  // Pops every event due at or before now_s, in order.
  std::vector<NetworkEvent> PopDue(double now_s);

  // The step the network is at (the target's newest step), for partitions by step.
  void SetStep(StepIndex step, double now_s);

  // Node faults.
  void Kill(NodeId node, double now_s);
  void Freeze(NodeId node, double now_s);
  void Resume(NodeId node, double now_s);
  // A new process in place of `node` (a restarted target): a new writer identity; it gets
  // every writer's transient-local history of the topics it reads.
  void Restart(NodeId node, double now_s);
  bool IsRunning(NodeId node) const;

  void SetDropFilter(DropFilter filter) { drop_filter_ = std::move(filter); }

  // Statistics.
  std::int64_t sent() const { return sent_; }
  std::int64_t lost_first_try() const { return lost_first_try_; }

 private:
  struct Channel {
    double last_delivery_s = 0.0;  // in order: nothing overtakes what went before
    // Samples held back while the link is cut or the reader frozen, in order, with the
    // global send order (seq) so a resumed reader gets them as its socket would.
    std::vector<std::pair<std::uint64_t, Message>> held;
  };
  struct Queued {
    double time_s;
    std::uint64_t seq;
    NetworkEvent event;
    bool operator>(const Queued& other) const {
      return time_s != other.time_s ? time_s > other.time_s : seq > other.seq;
    }
  };
  enum class NodeState { kRunning, kFrozen, kDead };

  std::vector<NodeId> Readers(NodeId from, const Message& message) const;
  bool Connected(NodeId a, NodeId b) const;
  void Transmit(double now_s, NodeId from, NodeId to, const Message& message, bool first_try);
  void Schedule(double time_s, NetworkEvent event);
  void Heard(NodeId reader, NodeId writer, double now_s);
  void AssertionTick(double now_s);
  void CheckLiveliness(double now_s);
  void ReleaseHeld(double now_s);
  std::size_t HistoryDepth(const Message& message) const;
  double Uniform();

  const Config& config_;
  std::uint64_t seed_;
  std::uint64_t draws_ = 0;
  std::uint64_t seq_ = 0;
  StepIndex step_ = 0;
  std::vector<NodeState> nodes_;
  std::vector<int> incarnation_;
  std::vector<double> last_write_s_;
  std::map<std::pair<NodeId, NodeId>, Channel> channels_;  // (from, to)
  std::map<std::pair<NodeId, NodeId>, double> last_heard_s_;  // (reader, writer)
  std::map<std::pair<NodeId, NodeId>, bool> believed_alive_;  // (reader, writer)
  // Liveliness changes that came while their reader was frozen: a restarted process's old
  // incarnation is lost for it too, and it learns so once resumed (a real process's
  // middleware finds the lease expired; docs/PROTOCOL.md, "Rejoining").
  std::map<NodeId, std::vector<LivelinessChange>> missed_while_frozen_;
  std::map<NodeId, std::map<int, Message>> latest_state_;      // for a restarted target
  std::priority_queue<Queued, std::vector<Queued>, std::greater<Queued>> queue_;
  DropFilter drop_filter_;
  std::int64_t sent_ = 0;
  std::int64_t lost_first_try_ = 0;
};

}  // namespace deif::sim
