// The deif_agent application: DDS adapters around one AgentCore. It only transports: every
// number it publishes or writes comes from AgentCore, so its estimates equal those of the
// in-process simulation for the same inputs.
#pragma once

#include <atomic>
#include <cstdint>
#include <deque>
#include <map>
#include <memory>
#include <optional>
#include <set>
#include <string>
#include <utility>
#include <variant>

#include <spdlog/logger.h>

#include "dds/dds_common.hpp"
#include "common/protocol/agent_core.hpp"
#include "common/artefacts/artefacts.hpp"
#include "common/config/config.hpp"
#include "deif.h"

namespace deif::agent {

struct AgentOptions {
  AgentId id = 0;
  std::string out_dir;  // where agent_<id>.csv goes; empty: no CSV
};

// Exit codes of deif_agent (and deif_target).
inline constexpr int kExitOk = 0;
inline constexpr int kExitRuntimeError = 1;
inline constexpr int kExitBadConfig = 2;
inline constexpr int kExitDuplicateId = 3;

class AgentApp {
 public:
  // Creates the core, then every DDS entity. Throws ConfigError for a configuration the
  // core refuses, std::runtime_error when DDS entities cannot be created.
  AgentApp(const Config& config, AgentOptions options, std::shared_ptr<spdlog::logger> log);
  ~AgentApp();
  AgentApp(const AgentApp&) = delete;
  AgentApp& operator=(const AgentApp&) = delete;

  // Runs until the scenario ends, the target announces the end, or stop(). Returns the
  // process exit code.
  int run();
  // Thread-safe; makes run() return soon.
  void stop();

 private:
  struct TruthEvent { deif_msgs::Truth msg; };
  struct RangeEvent { deif_msgs::Range msg; };
  struct ContributionEvent { deif_msgs::Contribution msg; dds::WriterKey writer; };
  struct StateEvent { deif_msgs::AgentState msg; dds::WriterKey writer; };
  enum class WriterTopic { kContribution, kAgentState };
  struct WriterEvent { WriterTopic topic; dds::WriterKey writer; bool alive; };
  using Event = std::variant<TruthEvent, RangeEvent, ContributionEvent, StateEvent, WriterEvent>;

  // Waits for events until the deadline (or one arrives) and applies them.
  void Pump(dds::Clock::time_point deadline);
  void Handle(const Event& event);
  void OnContribution(const deif_msgs::Contribution& msg, const dds::WriterKey& writer);
  void OnRange(const deif_msgs::Range& msg);
  void OnState(const deif_msgs::AgentState& msg, const dds::WriterKey& writer);
  void OnWriterChanged(const WriterEvent& event);

  bool RefuseDuplicateId();
  // Waits for the next step to do (the newest range for this agent beyond done_). Returns
  // the step and its range (nullopt when advancing on the target's truth without a range),
  // or nullopt when the run is over.
  std::optional<std::pair<StepIndex, std::optional<RangeObservation>>> WaitForNextStep();
  void DoStep(StepIndex k, const std::optional<RangeObservation>& z);
  bool Eligible(AgentId m, StepIndex k) const;
  bool HoldsEverythingFor(StepIndex k) const;
  void IdentifyContributionWriters();
  std::map<AgentId, Vector2> MemberPositions(StepIndex k, const std::vector<Contribution>& fused) const;
  std::set<AgentId> Members() const;  // alive members, this agent included
  void Publish(const AgentSnapshot& snapshot, bool write_csv);
  void Reject(AgentId peer, const std::string& reason);
  void Drop(AgentId peer, const std::string& reason);
  // After missed steps: adopt the lowest-id member's estimate of `step`, if we hold it.
  std::optional<AgentId> AdoptPeerEstimate(StepIndex step);
  bool ValidPeerId(AgentId id) const;

  // Declaration order is destruction order in reverse: the asserter stops before the
  // participant is deleted, and the participant (with every entity) before the listeners
  // and the inbox they push into.
  const Config& config_;
  AgentOptions options_;
  std::shared_ptr<spdlog::logger> log_;
  AgentCore core_;
  const std::uint64_t instance_token_;
  std::atomic<bool> stop_requested_{false};
  dds::Inbox<Event> inbox_;
  dds::ReaderListener<deif_msgs::Truth> truth_listener_;
  dds::ReaderListener<deif_msgs::Range> range_listener_;
  dds::ReaderListener<deif_msgs::Contribution> contribution_listener_;
  dds::ReaderListener<deif_msgs::AgentState> state_listener_;
  std::unique_ptr<dds::DdsParticipant> participant_;
  dds::fdds::DataWriter* contribution_writer_ = nullptr;
  dds::fdds::DataWriter* state_writer_ = nullptr;
  dds::WriterKey own_contribution_writer_{};
  dds::WriterKey own_state_writer_{};
  std::unique_ptr<dds::LivelinessAsserter> asserter_;
  std::optional<AgentCsv> csv_;

  // Application-thread state (touched only by run() and the handlers it calls).
  StepIndex done_ = 0;         // the last step finished (0: the initial state)
  StepIndex active_step_ = 1;  // the step being worked on; the fusion window is about it
  StepIndex newest_target_step_ = 0;  // the newest step seen in a truth or one of our ranges
  std::map<StepIndex, RangeObservation> ranges_;  // this agent's ranges beyond done_
  std::deque<Vector2> published_positions_;       // our latest published positions
  std::map<StepIndex, dds::Clock::time_point> truth_seen_;  // target steps beyond done_
  bool end_of_run_ = false;
  dds::WriterTracker contribution_writers_;
  dds::WriterTracker state_writers_;
  std::set<AgentId> fused_last_step_;  // ids fused at step done_
  std::map<dds::ParticipantPrefix, AgentId> participant_ids_;  // from agent_state samples
  std::set<dds::WriterKey> ignored_writers_;  // writers whose samples were refused by id
  std::map<StepIndex, std::map<AgentId, Contribution>> held_;  // validated, not yet fused
  std::map<AgentId, std::map<StepIndex, Vector2>> positions_;  // peers' published positions
  // Peers' published estimates x(k|k) and position covariances, for a rejoin.
  std::map<AgentId, std::map<StepIndex, std::pair<Vector2, Matrix2>>> estimates_;
  std::map<dds::WriterKey, std::uint64_t> same_id_writers_;    // state writers using our id
  std::set<std::pair<AgentId, std::string>> logged_;           // log-once (peer, reason)
  long rejected_ = 0;
  long dropped_ = 0;
};

}  // namespace deif::agent
