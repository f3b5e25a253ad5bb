// deif_target's application: the thin DDS adapter around the target's protocol
// (common/protocol/target_protocol.hpp): the world, its truth and every agent's range.
// With --hold-for-faults it prints "hold <step> <faults>" on stdout when it reaches a step
// with scripted faults and, in lock-step, waits for "go <step>" on stdin (the launcher
// applies the faults in between), so faults land on their exact step.
#pragma once

#include <atomic>
#include <deque>
#include <filesystem>
#include <mutex>
#include <optional>
#include <set>
#include <thread>

#include "common/artefacts/artefacts.hpp"
#include "common/protocol/discovery_watch.hpp"
#include "common/protocol/target_protocol.hpp"
#include "dds/application.hpp"
#include "dds/counters.hpp"
#include "dds/delivery.hpp"
#include "dds/node.hpp"

namespace deif::target {

struct TargetOptions {
  std::optional<StepIndex> start_step;  // a restarted target: resume here at the earliest
  bool hold_for_faults = false;
};

// The rows a target started again (--start-step or --append) finds in its files, which it
// never writes again: target.csv's steps up to truth_through; ranges.csv's steps before
// ranges_through, and at that step the agents in ranges_at_last.
struct RowsOnFile {
  StepIndex truth_through = 0;
  StepIndex ranges_through = 0;
  std::set<AgentId> ranges_at_last;
};

class TargetNode : public dds::Application {
 public:
  TargetNode(dds::ProcessContext& context, TargetOptions options);
  ~TargetNode() override;
  int Run() override;
  void Stop() override;
  bool LeaveQuietly() override;
  bool RestartInPlace() const override { return restart_in_place_; }
  // --start-step with the step after the one it had reached (or the one it was given): the
  // new process never goes back, even when the agents it finds restarted too and report no
  // step yet.
  dds::RestartOptions RestartOptionsOf() const override;

 private:
  bool AnotherTargetInThisRun();
  void WriteCounters() const;
  std::string CountersPath() const;
  // What the earlier process wrote there, for a process started again (--append): its counts
  // go on from them (dds::AddEarlierCounters).
  nlohmann::json earlier_counters_;
  double counters_due_s_ = 0.0;  // when the counters are written next while it runs
  bool DeafForTest() const;  // DEIF_FAULT_DEAF (dds::FaultDeafStep)
  bool CrashForTest(StepIndex step);  // DEIF_FAULT_CRASH (dds::FaultCrashStep), once
  // While it waits for the agents: whether its range writer has stopped short of agents that
  // are present (their states arrive, no reader of theirs matched, unchanged for
  // dds::DiscoveryPatienceS), so that it starts again in place with a new participant
  // (docs/FASTDDS_NOTES.md, "Endpoint discovery that stops short"). Not with security.
  bool DiscoveryStoppedShort(double now_s);
  // With a Discovery Server: whether the server forgot the target while agents' participants
  // are still listed up (dds::ServerForgetting), and it is to start again in place with a new
  // participant.
  bool ForgottenByTheServer(double now_s);
  void Execute(std::vector<protocol::TargetAction> actions);
  void ReadControl();  // the stdin thread: "go <step>" lines
  void Dispatch(const dds::Event& event, double now_s);

  dds::ProcessContext& context_;
  const Config& config_;
  const TargetOptions options_;
  const RowsOnFile on_file_;  // read once, before protocol_ (its floor)
  dds::Node node_;
  protocol::TargetProtocol protocol_;
  std::optional<TargetCsv> target_csv_;
  std::optional<RangesCsv> ranges_csv_;
  std::atomic<bool> stop_requested_{false};
  bool crashed_for_test_ = false;  // CrashForTest
  bool restart_in_place_ = false;  // this process can no longer hear (Node::ReceiveStuck)
  bool watching_ports_ = true;     // dds::RestartForLostPorts
  std::optional<int> exit_code_;
  std::mutex control_mutex_;
  std::deque<StepIndex> go_steps_;  // guarded by control_mutex_
  std::thread control_thread_;
  std::vector<dds::Event> early_events_;  // taken during the start-up check, replayed after
  protocol::DiscoveryWatch discovery_watch_;
  dds::ServerForgetting forgetting_;  // network.discovery: server
  dds::DeliveryDelays delivery_;  // docs/ARTEFACTS.md, "Delivery delays"
};

}  // namespace deif::target
