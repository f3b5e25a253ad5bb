// The deif_target application: the world. It moves the target (TargetCore), publishes the
// truth and every alive agent's noisy range, and paces the lock-step protocol.
#pragma once

#include <atomic>
#include <map>
#include <memory>
#include <optional>
#include <set>
#include <string>
#include <variant>

#include <spdlog/logger.h>

#include "dds/dds_common.hpp"
#include "common/artefacts/artefacts.hpp"
#include "common/config/config.hpp"
#include "common/protocol/target_core.hpp"
#include "deif.h"
#include "target/csv_appender.hpp"

namespace deif::target {

struct TargetOptions {
  std::string out_dir;                  // where target.csv and ranges.csv go; empty: none
  std::optional<StepIndex> start_step;  // resume from this step (after a restart)
};

inline constexpr int kExitOk = 0;
inline constexpr int kExitRuntimeError = 1;
inline constexpr int kExitBadConfig = 2;

class TargetApp {
 public:
  TargetApp(const Config& config, TargetOptions options, std::shared_ptr<spdlog::logger> log);
  ~TargetApp();
  TargetApp(const TargetApp&) = delete;
  TargetApp& operator=(const TargetApp&) = delete;

  int run();
  void stop();  // thread-safe

 private:
  struct StateEvent { deif_msgs::AgentState msg; dds::WriterKey writer; };
  struct WriterEvent { dds::WriterKey writer; bool alive; };
  using Event = std::variant<StateEvent, WriterEvent>;

  void Pump(dds::Clock::time_point deadline);
  // Alive agents (state writer alive) with a known latest state.
  std::set<AgentId> AliveAgents() const;
  // Waits for the agents before the first step; returns the first step, or nullopt.
  std::optional<StepIndex> WaitForAgents();
  void OpenArtefacts(bool append);
  void PublishStep(StepIndex k, const std::set<AgentId>& agents);
  void WaitForStates(StepIndex k, const std::set<AgentId>& agents);
  void PublishEndOfRun();

  const Config& config_;
  TargetOptions options_;
  std::shared_ptr<spdlog::logger> log_;
  TargetCore core_;
  std::atomic<bool> stop_requested_{false};
  dds::Inbox<Event> inbox_;
  dds::ReaderListener<deif_msgs::AgentState> state_listener_;
  std::unique_ptr<dds::DdsParticipant> participant_;  // after the listener: deleted first
  dds::fdds::DataWriter* truth_writer_ = nullptr;
  dds::fdds::DataWriter* range_writer_ = nullptr;

  dds::WriterTracker state_writers_;
  std::map<AgentId, deif_msgs::AgentState> latest_;  // the last state received per agent
  std::optional<TargetCsv> target_csv_;
  std::optional<RangesCsv> ranges_csv_;
  std::unique_ptr<CsvAppender> target_append_;
  std::unique_ptr<CsvAppender> ranges_append_;
};

}  // namespace deif::target
