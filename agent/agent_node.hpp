// deif_agent's application: the thin DDS adapter around the agent's protocol
// (common/protocol/agent_protocol.hpp). It only delivers events and carries out actions:
// every number it publishes or writes comes from the protocol, so its estimates equal those
// of the in-process simulation for the same inputs.
#pragma once

#include <atomic>
#include <cstdint>
#include <map>
#include <optional>
#include <set>
#include <string>
#include <utility>
#include <vector>

#include "common/artefacts/artefacts.hpp"
#include "common/protocol/agent_protocol.hpp"
#include "common/protocol/discovery_watch.hpp"
#include "common/protocol/tree_exchange.hpp"
#include "dds/application.hpp"
#include "dds/counters.hpp"
#include "dds/delivery.hpp"
#include "dds/node.hpp"

namespace deif::agent {

class AgentNode : public dds::Application {
 public:
  // Creates every DDS entity. Throws std::runtime_error when one cannot be created.
  AgentNode(dds::ProcessContext& context, AgentId id);
  int Run() override;
  void Stop() override;
  bool LeaveQuietly() override;
  bool RestartInPlace() const override { return restart_in_place_; }

 private:
  // Another live process with this id (its state, with another instance token) refuses us.
  bool AnotherProcessHasThisId();
  void Dispatch(const dds::Event& event, double now_s);
  // Whether `writer` may speak for agent `claimed`: always without security; with it, only
  // when its permissions name that id (docs/SECURITY.md).
  bool Authorised(AgentId claimed, const protocol::SenderKey& writer) const;
  void Execute(std::vector<protocol::AgentAction> actions);
  // Carries out the tree exchange's actions; its deliveries last, after its sends.
  void ExecuteRelay(std::vector<protocol::TreeAction> actions);
  // Carries out what the protocol and the tree exchange ask until neither asks more.
  void Pump();
  // The members the tree is made of (network.exchange: tree): the agents of the run whose
  // participants are up, less those the protocol saw lost, and this one.
  std::set<AgentId> TreeMembers() const;
  // Puts the relay endpoints in the partitions of a tree place with `parent`: before they
  // exist (move false), or moving them (true).
  void PlaceRelays(std::optional<AgentId> parent, bool move, bool keep_watch = false);
  // Drops the watches on parents that are no longer silent (all of them once none is).
  void DropWatchesOnReturn();
  static std::string ParentName(std::optional<AgentId> parent);
  // How long a gap between two wake-ups of the loop means this process was away.
  double AwayAfterS() const;
  // Ends Run() when this process can no longer hear (Node::ReceiveStuck): restarts it in
  // place (RestartInPlace), at most dds::kMaxRestartsInPlace times in a process's life.
  int Deaf();
  bool DeafForTest() const;  // DEIF_FAULT_DEAF (dds::FaultDeafStep)
  bool ThrowForTest();       // DEIF_FAULT_THROW (dds::FaultThrowStep), once
  bool CrashForTest();       // DEIF_FAULT_CRASH (dds::FaultCrashStep), once
  bool ReaderLoopForTest() const;  // DEIF_FAULT_READER_LOOP (dds::FaultReaderLoopStep)
  // Whether this agent's endpoint discovery stopped short of the participants it sees
  // (protocol::DiscoveryWatch) and it is to start again in place with a new participant. If
  // it already did so dds::kMaxRestartsInPlace times, it says so once and goes on.
  bool DiscoveryStoppedShort(double now_s);
  // With a Discovery Server: whether the server forgot this agent while the target's
  // participant is still listed up (dds::ServerForgetting), and it is to start again in place
  // with a new participant (as DiscoveryStoppedShort).
  bool ForgottenByTheServer(double now_s);
  // Tells the protocol what the transport has matched (docs/PROTOCOL.md, "Start").
  void ReportMatches(double now_s);
  // Whether the relay endpoints of this agent's place in the tree matched their other ends:
  // its parent's (one each way) and its children's (docs/SCALING.md).
  bool TreeLinksMatched() const;
  // In lock-step, the peers whose processes this agent looks at often because a step waits
  // for them: members of the open step (AgentProtocol::MembersWaitedFor) and, in the tree,
  // children whose batch its relay waits for (TreeExchange::ChildrenWaitedFor); and from
  // when on.
  std::set<AgentId> WaitedFor(double now_s) const;
  std::optional<double> WaitedForFromS() const;
  // network.membership: roll_call (docs/PROTOCOL.md, "Membership from the roll call").
  bool RollCallMembership() const { return EffectiveMembership(config_) == MembershipKind::kRollCall; }
  // With membership from the roll call: this agent and the peers whose participants it sees
  // (ReportMatches), as of ParticipantsVersion peers_up_version_.
  int peers_up_ = 1;
  std::optional<std::uint64_t> peers_up_version_;
  // <out>/agent_<id>.counters.json: what this process rejected and dropped, by reason, and
  // how long samples took to reach it.
  void WriteCounters() const;
  std::string CountersPath() const;
  // What the earlier process wrote there, for a process started again (--append): its counts
  // go on from them (dds::AddEarlierCounters).
  nlohmann::json earlier_counters_;
  double counters_due_s_ = 0.0;  // when the counters are written next while it runs

  dds::ProcessContext& context_;
  const Config& config_;
  const AgentId id_;
  const std::uint64_t instance_token_;
  const dds::Timings timings_;  // the config's, as the network's size makes them (EffectiveTimings)
  dds::Node node_;
  protocol::AgentProtocol protocol_;
  std::optional<protocol::TreeExchange> tree_;  // network.exchange: tree
  // The participants' and the protocol's membership versions the tree was last made from.
  std::pair<std::uint64_t, std::uint64_t> tree_version_{~0ull, ~0ull};
  bool tree_live_ = false;  // the run has begun: the tree follows the members
  // Relay writers to this agent (deif/relay_down) -> the parent whose batches they carried:
  // their liveliness is the parent's (TreeExchange::OnParentLiveliness).
  std::map<protocol::SenderKey, AgentId> parent_writers_;
  // The same of the parents it left because they fell silent, heard on the watches its
  // reader left in their partitions (docs/SCALING.md, "A parent heard again").
  std::map<protocol::SenderKey, AgentId> silent_writers_;
  double last_loop_s_ = -1.0;  // when the loop last woke
  std::optional<AgentCsv> csv_;
  dds::DeliveryDelays delivery_;  // docs/ARTEFACTS.md, "Delivery delays"
  std::atomic<bool> stop_requested_{false};
  std::optional<int> exit_code_;
  bool restart_in_place_ = false;  // this process can no longer hear (Node::ReceiveStuck)
  bool watching_ports_ = true;     // dds::RestartForLostPorts
  bool threw_for_test_ = false;    // ThrowForTest
  bool crashed_for_test_ = false;  // CrashForTest
  std::vector<dds::Event> early_events_;  // taken during the start-up check, replayed after
  protocol::DiscoveryWatch discovery_watch_;
  dds::ServerForgetting forgetting_;  // network.discovery: server
};

}  // namespace deif::agent
