// The DDS node (node.hpp). QoS choices are explained in docs/ARCHITECTURE.md ("Topics and
// QoS"); the Fast DDS facts they rest on in docs/FASTDDS_NOTES.md.
#include "dds/node.hpp"

#include <algorithm>
#include <array>
#include <atomic>
#include <condition_variable>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <map>
#include <mutex>
#include <optional>
#include <random>
#include <regex>
#include <set>
#include <sstream>
#include <stdexcept>
#include <thread>

#include <spdlog/fmt/fmt.h>

#include <fastdds/dds/core/condition/GuardCondition.hpp>
#include <fastdds/dds/core/condition/StatusCondition.hpp>
#include <fastdds/dds/core/condition/WaitSet.hpp>
#include <fastdds/dds/domain/DomainParticipant.hpp>
#include <fastdds/dds/domain/DomainParticipantFactory.hpp>
#include <fastdds/dds/domain/DomainParticipantListener.hpp>
#include <fastdds/dds/publisher/DataWriter.hpp>
#include <fastdds/dds/publisher/DataWriterListener.hpp>
#include <fastdds/dds/publisher/Publisher.hpp>
#include <fastdds/dds/subscriber/DataReader.hpp>
#include <fastdds/dds/subscriber/DataReaderListener.hpp>
#include <fastdds/dds/subscriber/SampleInfo.hpp>
#include <fastdds/dds/subscriber/Subscriber.hpp>
#include <fastdds/dds/log/Log.hpp>
#include <fastdds/dds/log/StdoutErrConsumer.hpp>
#include <fastdds/dds/topic/ContentFilteredTopic.hpp>
#include <fastdds/dds/topic/IContentFilter.hpp>
#include <fastdds/dds/topic/IContentFilterFactory.hpp>
#include <fastdds/dds/topic/Topic.hpp>
#include <fastdds/rtps/attributes/ServerAttributes.h>
#include <fastdds/rtps/transport/UDPv4TransportDescriptor.h>
#include <fastdds/rtps/transport/shared_mem/SharedMemTransportDescriptor.h>
#include <fastrtps/utils/IPLocator.h>

#include "dds/conversions.hpp"
#include "dds/locked_key.hpp"
#include "dds/security.hpp"
#include "dds/shm_ports.hpp"
#include "deifPubSubTypes.h"

namespace deif::dds {

namespace fdds = eprosima::fastdds::dds;
using eprosima::fastrtps::Duration_t;

namespace {

Duration_t DdsDuration(double seconds) { return Duration_t(static_cast<long double>(seconds)); }

protocol::SenderKey ToKey(const fdds::InstanceHandle_t& handle) {
  protocol::SenderKey key{};
  for (std::size_t i = 0; i < key.size(); ++i) key[i] = handle.value[static_cast<unsigned>(i)];
  return key;
}

// The QoS of each topic: one row per topic (docs/ARCHITECTURE.md, "Topics and QoS").
struct TopicQos {
  fdds::DurabilityQosPolicyKind durability;
  int writer_depth;         // per instance (agent id)
  int reader_depth;
  bool manual_liveliness;   // MANUAL_BY_TOPIC with network.liveliness_lease_s
  bool sized_by_use = false;  // samples allocated as large as they are, not as the type's bound
  // The lease is network.relay_lease_s (EffectiveRelayLeaseS), not the lease of every agent's
  // writers: a relay writer has at most tree_fanout readers.
  bool relay_lease = false;
};

TopicQos QosOf(Topic topic, const NetworkConfig& network) {
  const int history = network.history_steps;
  switch (topic) {
    case Topic::kTruth:  // observers only; a late joiner needs no old truth, but an observer
                         // that lags a fast lock-step by up to the history keeps every step
      return {fdds::VOLATILE_DURABILITY_QOS, 8, std::max(8, history), false};
    case Topic::kRange:  // the roll calls a frozen or cut-off agent missed, up to the history
      return {fdds::TRANSIENT_LOCAL_DURABILITY_QOS, history, history, true};
    case Topic::kContribution:  // what a late or cut-off peer missed, up to the history
      return {fdds::TRANSIENT_LOCAL_DURABILITY_QOS, history, history, true};
    case Topic::kAgentState:  // the latest state of every agent, also for a restarted target
      return {fdds::TRANSIENT_LOCAL_DURABILITY_QOS, 1, 4, true};
    case Topic::kRelayUp:  // what a relay's new parent missed, up to the history (docs/SCALING.md);
                           // a batch's bound is 256 contributions
      return {fdds::TRANSIENT_LOCAL_DURABILITY_QOS, history, history, false, true};
    case Topic::kRelayDown:  // what a new child missed; its liveliness tells the children that
                             // their parent fell silent (docs/SCALING.md, "Losing a relay")
      return {fdds::TRANSIENT_LOCAL_DURABILITY_QOS, history, history, true, true, true};
  }
  return {fdds::VOLATILE_DURABILITY_QOS, 1, 1, false};
}

// Liveliness and heartbeat traffic grow as N^2 (every writer to every matched reader). On a
// busy host that traffic is what starves the processes, and starved processes look dead:
// the effective timings are derived so that the whole network's liveliness assertions stay
// within kLivelinessBudgetPerS messages per second, and their heartbeats (each writer's to
// each matched reader while a sample is unacknowledged) within kHeartbeatBudgetPerS
// (docs/BENCHMARKS.md, "Heartbeats at large N"). At N = 64 on 2 cores a 32 ms heartbeat
// made 1.4-1.6 steps/s and 0.2-0.3 s made 3.4-3.5: slow acknowledgements under load draw
// more heartbeats, which draw more acknowledgements.
constexpr double kLivelinessBudgetPerS = 4000.0;
constexpr double kHeartbeatBudgetPerS = 20000.0;
// The target's share in real time: heartbeats of the agents' state writers, N of them
// (WriterHeartbeatS).
constexpr double kTargetHeartbeatBudgetPerS = 2000.0;
// Participant announcements grow as N^2 too: each process's reaches every other, a wake-up
// of a receive thread each. At N = 64 the default 0.5 s period made 8320 a second; within
// this budget (2.08 s) a 64-agent lock-step ran 7.6 steps/s against 5.8, with 23 % less CPU
// a step (docs/BENCHMARKS.md, "Participant announcements at large N").
constexpr double kAnnouncementBudgetPerS = 2000.0;
// Renewals of an idle writer that may go missing in a row before a peer takes it for lost.
// With two renewals per lease a single lost one makes the lease run out as the next is due:
// 32 agents on 3 hosts with 15 % loss took 720-780 live peers for lost in a 20 s run with
// the grace of 0.2 s, 25-35 when a lapse counted only after 4 renewals in a row went
// missing (docs/BENCHMARKS.md, "Repairs in real time, measured 2026-11-26").
constexpr int kRenewalsLostInARow = 4;

}  // namespace

Timings EffectiveTimings(const Config& config) {
  const NetworkConfig& net = config.network;
  const double pairs = static_cast<double>(config.agents.count) * (config.agents.count + 1);
  Timings t;
  // No more assertions than configured or than the budget affords, and at least two per
  // lease (one if so configured): the lease grows until the budget affords them. With a
  // single assertion per lease, any delay of one assertion lets the lease run out; at
  // N = 64 that was about 60 false losses in every start-up (docs/BENCHMARKS.md,
  // "Liveliness at large N").
  const int least = std::min(2, net.liveliness_assertions_per_lease);
  t.liveliness_lease_s = std::max(net.liveliness_lease_s, least * pairs / kLivelinessBudgetPerS);
  const double affordable = kLivelinessBudgetPerS * t.liveliness_lease_s / pairs;
  t.assertions_per_lease = std::max(
      least, std::min(net.liveliness_assertions_per_lease, static_cast<int>(affordable + 1e-9)));
  t.heartbeat_period_s = std::max(net.heartbeat_period_s, pairs / kHeartbeatBudgetPerS);
  // A longer announcement period comes with a lease as many periods long as configured, so
  // that a starved process does not lose its peers sooner (measured in periods).
  t.participant_announcement_s =
      std::max(net.participant_announcement_s, pairs / kAnnouncementBudgetPerS);
  t.participant_lease_s =
      net.participant_lease_s * (t.participant_announcement_s / net.participant_announcement_s);
  t.peer_grace_s = net.liveliness_grace_s;
  if (EffectiveExchange(config) == ExchangeKind::kTree) {
    const double renewal_s = t.liveliness_lease_s / t.assertions_per_lease;
    // Half a renewal past the (kRenewalsLostInARow + 1)-th renewal's time: a loss then falls
    // between two renewals' arrivals, not on one (at 20 agents, 3 renewals a lease, most of
    // the losses were undone a millisecond later by a renewal that came just after).
    t.peer_grace_s =
        std::max(t.peer_grace_s, (kRenewalsLostInARow + 1.5) * renewal_s - t.liveliness_lease_s);
  }
  return t;
}

namespace {

// A duration in seconds as the clock's.
Clock::duration Seconds(double s) {
  return std::chrono::duration_cast<Clock::duration>(std::chrono::duration<double>(s));
}

// Renewals per lease of a relay writer, at most: it writes every step, and with
// network.liveliness_assertions_per_lease (8) it also asserted between the writes of a 10 Hz
// run, a message to each child every period.
constexpr int kRelayRenewals = 3;

// A MANUAL_BY_TOPIC writer's lease, and how long it may stay idle before it asserts.
double LeaseOf(const TopicQos& spec, const Config& config) {
  return spec.relay_lease ? EffectiveRelayLeaseS(config) : EffectiveTimings(config).liveliness_lease_s;
}
double AssertPeriodOf(const TopicQos& spec, const Config& config) {
  if (spec.relay_lease) {
    return LeaseOf(spec, config) / std::clamp(config.network.liveliness_assertions_per_lease, 1, kRelayRenewals);
  }
  const Timings t = EffectiveTimings(config);
  return t.liveliness_lease_s / t.assertions_per_lease;
}

}  // namespace

double ForgottenAfterS(const Timings& timings) {
  return timings.participant_lease_s + 2.0 * timings.participant_announcement_s;
}

void ServerForgetting::Note(const Event& event, double now_s) {
  if (const auto* change = std::get_if<LivelinessChange>(&event)) {
    if (change->alive) {
      alive_writers_.insert(change->writer);
    } else {
      alive_writers_.erase(change->writer);
    }
  } else {
    watch_.Heard(now_s);
  }
}

std::optional<std::string> ServerForgetting::Forgotten(const Node& node, const std::function<bool()>& peers_listed,
                                                       const std::string& hears, double now_s) {
  // Forgotten takes a silence longer than the patience after the server was found again; no
  // writer it reads alive (a target that died leaves the peers' writers alive).
  if (watch_.silent_s(now_s) <= patience_s_ || !alive_writers_.empty()) return std::nullopt;
  const std::optional<double> server_since = node.DiscoveryServerSinceS();
  if (!watch_.Forgotten(now_s, patience_s_, server_since && peers_listed() ? server_since : std::nullopt)) {
    return std::nullopt;
  }
  return fmt::format("heard {} for {:.1f} s, {:.1f} s of it since the Discovery Server was found again, while the "
                     "participants it should hear are still listed up: the server took this process for gone "
                     "(docs/FASTDDS_NOTES.md, \"Forgotten by the server\")",
                     hears, watch_.silent_s(now_s), now_s - *server_since);
}

double DiscoveryPatienceS(const Config& config, int restarts_in_place) {
  const double base = std::max(5.0, 4.0 * EffectiveTimings(config).participant_announcement_s);
  return base * static_cast<double>(1 << std::clamp(restarts_in_place, 0, 8));
}

namespace {

template <typename Qos>
void ApplyCommon(Qos& qos, const TopicQos& spec, int depth, const Config& config) {
  qos.reliability().kind = fdds::RELIABLE_RELIABILITY_QOS;
  qos.durability().kind = spec.durability;
  qos.history().kind = fdds::KEEP_LAST_HISTORY_QOS;
  qos.history().depth = depth;
  // One instance per agent id (and id 0 is never used). Fast DDS 2.9 defaults to 10
  // instances: an 11th agent was silently never seen.
  const int instances = config.agents.count + 1;
  qos.resource_limits().max_instances = instances;
  qos.resource_limits().max_samples_per_instance = depth;
  qos.resource_limits().max_samples = instances * depth;
  qos.resource_limits().allocated_samples = std::min(instances * depth, 64);
  if (spec.manual_liveliness) {
    // AUTOMATIC liveliness does not detect a killed writer in Fast DDS 2.9.1.
    qos.liveliness().kind = fdds::MANUAL_BY_TOPIC_LIVELINESS_QOS;
    qos.liveliness().lease_duration = DdsDuration(LeaseOf(spec, config));
    qos.liveliness().announcement_period = DdsDuration(AssertPeriodOf(spec, config));
  }
  qos.data_sharing().off();
  if (spec.sized_by_use) {
    qos.endpoint().history_memory_policy = eprosima::fastrtps::rtps::DYNAMIC_REUSABLE_MEMORY_MODE;
  }
}

}  // namespace

double WriterHeartbeatS(Topic topic, const Config& config, bool per_agent_writer) {
  const double budgeted = EffectiveTimings(config).heartbeat_period_s;
  if (config.scenario.mode != StepMode::kRealTime) return budgeted;
  // In real time a lost sample delays its reader past the deadline, and with it every
  // agent that waits for what the reader sends next (a lost range: that agent's
  // contribution, missing from every agent's step). The N^2 budget is for writers that
  // every agent reads; these have a few readers each, so they may repair sooner
  // (docs/BENCHMARKS.md, "Repairs in real time, measured 2026-11-26"). Not in lock-step,
  // where on one busy host slow acknowledgements drew more heartbeats and cost 20 % of the
  // steps a second (docs/BENCHMARKS.md, "The tree exchange, measured 2026-11-26").
  const double n = config.agents.count;
  const bool udp = config.network.transport == TransportKind::kUdp;
  if (topic == Topic::kRelayUp || topic == Topic::kRelayDown || (topic == Topic::kRange && per_agent_writer && udp)) {
    // At most tree_fanout readers each, spread over the agents: 2 N pairs in the network
    // (20 agents, 3 hosts, 10 % loss, 10 Hz: 97 % of the agent-steps complete against 81 %).
    // The target's writer of one agent's ranges, over UDPv4 (the runs across hosts, where
    // samples are lost in transit), repairs as soon: a range repaired after the 32 ms of the
    // target's own budget (below) at 64 agents came after the agent's relay had sent its
    // batch up, and the contribution went late to every agent (64 agents, 4 hosts, 5 % loss,
    // 10 Hz: the steps agreed at a median of 27 % against 2 %, docs/BENCHMARKS.md, "Late
    // batches at 64 agents with loss").
    return std::max(config.network.heartbeat_period_s, 2.0 * n / kHeartbeatBudgetPerS);
  }
  if (topic == Topic::kAgentState && udp) {
    // An agent's state (read by the target), where samples can be lost in transit (UDPv4
    // only: the runs across hosts). The N writers meet in the target, the busiest process,
    // so their heartbeats keep within a budget of its own. Not over shared memory, where
    // nothing is lost on the way and heartbeats only cost: at 64 agents on one 2-core host,
    // 6.4 ms for these and the ranges made the target fall behind after a kill and stay
    // behind, 12.8 ms from the first step, and 32 ms in 1 run of 4, from step 230 on.
    return std::max(config.network.heartbeat_period_s, n / kTargetHeartbeatBudgetPerS);
  }
  return budgeted;
}

namespace {

// per_agent_writer: one of the target's writers of ranges, one per agent (d.range_partitions).
fdds::DataWriterQos WriterQos(Topic topic, const Config& config, bool per_agent_writer = false) {
  const TopicQos spec = QosOf(topic, config.network);
  fdds::DataWriterQos qos = fdds::DATAWRITER_QOS_DEFAULT;
  ApplyCommon(qos, spec, spec.writer_depth, config);
  // A lost sample is repaired one heartbeat later: Fast DDS's default (3 s) is far longer
  // than a step (docs/FASTDDS_NOTES.md). Heartbeats are sent only while samples are unacked.
  auto& times = qos.reliable_writer_qos().times;
  times.heartbeatPeriod = DdsDuration(WriterHeartbeatS(topic, config, per_agent_writer));
  times.nackResponseDelay = DdsDuration(config.network.nack_response_delay_s);
  times.nackSupressionDuration = Duration_t(0, 0);
  qos.publish_mode().kind = fdds::SYNCHRONOUS_PUBLISH_MODE;
  return qos;
}

fdds::DataReaderQos ReaderQos(Topic topic, const Config& config) {
  const TopicQos spec = QosOf(topic, config.network);
  fdds::DataReaderQos qos = fdds::DATAREADER_QOS_DEFAULT;
  ApplyCommon(qos, spec, spec.reader_depth, config);
  auto& times = qos.reliable_reader_qos().times;
  times.heartbeatResponseDelay = DdsDuration(config.network.heartbeat_response_delay_s);
  times.initialAcknackDelay = DdsDuration(config.network.heartbeat_response_delay_s);
  return qos;
}

// Set by DdsLog when this process's shared-memory receive loop is stuck (Node::ReceiveStuck).
std::atomic<bool> g_receive_stuck{false};
// SetReaderLoopHandler's; taken (and called) once.
std::atomic<ReaderLoopHandler> g_reader_loop_handler{nullptr};

// Counts events in windows of `window`: whether `count` of them came within one.
class Burst {
 public:
  Burst(Clock::duration window, int count) : window_(window), count_(count) {}
  bool Note(Clock::time_point now) {
    if (now - start_ > window_) {
      start_ = now;
      seen_ = 0;
    }
    return ++seen_ >= count_;
  }

 private:
  Clock::duration window_;
  int count_;
  Clock::time_point start_{};
  int seen_ = 0;
};

// Fast DDS's log, read by the process itself. It shows Fast DDS's errors, and with
// DEIF_DDS_LOG=warning (or info) its warnings (and more): errors and warnings on stderr, so in
// every process's log (Fast DDS's own consumer wrote them on stdout, which for the target is
// its launcher's control pipe); DEIF_DDS_LOG_CATEGORIES=REGEX keeps the categories it matches,
// e.g. '^(?!SECURITY_CRYPTO)' (docs/FASTDDS_NOTES.md, "Key hashes"). It always reads warnings,
// to see one failure of Fast DDS 2.9.1 that nothing else shows: a shared-memory receive thread
// that pops a message of a dead writer whose segment is gone fails on it without removing it,
// again and again, each time with the warning "Error receiving data", and the process hears
// nothing more on that port (docs/FASTDDS_NOTES.md, "A receive loop stuck on a dead writer's
// segment"). Thousands a second of them mean that loop.
class DdsLog final : public fdds::LogConsumer {
 public:
  DdsLog(fdds::Log::Kind shown, std::optional<std::regex> categories)
      : shown_(shown), categories_(std::move(categories)) {}

  void Consume(const fdds::Log::Entry& entry) override {
    if (entry.kind == fdds::Log::Warning && entry.context.category != nullptr &&
        std::strcmp(entry.context.category, "RTPS_MSG_OUT") == 0 &&
        entry.message.rfind("Error receiving data", 0) == 0) {
      if (receive_errors_.Note(Clock::now())) g_receive_stuck.store(true);  // on its one logging thread
    }
    if (entry.kind == fdds::Log::Error && entry.context.category != nullptr &&
        std::strcmp(entry.context.category, "SUBSCRIBER") == 0 &&
        entry.message.rfind(kLostChange, 0) == 0 && !NoteLostChange()) {
      return;  // the first few are shown; thousands a second would fill the disk
    }
    if (entry.kind > shown_) return;
    if (categories_ && !std::regex_search(entry.context.category, *categories_)) return;
    printer_.Consume(entry);
  }

 private:
  // Fast DDS 2.9.1's error when a keyed reader's history lost track of a change: in a loop
  // of its own, thousands a second (docs/FASTDDS_NOTES.md, "A reader that hands out one
  // sample for ever"). Node::Wait makes a reader that hands out one sample twice anew; if
  // the errors go on all the same, the loop is one that no call returns from.
  static constexpr const char* kLostChange = "Change not found on this key";
  static constexpr int kLostChangesShown = 5;

  // Whether to show this one. Calls the handler (SetReaderLoopHandler) once lost_changes_
  // says the loop.
  bool NoteLostChange() {  // on Fast DDS's one logging thread
    if (lost_changes_.Note(Clock::now())) {
      if (ReaderLoopHandler handler = g_reader_loop_handler.exchange(nullptr)) handler();
    }
    return ++lost_shown_ <= kLostChangesShown;
  }

  fdds::Log::Kind shown_;
  std::optional<std::regex> categories_;
  fdds::StdoutErrConsumer printer_;  // warnings and errors on stderr, info on stdout
  Burst receive_errors_{std::chrono::seconds(1), 1000};  // a loop, not a socket closed
  Burst lost_changes_{std::chrono::seconds(5), 1000};    // a loop, not a writer restarting
  long lost_shown_ = 0;
};

// Once per process, before its first participant.
void InstallDdsLog() {
  static std::once_flag once;
  std::call_once(once, [] {
    fdds::Log::Kind shown = fdds::Log::Error;
    if (const char* level = std::getenv("DEIF_DDS_LOG")) {
      const std::string l(level);
      if (l == "warning") shown = fdds::Log::Warning;
      if (l == "info") shown = fdds::Log::Info;
    }
    std::optional<std::regex> categories;
    if (const char* pattern = std::getenv("DEIF_DDS_LOG_CATEGORIES")) {
      try {
        categories.emplace(pattern);
      } catch (const std::regex_error& e) {
        std::fprintf(stderr, "DEIF_DDS_LOG_CATEGORIES: not a regular expression (%s); not filtered\n", e.what());
      }
    }
    fdds::Log::ClearConsumers();
    fdds::Log::RegisterConsumer(std::make_unique<DdsLog>(shown, std::move(categories)));
    fdds::Log::SetVerbosity(shown == fdds::Log::Info ? fdds::Log::Info : fdds::Log::Warning);
  });
}

// The ports of a comma-separated list ("42162,42163"); what is not a port is skipped.
std::set<int> PortsOfList(const char* list) {
  std::set<int> ports;
  if (list == nullptr) return ports;
  std::istringstream items(list);
  std::string item;
  while (std::getline(items, item, ',')) {
    if (!item.empty() && item.size() <= 5 && item.find_first_not_of("0123456789") == std::string::npos) {
      ports.insert(std::stoi(item));
    }
  }
  return ports;
}

// The unicast shared-memory ports of the participant made last by this process (Node).
std::mutex g_listened_mutex;
std::vector<int> g_listened_ports;

// A participant id whose shared-memory ports (/dev/shm/fastrtps_port<port>, the unicast
// ports of RTPS's default port mapping) no process has created (neither the port's file nor
// its lock file exists): a process restarted after
// kill -9 must not reopen the ports its dead predecessor left. Fast DDS finds such a port
// unhealthy (nobody drains it), removes the segment and creates a new one under the same
// name, while the live peers keep writing into the old mapping: the newcomer then hears
// nothing over shared memory (docs/FASTDDS_NOTES.md, "Shared memory and restarts"). A taken
// port found anyway (two processes starting at once) is moved on by Fast DDS itself. Nor an
// id whose ports this process listened on before it started again in place
// (kShmPortsUsedVariable): when a peer had replaced such a port under it, the process's
// leaving removed the replacement's name, and a new participant on the same id would make
// yet another segment there while its peers write into the one they mapped
// (docs/FASTDDS_NOTES.md, "A port replaced under its listener"). -1 (Fast DDS picks) when
// every id in the domain's range is taken.
std::int32_t FreshShmParticipantId(int domain_id) {
  // RTPS default port mapping: PB 7400, DG 250, PG 2, d1 10 (metatraffic unicast), d3 11.
  constexpr int kPortBase = 7400, kDomainGain = 250, kIdGain = 2, kMetaOffset = 10;
  constexpr int kMaxId = (kDomainGain - kMetaOffset) / kIdGain - 1;  // ports stay in the domain
  const std::set<int> used = PortsOfList(std::getenv(kShmPortsUsedVariable));
  // A port whose segment's name is gone may still have a live listener: its lock file.
  const auto taken = [&used](int port) {
    std::error_code ec;
    const std::string path = "/dev/shm/fastrtps_port" + std::to_string(port);
    return used.count(port) > 0 || std::filesystem::exists(path, ec) || std::filesystem::exists(path + "_el", ec);
  };
  for (int id = 0; id <= kMaxId; ++id) {
    const int meta = kPortBase + kDomainGain * domain_id + kMetaOffset + kIdGain * id;
    if (!taken(meta) && !taken(meta + 1)) return id;
  }
  return -1;
}

// How long a shared-memory port's listener may stay still before Fast DDS takes the port for
// a dead process's (ParticipantQos).
double ShmPortCheckS(const Config& config) { return std::max(1.0, config.network.participant_lease_s); }

// The GUID prefix of the Discovery Server with id 0 (`fastdds discovery -i 0`).
const eprosima::fastrtps::rtps::GuidPrefix_t& ServerPrefix() {
  static const eprosima::fastrtps::rtps::GuidPrefix_t prefix = [] {
    eprosima::fastrtps::rtps::RemoteServerAttributes server;
    server.ReadguidPrefix("44.53.00.5f.45.50.52.4f.53.49.4d.41");
    return server.guidPrefix;
  }();
  return prefix;
}

// What a participant announces as its user data: the partition of its run.
std::string RunAnnouncement(const std::string& run_name) { return "deif." + run_name; }

fdds::DomainParticipantQos ParticipantQos(const Config& config, const std::string& name,
                                         const std::string& run_name) {
  // Start from the factory default, so that an XML profile named by
  // FASTRTPS_DEFAULT_PROFILES_FILE (initial peers, transports: docs/RUNNING.md) applies.
  fdds::DomainParticipantQos qos =
      fdds::DomainParticipantFactory::get_instance()->get_default_participant_qos();
  qos.name(name);
  // Its run, so that peers know a participant of their own run by its name before any of its
  // endpoints exist (Node::TargetUp). Not with ros2_naming: ROS 2 keeps its enclave there.
  if (!config.network.ros2_naming) {
    const std::string run = RunAnnouncement(run_name);
    qos.user_data().data_vec(std::vector<eprosima::fastrtps::rtps::octet>(run.begin(), run.end()));
  }
  const NetworkConfig& network = config.network;
  auto& discovery = qos.wire_protocol().builtin.discovery_config;
  const Timings timings = EffectiveTimings(config);
  discovery.leaseDuration = DdsDuration(timings.participant_lease_s);
  discovery.leaseDuration_announcementperiod = DdsDuration(timings.participant_announcement_s);
  if (network.discovery == DiscoveryKind::kServer) {
    const std::string& address = network.discovery_server;
    const std::size_t colon = address.rfind(':');
    eprosima::fastrtps::rtps::RemoteServerAttributes server;
    server.guidPrefix = ServerPrefix();
    eprosima::fastrtps::rtps::Locator_t locator;
    eprosima::fastrtps::rtps::IPLocator::setIPv4(locator, address.substr(0, colon));
    locator.port = static_cast<std::uint32_t>(std::stoul(address.substr(colon + 1)));
    server.metatrafficUnicastLocatorList.push_back(locator);
    discovery.discoveryProtocol = eprosima::fastrtps::rtps::DiscoveryProtocol_t::CLIENT;
    discovery.m_DiscoveryServers.push_back(server);
  }
  if (qos.transport().user_transports.empty()) {
    qos.transport().use_builtin_transports = false;
    if (network.transport == TransportKind::kShm) {
      // Fast DDS's default port (512 messages, 0.5 MiB segment): larger ones did not stop a
      // local flood from starving a neighbour and cost memory (docs/FASTDDS_NOTES.md).
      auto shm = std::make_shared<eprosima::fastdds::rtps::SharedMemTransportDescriptor>();
      // A port whose listener has not stirred for this long is taken for a dead process's
      // and removed; Fast DDS's 1 s took the port of a process that was only starved of CPU
      // (docs/FASTDDS_NOTES.md, "A starved process's port"). A participant lease is how
      // long the network waits for a silent process anyway: the configured one, not the
      // longer one of a large network (EffectiveTimings): with that (20.8 s at N = 64)
      // every process outlived the run's end by 10-20 s, its exit held up by this check.
      shm->healthy_check_timeout_ms(static_cast<std::uint32_t>(1000.0 * ShmPortCheckS(config)));
      qos.transport().user_transports.push_back(shm);
      if (qos.wire_protocol().participant_id < 0) {
        qos.wire_protocol().participant_id = FreshShmParticipantId(network.domain_id);
      }
    }
    auto udp = std::make_shared<eprosima::fastdds::rtps::UDPv4TransportDescriptor>();
    udp->sendBufferSize = 1 << 20;
    udp->receiveBufferSize = 1 << 20;
    qos.transport().user_transports.push_back(udp);
  }
  return qos;
}

// ---- DDS Security (dds/security.hpp, docs/SECURITY.md), kept apart from the transport and
// discovery settings above.

// Switches the builtin security plugins on with the files of participant `name`, once they
// passed the checks (SecurityError names a bad file).
void ApplySecurity(fdds::DomainParticipantQos& qos, const Config& config, const std::string& name) {
  const SecurityFiles files = FilesOf(config.network.security.dir, name);
  CheckSecurityFiles(files);
  for (const auto& [key, value] : SecurityProperties(files)) {
    qos.properties().properties().emplace_back(key, value);
  }
}

// The participant listener of every node: which participants of the run are up (by the
// name and the run each announces: ParticipantQos), and, when secure, the partitions of
// every remote writer as first discovered and where the authentication with every remote
// participant stands.
//
// Partitions: Fast DDS calls on_publisher_discovery before it matches the writer with any
// reader, so the binding exists before a sample can arrive. A writer announced again with
// other partitions is revoked: Fast DDS checks the permissions again but keeps an existing
// match, and a writer first announced in a partition its permissions refuse was never
// matched on it.
//
// Authentication: Fast DDS 2.9.1 can leave the handshake with a remote participant stalled
// for good when it discovers two new participants at once on two receive threads (shared
// scratch data in its security manager, docs/FASTDDS_NOTES.md). Neither side then reports an
// outcome; Node recreates its participant when it sees one (AwaitAuthentication).
class ParticipantListener final : public fdds::DomainParticipantListener {
 public:
  using Guid = eprosima::fastrtps::rtps::GUID_t;

  void on_publisher_discovery(fdds::DomainParticipant*,
                              eprosima::fastrtps::rtps::WriterDiscoveryInfo&& info) override {
    using Info = eprosima::fastrtps::rtps::WriterDiscoveryInfo;
    if (info.status == Info::REMOVED_WRITER) return;  // kept: the same writer may come back
    if (info.status == Info::DISCOVERED_WRITER) endpoints_heard_.fetch_add(1);
    const std::vector<std::string> names = info.info.m_qos.m_partition.getNames();
    const protocol::SenderKey key = ToKey(fdds::InstanceHandle_t(info.info.guid()));
    std::lock_guard<std::mutex> lock(mutex_);
    const auto [it, first] = bindings_.try_emplace(key, Binding{names, false});
    if (!first && it->second.partitions != names) it->second.revoked = true;
  }

  void on_subscriber_discovery(fdds::DomainParticipant*,
                               eprosima::fastrtps::rtps::ReaderDiscoveryInfo&& info) override {
    using Info = eprosima::fastrtps::rtps::ReaderDiscoveryInfo;
    if (info.status == Info::DISCOVERED_READER) endpoints_heard_.fetch_add(1);
  }

  void on_participant_discovery(fdds::DomainParticipant*,
                                eprosima::fastrtps::rtps::ParticipantDiscoveryInfo&& info) override {
    using Info = eprosima::fastrtps::rtps::ParticipantDiscoveryInfo;
    std::lock_guard<std::mutex> lock(mutex_);
    if (info.status == Info::DISCOVERED_PARTICIPANT) {
      Peer& peer = peers_[info.info.m_guid];
      if (!peer.seen) peer.discovered = Clock::now();
      peer.seen = true;
      peer.gone = false;
      const auto& data = info.info.m_userData.data_vec();
      const std::string name = info.info.m_participantName.to_string();
      const bool of_run = !watched_run_.empty() && std::string(data.begin(), data.end()) == watched_run_;
      peer.watched = name == watched_name_ && of_run;
      peer.agent = of_run ? AgentIdOfName(name) : 0;
      peer.shm_ports = ShmUnicastPorts(info.info);
      last_discovery_ = Clock::now();
      if (info.info.m_guid.guidPrefix == ServerPrefix()) {
        server_since_s_ = ToSeconds(Clock::now());
      }
    } else if (info.status == Info::REMOVED_PARTICIPANT ||
               info.status == Info::DROPPED_PARTICIPANT) {
      peers_[info.info.m_guid].gone = true;
      if (info.info.m_guid.guidPrefix == ServerPrefix()) server_since_s_.reset();
    }
    int up = 0;
    for (const auto& [guid, peer] : peers_) up += peer.watched && !peer.gone ? 1 : 0;
    watched_up_.store(up);
    version_.fetch_add(1);
  }

  void onParticipantAuthentication(fdds::DomainParticipant*,
                                   eprosima::fastrtps::rtps::ParticipantAuthenticationInfo&& info) override {
    std::lock_guard<std::mutex> lock(mutex_);
    Peer& peer = peers_[info.guid];
    if (!peer.seen) peer.discovered = Clock::now();
    peer.seen = true;
    peer.settled = true;  // authorised or refused: either way an outcome
  }

  // The partitions `writer` was bound to; nullopt if unknown or revoked.
  std::optional<std::vector<std::string>> Of(const protocol::SenderKey& writer) const {
    std::lock_guard<std::mutex> lock(mutex_);
    const auto it = bindings_.find(writer);
    if (it == bindings_.end() || it->second.revoked) return std::nullopt;
    return it->second.partitions;
  }

  struct Progress {
    int stalled = 0;    // discovered longer than `stall` ago, no outcome yet
    int pending = 0;    // discovered, no outcome yet
    Clock::time_point last_discovery{};
  };
  Progress Check(Clock::duration stall) const {
    std::lock_guard<std::mutex> lock(mutex_);
    Progress p;
    p.last_discovery = last_discovery_;
    const auto now = Clock::now();
    for (const auto& [guid, peer] : peers_) {
      if (!peer.seen || peer.settled || peer.gone) continue;
      ++p.pending;
      if (now - peer.discovered > stall) ++p.stalled;
    }
    return p;
  }
  // Watch for remote participants named `name` that announce the run `run` (before the
  // participant exists); WatchedUp() says whether one is up, without a lock.
  void Watch(const std::string& name, const std::string& run) {
    watched_name_ = name;
    watched_run_ = run;
  }
  bool WatchedUp() const { return watched_up_.load() > 0; }
  // Changes with every participant discovered or gone (without a lock).
  std::uint64_t Version() const { return version_.load(); }
  std::uint64_t EndpointsHeard() const { return endpoints_heard_.load(); }
  // The ids of the participants named agent-<id> that announced the watched run and are up.
  std::set<AgentId> AgentsUp() const {
    std::lock_guard<std::mutex> lock(mutex_);
    std::set<AgentId> up;
    for (const auto& [guid, peer] : peers_) {
      if (peer.agent > 0 && !peer.gone) up.insert(peer.agent);
    }
    return up;
  }
  // The agents of the watched run that are up, whose participants listen on shared-memory
  // ports of the host `host` (the two bytes of a Fast DDS shared-memory locator and GUID
  // prefix that name a host), and those ports, by participant.
  // agents: the agent id of each of those participants.
  std::map<protocol::SenderKey, std::vector<int>> AgentShmPorts(std::array<std::uint8_t, 2> host,
                                                                std::map<protocol::SenderKey, AgentId>& agents) const {
    std::lock_guard<std::mutex> lock(mutex_);
    std::map<protocol::SenderKey, std::vector<int>> ports;
    agents.clear();
    for (const auto& [guid, peer] : peers_) {
      if (peer.agent <= 0 || peer.gone || peer.shm_ports.empty() || peer.shm_ports.front().first != host) continue;
      const protocol::SenderKey key = ToKey(fdds::InstanceHandle_t(guid));
      std::vector<int>& list = ports[key];
      for (const auto& [port_host, port] : peer.shm_ports) list.push_back(port);
      agents[key] = peer.agent;
    }
    return ports;
  }
  // Since when the Discovery Server's participant is listed up, this time (nullopt: it is not).
  std::optional<double> ServerSinceS() const {
    std::lock_guard<std::mutex> lock(mutex_);
    return server_since_s_;
  }
  // Forgets the participants (a new local participant authenticates afresh).
  void ResetPeers() {
    std::lock_guard<std::mutex> lock(mutex_);
    peers_.clear();
    watched_up_.store(0);
    last_discovery_ = Clock::time_point{};
  }

 private:
  struct Binding {
    std::vector<std::string> partitions;
    bool revoked = false;
  };
  struct Peer {
    bool seen = false;
    bool settled = false;
    bool gone = false;
    Clock::time_point discovered{};
    bool watched = false;  // its name and announced run are the watched ones (Watch)
    AgentId agent = 0;     // agent-<id> of the watched run, else 0
    std::vector<std::pair<std::array<std::uint8_t, 2>, int>> shm_ports;  // (host, port) of its unicast locators
  };
  // The shared-memory unicast locators a participant announces, metatraffic and user: a
  // Fast DDS 2.9.1 SHM locator carries 'U' (unicast) and its host's id in address bytes 0-2.
  static std::vector<std::pair<std::array<std::uint8_t, 2>, int>> ShmUnicastPorts(
      const eprosima::fastrtps::rtps::ParticipantProxyData& data) {
    std::vector<std::pair<std::array<std::uint8_t, 2>, int>> ports;
    for (const auto* list : {&data.metatraffic_locators.unicast, &data.default_locators.unicast}) {
      for (const auto& locator : *list) {
        if (locator.kind != LOCATOR_KIND_SHM || locator.address[0] != 'U') continue;
        const std::pair<std::array<std::uint8_t, 2>, int> port{{locator.address[1], locator.address[2]},
                                                               static_cast<int>(locator.port)};
        if (std::find(ports.begin(), ports.end(), port) == ports.end()) ports.push_back(port);
      }
    }
    return ports;
  }
  // The id of a participant named agent-<id> (0 for any other name).
  static AgentId AgentIdOfName(const std::string& name) {
    static const std::string prefix = "agent-";
    if (name.size() <= prefix.size() || name.size() > prefix.size() + 6 ||
        name.compare(0, prefix.size(), prefix) != 0) {
      return 0;
    }
    AgentId id = 0;
    for (std::size_t i = prefix.size(); i < name.size(); ++i) {
      if (name[i] < '0' || name[i] > '9') return 0;
      id = id * 10 + (name[i] - '0');
    }
    return id;
  }
  std::string watched_name_, watched_run_;  // set before the participant exists
  std::atomic<int> watched_up_{0};
  std::atomic<std::uint64_t> version_{0};
  std::atomic<std::uint64_t> endpoints_heard_{0};  // remote writers and readers discovered
  mutable std::mutex mutex_;
  std::map<protocol::SenderKey, Binding> bindings_;
  std::map<Guid, Peer> peers_;
  Clock::time_point last_discovery_{};
  std::optional<double> server_since_s_;
};

// A content filter on the key that reads the id straight from the serialized sample:
// every keyed type of idl/deif.idl starts with its key, a 32-bit agent_id, right after the
// 4-byte encapsulation header. (Fast DDS's SQL filter would need TypeObjects, which the
// plain XCDR1 types, readable by other vendors, do not have.) Two expressions:
// "agent_id = %0" (one agent's samples) and "agent_id BETWEEN %0 AND %1" (the ids of the
// run: garbage under any other id is dropped as it arrives, before it is stored, woken for
// or deserialized; docs/PROTOCOL.md, "Peer data is untrusted"). A writer whose participant
// knows this filter class evaluates it before sending.
constexpr const char* kAgentIdFilterClass = "DEIF_AGENT_ID";

class AgentIdFilter final : public fdds::IContentFilter {
 public:
  // Samples outside [lo, hi] that a reader of this participant drops are counted in
  // `dropped` when it is not null (the BETWEEN form).
  AgentIdFilter(std::int32_t lo, std::int32_t hi, std::atomic<long>* dropped,
                const eprosima::fastrtps::rtps::GuidPrefix_t& local)
      : lo_(lo), hi_(hi), dropped_(dropped), local_(local) {}
  virtual ~AgentIdFilter() = default;
  bool evaluate(const SerializedPayload& payload, const FilterSampleInfo&,
                const GUID_t& reader) const override {
    bool pass = false;
    if (payload.length >= 8 && payload.data != nullptr) {
      const bool little_endian = payload.data[1] == 0x01;
      std::uint32_t raw = 0;
      for (int i = 0; i < 4; ++i) {
        const std::uint32_t byte = payload.data[4 + i];
        raw |= little_endian ? byte << (8 * i) : byte << (8 * (3 - i));
      }
      const auto id = static_cast<std::int32_t>(raw);
      pass = id >= lo_ && id <= hi_;
    }
    if (!pass && dropped_ != nullptr && reader.guidPrefix == local_) ++*dropped_;
    return pass;
  }

 private:
  std::int32_t lo_, hi_;
  std::atomic<long>* dropped_;
  eprosima::fastrtps::rtps::GuidPrefix_t local_;
};

class AgentIdFilterFactory : public fdds::IContentFilterFactory {
 public:
  ReturnCode_t create_content_filter(const char*, const char*, const fdds::TopicDataType*,
                                     const char* expression, const ParameterSeq& parameters,
                                     fdds::IContentFilter*& filter) override {
    const std::string e = expression == nullptr ? "agent_id = %0" : expression;
    const bool between = e == "agent_id BETWEEN %0 AND %1";
    if (!between && e != "agent_id = %0") return ReturnCode_t::RETCODE_BAD_PARAMETER;
    if (parameters.length() != (between ? 2 : 1)) return ReturnCode_t::RETCODE_BAD_PARAMETER;
    long values[2] = {0, 0};
    for (int i = 0; i < parameters.length(); ++i) {
      char* end = nullptr;
      values[i] = std::strtol(parameters[i], &end, 10);
      if (end == parameters[i] || *end != '\0') return ReturnCode_t::RETCODE_BAD_PARAMETER;
    }
    if (!between) values[1] = values[0];
    delete static_cast<AgentIdFilter*>(filter);
    filter = new AgentIdFilter(static_cast<std::int32_t>(values[0]), static_cast<std::int32_t>(values[1]),
                               between ? &dropped : nullptr, local);
    return ReturnCode_t::RETCODE_OK;
  }
  ReturnCode_t delete_content_filter(const char*, fdds::IContentFilter* filter) override {
    delete static_cast<AgentIdFilter*>(filter);
    return ReturnCode_t::RETCODE_OK;
  }
  std::atomic<long> dropped{0};                   // by this participant's BETWEEN readers
  eprosima::fastrtps::rtps::GuidPrefix_t local;  // this participant
};

// Reports every change of a remote writer's liveliness, one call each, from a DDS thread.
class LivelinessListener : public fdds::DataReaderListener {
 public:
  using Callback = std::function<void(const protocol::SenderKey&, bool alive)>;
  LivelinessListener(Callback callback, std::function<void()> wake)
      : callback_(std::move(callback)), wake_(std::move(wake)) {}
  void on_liveliness_changed(fdds::DataReader*, const fdds::LivelinessChangedStatus& status) override {
    if (status.alive_count_change > 0) callback_(ToKey(status.last_publication_handle), true);
    if (status.alive_count_change < 0) callback_(ToKey(status.last_publication_handle), false);
  }
  void on_subscription_matched(fdds::DataReader*, const fdds::SubscriptionMatchedStatus& status) override {
    if (status.current_count_change < 0) callback_(ToKey(status.last_publication_handle), false);
    if (status.current_count_change > 0) wake_();  // the application may want to know
  }

 private:
  Callback callback_;
  std::function<void()> wake_;
};

// Keeps the set of remote readers a writer currently matches (Fast DDS 2.9 does not
// implement DataWriter::get_matched_subscriptions), from a DDS thread.
class MatchListener : public fdds::DataWriterListener {
 public:
  explicit MatchListener(std::function<void()> wake) : wake_(std::move(wake)) {}
  void on_publication_matched(fdds::DataWriter*, const fdds::PublicationMatchedStatus& status) override {
    {
      std::lock_guard<std::mutex> lock(mutex_);
      if (status.current_count_change > 0) readers_.insert(ToKey(status.last_subscription_handle));
      if (status.current_count_change < 0) readers_.erase(ToKey(status.last_subscription_handle));
    }
    wake_();  // the application may be waiting for a match
  }
  bool AnyReader() const {
    std::lock_guard<std::mutex> lock(mutex_);
    return !readers_.empty();
  }
  std::set<protocol::SenderKey> Readers() const {
    std::lock_guard<std::mutex> lock(mutex_);
    return readers_;
  }

 private:
  std::function<void()> wake_;
  mutable std::mutex mutex_;
  std::set<protocol::SenderKey> readers_;
};

constexpr int kMaxAuthenticationRestarts = 5;

// Waits until every participant discovered so far has an authentication outcome and no new
// one appeared for a while (true), or one has had none for kStall (false: the handshake
// stalled). Bounded: after kLongest it goes on with what it has.
bool AwaitAuthentication(const ParticipantListener& listener, const Config& config) {
  const auto start = Clock::now();
  // A handshake is a few milliseconds; its messages are resent every 0.5 s and more.
  const auto stall = Seconds(3.0);
  const auto least = Seconds(std::min(0.5, config.network.participant_announcement_s));
  const auto quiet = Seconds(0.2);
  const auto longest = Seconds(15.0);
  while (Clock::now() - start < longest) {
    std::this_thread::sleep_for(std::chrono::milliseconds(20));
    const ParticipantListener::Progress p = listener.Check(stall);
    if (p.stalled > 0) return false;
    const auto now = Clock::now();
    if (p.pending == 0 && now - start >= least && now - p.last_discovery >= quiet) return true;
  }
  return true;
}

// A random wait within RestartWindowS (dds/node.hpp).
Clock::duration RestartBackoff(int restart, int agents) {
  static std::mt19937_64 rng{std::random_device{}()};
  std::uniform_real_distribution<double> wait_s(0.0, RestartWindowS(restart, agents));
  return Seconds(wait_s(rng));
}

}  // namespace

// ---------------------------------------------------------------------------------------

struct Node::Impl {
  const Config& config;
  std::string run_name;
  fdds::DomainParticipant* participant = nullptr;
  fdds::Publisher* publisher = nullptr;
  fdds::Subscriber* subscriber = nullptr;
  std::map<Topic, fdds::Topic*> topics;
  std::vector<fdds::ContentFilteredTopic*> filtered;
  std::map<Topic, fdds::DataWriter*> writers;
  // Ranges in a partition per agent (docs/PROTOCOL.md, "Ranges"): the writer of each agent
  // id's ranges, made for 1..agents.count with the writer of ranges (and 0: the one of any
  // other id, made at its first range); writers[kRange] is agent 1's.
  bool range_partitions = false;
  std::map<AgentId, fdds::DataWriter*> range_writers;
  std::vector<std::pair<Topic, fdds::DataWriter*>> every_writer;  // the range writers included
  std::map<Topic, fdds::DataReader*> readers;
  std::map<Topic, std::unique_ptr<LivelinessListener>> listeners;
  // Readers MoveSubPartitions left where they were, each in its own subscriber: they report
  // the liveliness of what they match (through the topic's listener) and hand out nothing.
  std::multimap<Topic, fdds::DataReader*> watches;
  // Samples taken from a reader that MoveSubPartitions replaced, handed out by the next Wait().
  std::vector<Event> stashed;
  // Readers that handed out one sample twice in a row (TakeAll), made anew by Wait(), and
  // those made anew so far (ReadersMadeAnew).
  std::set<Topic> readers_to_remake;
  std::vector<Topic> readers_made_anew;
  std::map<Topic, std::unique_ptr<MatchListener>> writer_listeners;
  std::set<protocol::SenderKey> own_writers;
  std::map<Topic, std::string> writer_sub_partitions, reader_sub_partitions;  // SetSubPartitions
  bool passive = false;  // MakePassive(): no writer, ever
  bool secure = false;   // network.security.enabled
  ParticipantListener participant_listener;  // the participant's listener when secure
  int authentication_restarts = 0;
  AgentIdFilterFactory filter_factory;  // registered with the participant
  bool filters_registered = true;
  fdds::WaitSet waitset;
  fdds::GuardCondition guard;
  // The shared-memory ports this participant listens on (PortsLost), checked once a second.
  std::optional<ShmPortWatch> port_watch;
  Clock::time_point next_port_check{};
  // The processes of the run's agents on this host, by their ports' locks (EndedAgents).
  EndedProcessWatch ended_watch;
  std::map<protocol::SenderKey, AgentId> ended_watch_agents;  // the agent of each participant watched
  Clock::time_point next_ended_check{}, next_suspects_check{};

  std::mutex events_mutex;
  std::vector<LivelinessChange> liveliness_events;  // guarded by events_mutex

  // Liveliness asserter.
  std::mutex assert_mutex;
  std::condition_variable assert_cv;
  bool assert_stop = false;
  std::map<fdds::DataWriter*, Clock::time_point> last_write;  // guarded by assert_mutex
  // MANUAL_BY_TOPIC writers, how long each may stay idle, its own listener of matches
  // (nullptr: shared by several writers) and its thread (StartLiveliness); guarded by
  // assert_mutex.
  struct Asserted {
    fdds::DataWriter* writer;
    Clock::duration period;
    const MatchListener* matches;
    // The thread that asserts it (StartLiveliness).
    enum class Thread { kOthers, kRelay, kState } thread = Thread::kOthers;
  };
  std::vector<Asserted> asserted;
  std::thread asserter, relay_asserter, state_asserter;

  explicit Impl(const Config& c) : config(c) {}
};

Node::Node(const Config& config, const std::string& participant_name, const std::string& run_name)
    : impl_(std::make_unique<Impl>(config)) {
  Impl& d = *impl_;
  d.run_name = run_name;
  d.secure = config.network.security.enabled;
  if (!config.network.ros2_naming) d.participant_listener.Watch("target", RunAnnouncement(run_name));
  InstallDdsLog();
  if (d.secure) {
    fdds::DomainParticipantQos qos = ParticipantQos(config, participant_name, run_name);
    ApplySecurity(qos, config, participant_name);
    auto* factory = fdds::DomainParticipantFactory::get_instance();
    // No status through this listener (StatusMask::none): only discovery callbacks.
    d.participant = factory->create_participant(config.network.domain_id, qos, &d.participant_listener,
                                                fdds::StatusMask::none());
    // Before any endpoint exists: a handshake that stalls (ParticipantListener) costs a new
    // participant, a few seconds, and nothing else.
    while (d.participant != nullptr && !AwaitAuthentication(d.participant_listener, config) &&
           d.authentication_restarts < kMaxAuthenticationRestarts) {
      factory->delete_participant(d.participant);
      d.participant_listener.ResetPeers();
      ++d.authentication_restarts;
      // Not at once: participants re-created together would stall each other again.
      std::this_thread::sleep_for(RestartBackoff(d.authentication_restarts, config.agents.count));
      d.participant = factory->create_participant(config.network.domain_id, qos, &d.participant_listener,
                                                  fdds::StatusMask::none());
    }
  } else {
    d.participant = fdds::DomainParticipantFactory::get_instance()->create_participant(
        config.network.domain_id, ParticipantQos(config, participant_name, run_name),
        &d.participant_listener, fdds::StatusMask::none());
  }
  if (d.participant == nullptr) {
    throw std::runtime_error("cannot create a DDS participant on domain " +
                             std::to_string(config.network.domain_id) +
                             (d.secure ? " with the security files of '" + participant_name +
                                             "' (does the governance cover this domain?)"
                                       : std::string()));
  }
  d.filter_factory.local = d.participant->guid().guidPrefix;
  if (d.participant->register_content_filter_factory(kAgentIdFilterClass, &d.filter_factory) !=
      ReturnCode_t::RETCODE_OK) {
    throw std::runtime_error("cannot register the agent id content filter");
  }
  const bool ros2 = config.network.ros2_naming;
  std::set<std::string> registered;  // the relay topics share one type
  for (Topic topic : kAllTopics) {
    fdds::TypeSupport support;
    switch (topic) {
      case Topic::kTruth: support.reset(new LockedKey<deif_msgs::TruthPubSubType>()); break;
      case Topic::kRange: support.reset(new LockedKey<deif_msgs::RangePubSubType>()); break;
      case Topic::kContribution: support.reset(new LockedKey<deif_msgs::ContributionPubSubType>()); break;
      case Topic::kAgentState: support.reset(new LockedKey<deif_msgs::AgentStatePubSubType>()); break;
      case Topic::kRelayUp:
      case Topic::kRelayDown:
        support.reset(new LockedKey<deif_msgs::ContributionBatchPubSubType>());
        break;
    }
    const TopicNames names = NamesOf(topic);
    if (ros2) support->setName(names.ros2_type);
    if (registered.insert(support.get_type_name()).second &&
        support.register_type(d.participant) != ReturnCode_t::RETCODE_OK) {
      throw std::runtime_error(std::string("cannot register the type of ") + names.name);
    }
    fdds::Topic* t = d.participant->create_topic(ros2 ? names.ros2_name : names.name,
                                                 support.get_type_name(), fdds::TOPIC_QOS_DEFAULT);
    if (t == nullptr) throw std::runtime_error(std::string("cannot create topic ") + names.name);
    d.topics[topic] = t;
  }
  // Runs are isolated by a partition named after the run (docs/PROTOCOL.md); ROS 2 tools
  // use the default partition, so with ros2_naming only the run token isolates.
  fdds::PublisherQos publisher_qos = fdds::PUBLISHER_QOS_DEFAULT;
  fdds::SubscriberQos subscriber_qos = fdds::SUBSCRIBER_QOS_DEFAULT;
  if (!ros2) {
    // With security each publisher's partition names its role (docs/SECURITY.md).
    const std::string published =
        d.secure ? PublisherPartition(run_name, participant_name) : "deif." + run_name;
    const std::string subscribed = d.secure ? SubscriberPartition(run_name) : "deif." + run_name;
    publisher_qos.partition().push_back(published.c_str());
    subscriber_qos.partition().push_back(subscribed.c_str());
  }
  // Not with security: the target's permissions grant it one partition, and with a writer
  // per agent a secure start of 16 agents stalled more often (docs/SECURITY.md). Not with a
  // Discovery Server: there one agent's reader now and then never matched its writer of
  // ranges (2 runs of 5 of mp_discovery_server; docs/PROTOCOL.md, "Ranges").
  d.range_partitions = !ros2 && !d.secure && config.network.discovery == DiscoveryKind::kSimple;
  d.publisher = d.participant->create_publisher(publisher_qos);
  d.subscriber = d.participant->create_subscriber(subscriber_qos);
  if (d.publisher == nullptr || d.subscriber == nullptr) {
    throw std::runtime_error("cannot create the DDS publisher/subscriber");
  }
  d.waitset.attach_condition(d.guard);
  // Fast DDS opened this participant's ports (and took their locks) as it created it. A
  // peer's reset that Fast DDS itself repairs moves the listener within a third of the port
  // check: only a port replaced for a whole check is lost.
  d.port_watch.emplace(ShmPortWatch::ListenedPorts(), ShmPortCheckS(config));
  std::lock_guard<std::mutex> lock(g_listened_mutex);
  g_listened_ports = d.port_watch->ports();
}

Node::~Node() {
  if (!impl_) return;  // abandoned
  Impl& d = *impl_;
  {
    std::lock_guard<std::mutex> lock(d.assert_mutex);
    d.assert_stop = true;
  }
  d.assert_cv.notify_all();
  if (d.asserter.joinable()) d.asserter.join();
  if (d.relay_asserter.joinable()) d.relay_asserter.join();
  if (d.state_asserter.joinable()) d.state_asserter.join();
  if (d.participant == nullptr) return;
  for (auto& [topic, reader] : d.readers) d.waitset.detach_condition(reader->get_statuscondition());
  d.waitset.detach_condition(d.guard);
  // Entities before the listeners they point to (the listeners are members of d).
  d.participant->delete_contained_entities();
  if (d.filters_registered) d.participant->unregister_content_filter_factory(kAgentIdFilterClass);
  fdds::DomainParticipantFactory::get_instance()->delete_participant(d.participant);
}

namespace {

// The partition of the ranges for agent `id` (docs/PROTOCOL.md, "Ranges").
std::string RangePartition(const std::string& run_name, AgentId id) {
  return "deif." + run_name + ".range." + std::to_string(id);
}

// The writer of agent `id`'s ranges. Ids outside 1..agents.count (no agent reads them;
// only a test tool writes them) share one writer in the run's partition alone, so that no
// id makes a new writer.
fdds::DataWriter* RangeWriterFor(Node::Impl& d, AgentId id) {
  if (id < 1 || id > static_cast<AgentId>(d.config.agents.count)) id = 0;
  auto it = d.range_writers.find(id);
  if (it != d.range_writers.end()) return it->second;
  fdds::PublisherQos qos = fdds::PUBLISHER_QOS_DEFAULT;
  const std::string run_partition = "deif." + d.run_name;
  const std::string own_partition = id == 0 ? run_partition : RangePartition(d.run_name, id);
  qos.partition().push_back(run_partition.c_str());  // what every reader of all ranges joins
  if (id != 0) qos.partition().push_back(own_partition.c_str());  // what agent `id` joins
  fdds::Publisher* publisher = d.participant->create_publisher(qos);
  fdds::DataWriter* writer =
      publisher == nullptr ? nullptr
                           : publisher->create_datawriter(d.topics.at(Topic::kRange), WriterQos(Topic::kRange, d.config, true),
                                                          d.writer_listeners.at(Topic::kRange).get(),
                                                          fdds::StatusMask::publication_matched());
  if (writer == nullptr) {
    throw std::runtime_error("cannot create the writer of ranges for agent " + std::to_string(id) +
                             " in partition " + own_partition);
  }
  d.range_writers[id] = writer;
  d.every_writer.emplace_back(Topic::kRange, writer);
  d.own_writers.insert(ToKey(writer->get_instance_handle()));
  {
    // A new writer asserts like the others (StartLiveliness), from its first period on.
    std::lock_guard<std::mutex> lock(d.assert_mutex);
    d.last_write[writer] = Clock::now();
    if (d.asserter.joinable()) {  // else StartLiveliness adds it
      d.asserted.push_back({writer, Seconds(AssertPeriodOf(QosOf(Topic::kRange, d.config.network), d.config)), nullptr});
    }
  }
  return writer;
}

}  // namespace

void Node::AddWriter(Topic topic) {
  Impl& d = *impl_;
  if (d.passive) {
    throw std::logic_error(std::string("a passive node has no writer (") + NamesOf(topic).name + ")");
  }
  auto listener = std::make_unique<MatchListener>([&d] { d.guard.set_trigger_value(true); });
  MatchListener* matches = listener.get();
  d.writer_listeners[topic] = std::move(listener);
  if (topic == Topic::kRange && d.range_partitions) {
    // One writer per agent, each in the run's partition and its agent's: an agent's reader
    // matches only its own (docs/PROTOCOL.md, "Ranges"). Every agent of the run has one
    // from the start, so that the matches the target waits for are there.
    for (AgentId j = 1; j <= static_cast<AgentId>(std::max(1, d.config.agents.count)); ++j) {
      RangeWriterFor(d, j);
    }
    d.writers[topic] = d.range_writers.at(1);
    return;
  }
  fdds::Publisher* publisher = d.publisher;
  if (auto sub = d.writer_sub_partitions.find(topic); sub != d.writer_sub_partitions.end()) {
    fdds::PublisherQos qos = fdds::PUBLISHER_QOS_DEFAULT;
    const std::string partition = "deif." + d.run_name + "." + sub->second;
    qos.partition().push_back(partition.c_str());
    publisher = d.participant->create_publisher(qos);
    if (publisher == nullptr) throw std::runtime_error("cannot create the publisher of " + partition);
  }
  fdds::DataWriter* writer = publisher->create_datawriter(
      d.topics.at(topic), WriterQos(topic, d.config), matches, fdds::StatusMask::publication_matched());
  if (writer == nullptr) {
    throw std::runtime_error(std::string("cannot create a writer on ") + NamesOf(topic).name);
  }
  d.writers[topic] = writer;
  d.every_writer.emplace_back(topic, writer);
  d.own_writers.insert(ToKey(writer->get_instance_handle()));
}

void Node::SetSubPartitions(Topic topic, const std::string& writer_suffix, const std::string& reader_suffix) {
  Impl& d = *impl_;
  if (d.secure || d.config.network.ros2_naming) {
    throw std::logic_error("sub-partitions are for plain runs with partitions only");
  }
  d.writer_sub_partitions[topic] = writer_suffix;
  d.reader_sub_partitions[topic] = reader_suffix;
}

namespace {

// Takes every sample waiting in the node's reader of `topic` (with TakeAll, below).
void TakeTopic(Node::Impl& d, Topic topic, std::vector<Event>& out);

// A subscriber of its own in partition `partition` (a reader that must not share its
// partition with the node's other readers).
fdds::Subscriber* SubscriberIn(Node::Impl& d, const std::string& partition) {
  fdds::SubscriberQos qos = fdds::SUBSCRIBER_QOS_DEFAULT;
  qos.partition().push_back(partition.c_str());
  fdds::Subscriber* subscriber = d.participant->create_subscriber(qos);
  if (subscriber == nullptr) throw std::runtime_error("cannot create the subscriber of " + partition);
  return subscriber;
}

// Makes the node's reader of `topic` in `subscriber`, woken by the node's Wait().
void MakeReader(Node::Impl& d, Topic topic, fdds::Subscriber* subscriber, fdds::TopicDescription* description,
                const fdds::DataReaderQos& qos, LivelinessListener* listener) {
  fdds::DataReader* reader = subscriber->create_datareader(
      description, qos, listener,
      fdds::StatusMask::liveliness_changed() << fdds::StatusMask::subscription_matched());
  if (reader == nullptr) {
    throw std::runtime_error(std::string("cannot create a reader on ") + NamesOf(topic).name);
  }
  reader->get_statuscondition().set_enabled_statuses(fdds::StatusMask::data_available());
  d.waitset.attach_condition(reader->get_statuscondition());
  d.readers[topic] = reader;
}

// Deletes the node's reader of `topic` and makes a new one with the same topic (or content
// filter), QoS, subscriber and listener; `between` runs on the subscriber in between.
void ReplaceReader(Node::Impl& d, Topic topic, const std::function<void(fdds::Subscriber*)>& between = nullptr) {
  fdds::DataReader* old = d.readers.at(topic);
  auto* subscriber = const_cast<fdds::Subscriber*>(old->get_subscriber());
  auto* description = const_cast<fdds::TopicDescription*>(old->get_topicdescription());
  const fdds::DataReaderQos qos = old->get_qos();
  d.waitset.detach_condition(old->get_statuscondition());
  if (subscriber->delete_datareader(old) != ReturnCode_t::RETCODE_OK) {
    throw std::runtime_error(std::string("cannot delete the reader on ") + NamesOf(topic).name);
  }
  d.readers.erase(topic);
  if (between) between(subscriber);
  MakeReader(d, topic, subscriber, description, qos, d.listeners.at(topic).get());
}

// Deletes the node's writer of `topic` (one without liveliness assertions: no thread of
// StartLiveliness holds it) and makes a new one with the same QoS in the same publisher, with
// a listener of its own; `between` runs on the publisher in between.
void ReplaceWriter(Node::Impl& d, Topic topic, const std::function<void(fdds::Publisher*)>& between) {
  fdds::DataWriter* old = d.writers.at(topic);
  auto* publisher = const_cast<fdds::Publisher*>(old->get_publisher());
  const fdds::DataWriterQos qos = old->get_qos();
  {
    std::lock_guard<std::mutex> lock(d.assert_mutex);
    d.last_write.erase(old);
  }
  if (publisher->delete_datawriter(old) != ReturnCode_t::RETCODE_OK) {
    throw std::runtime_error(std::string("cannot delete the writer on ") + NamesOf(topic).name);
  }
  if (between) between(publisher);
  auto listener = std::make_unique<MatchListener>([&d] { d.guard.set_trigger_value(true); });
  fdds::DataWriter* writer = publisher->create_datawriter(d.topics.at(topic), qos, listener.get(),
                                                          fdds::StatusMask::publication_matched());
  if (writer == nullptr) throw std::runtime_error(std::string("cannot create a writer on ") + NamesOf(topic).name);
  d.writer_listeners[topic] = std::move(listener);  // the old writer that called the old one is gone
  d.writers[topic] = writer;
  for (auto& entry : d.every_writer) {
    if (entry.second == old) entry.second = writer;
  }
  d.own_writers.insert(ToKey(writer->get_instance_handle()));
}

}  // namespace

void Node::MoveSubPartitions(Topic topic, const std::string& writer_suffix, const std::string& reader_suffix,
                             bool keep_watch) {
  Impl& d = *impl_;
  if (d.writer_sub_partitions.count(topic) == 0) {
    throw std::logic_error(std::string("no sub-partitions to move on ") + NamesOf(topic).name);
  }
  d.writer_sub_partitions[topic] = writer_suffix;
  d.reader_sub_partitions[topic] = reader_suffix;
  const auto already_in = [&d](const std::string& suffix, const auto& entity) {
    const auto names = entity->get_qos().partition().getNames();
    return names.size() == 1 && names.front() == "deif." + d.run_name + "." + suffix;
  };
  const auto moved = [&d, &already_in](const std::string& suffix, const auto& entity, const char* what) {
    if (already_in(suffix, entity)) return;
    auto qos = entity->get_qos();
    const std::string partition = "deif." + d.run_name + "." + suffix;
    qos.partition().clear();
    qos.partition().push_back(partition.c_str());
    if (entity->set_qos(qos) != ReturnCode_t::RETCODE_OK) {
      throw std::runtime_error(std::string("cannot move the ") + what + " to " + partition);
    }
  };
  if (auto w = d.writers.find(topic); w != d.writers.end()) {
    auto* publisher = const_cast<fdds::Publisher*>(w->second->get_publisher());
    if (QosOf(topic, d.config.network).manual_liveliness) {
      moved(writer_suffix, publisher, "publisher");  // its liveliness thread holds it (no such move yet)
    } else if (!already_in(writer_suffix, publisher)) {
      // A new writer, not the old one moved, for the same reason as the reader below: a
      // writer moved away from its reader during a partition and back after the heal sent
      // that reader nothing for 24 s (12 steps at the step timeout; docs/FASTDDS_NOTES.md,
      // "A reader moved and moved back"). The new parent gets what it missed from the tree
      // exchange, which sends it again (docs/SCALING.md), not from the writer's history.
      ReplaceWriter(d, topic, [&](fdds::Publisher* p) { moved(writer_suffix, p, "publisher"); });
    }
  }
  auto r = d.readers.find(topic);
  if (r == d.readers.end()) return;
  auto* subscriber = const_cast<fdds::Subscriber*>(r->second->get_subscriber());
  if (already_in(reader_suffix, subscriber)) return;
  // A new reader, not the old one moved: a reader moved away from a writer and back while
  // the two could not hear each other (a partition of the network) came back with the
  // writer's old record of it, and in 2 of 4 runs got nothing from that writer for 25-31
  // steps after the network healed (docs/FASTDDS_NOTES.md, "A reader moved and moved back").
  // A new reader is a reader the writer has never seen. What the old one held is kept.
  TakeTopic(d, topic, d.stashed);
  if (!keep_watch) {
    ReplaceReader(d, topic, [&](fdds::Subscriber* s) { moved(reader_suffix, s, "subscriber"); });
    return;
  }
  // The old reader stays in its subscriber and partition, out of the wait set: samples it
  // receives fill its history (history_steps deep) and are never taken. The new one gets a
  // subscriber of its own in the new partition.
  fdds::DataReader* old = r->second;
  if (subscriber == d.subscriber) {  // DropWatches deletes a watch's subscriber with it
    throw std::logic_error(std::string("a watch needs a reader in a subscriber of its own on ") + NamesOf(topic).name);
  }
  d.waitset.detach_condition(old->get_statuscondition());
  old->get_statuscondition().set_enabled_statuses(fdds::StatusMask::none());
  d.readers.erase(topic);
  d.watches.emplace(topic, old);
  fdds::Subscriber* fresh = SubscriberIn(d, "deif." + d.run_name + "." + reader_suffix);
  MakeReader(d, topic, fresh, const_cast<fdds::TopicDescription*>(old->get_topicdescription()), old->get_qos(),
             d.listeners.at(topic).get());
}

void Node::DropWatches(Topic topic) {
  Impl& d = *impl_;
  const auto range = d.watches.equal_range(topic);
  for (auto it = range.first; it != range.second; ++it) {
    fdds::DataReader* watch = it->second;
    auto* subscriber = const_cast<fdds::Subscriber*>(watch->get_subscriber());
    if (subscriber->delete_datareader(watch) != ReturnCode_t::RETCODE_OK ||
        d.participant->delete_subscriber(subscriber) != ReturnCode_t::RETCODE_OK) {
      throw std::runtime_error(std::string("cannot delete a watch on ") + NamesOf(topic).name);
    }
  }
  d.watches.erase(range.first, range.second);
}

int Node::Watches(Topic topic) const { return static_cast<int>(impl_->watches.count(topic)); }

void Node::RemakeReader(Topic topic) {
  Impl& d = *impl_;
  if (d.readers.count(topic) == 0) return;
  TakeTopic(d, topic, d.stashed);
  ReplaceReader(d, topic);
}

void Node::MakePassive() {
  if (!impl_->writers.empty()) throw std::logic_error("a node with writers cannot become passive");
  impl_->passive = true;
}

void Node::AddReader(const ReaderSpec& spec) {
  Impl& d = *impl_;
  fdds::TopicDescription* description = d.topics.at(spec.topic);
  if (spec.only_id && spec.id_range) throw std::logic_error("a reader takes one id or a range");
  if (spec.only_id || spec.id_range) {
    const std::string base = d.topics.at(spec.topic)->get_name();
    const std::string name =
        spec.only_id ? base + "_for_" + std::to_string(*spec.only_id)
                     : base + "_ids_" + std::to_string(spec.id_range->first) + "_" +
                           std::to_string(spec.id_range->second);
    std::vector<std::string> parameters;
    if (spec.only_id) {
      parameters = {std::to_string(*spec.only_id)};
    } else {
      parameters = {std::to_string(spec.id_range->first), std::to_string(spec.id_range->second)};
    }
    fdds::ContentFilteredTopic* filtered = d.participant->create_contentfilteredtopic(
        name, d.topics.at(spec.topic), spec.only_id ? "agent_id = %0" : "agent_id BETWEEN %0 AND %1",
        parameters, kAgentIdFilterClass);
    if (filtered == nullptr) throw std::runtime_error("cannot create the content filter " + name);
    d.filtered.push_back(filtered);
    description = filtered;
  }
  const Topic topic = spec.topic;
  if (d.readers.count(topic) > 0) throw std::logic_error(std::string("a second reader on ") + NamesOf(topic).name);
  auto listener = std::make_unique<LivelinessListener>(
      [&d, topic](const protocol::SenderKey& writer, bool alive) {
        {
          std::lock_guard<std::mutex> lock(d.events_mutex);
          d.liveliness_events.push_back({topic, writer, alive});
        }
        d.guard.set_trigger_value(true);
      },
      [&d] { d.guard.set_trigger_value(true); });
  fdds::Subscriber* subscriber = d.subscriber;
  if (topic == Topic::kRange && d.range_partitions && spec.only_id && *spec.only_id >= 1) {
    // Only its own agent's partition (docs/PROTOCOL.md, "Ranges"): the target's writers of
    // the other agents' ranges do not match it, so they send it nothing, not even news of
    // samples the filter would drop. The filter stays, against anyone else's writer there.
    subscriber = SubscriberIn(d, RangePartition(d.run_name, *spec.only_id));
  } else if (auto sub = d.reader_sub_partitions.find(topic); sub != d.reader_sub_partitions.end()) {
    subscriber = SubscriberIn(d, "deif." + d.run_name + "." + sub->second);
  }
  MakeReader(d, topic, subscriber, description, ReaderQos(topic, d.config), listener.get());
  d.listeners[topic] = std::move(listener);
}

void Node::RemoveReader(Topic topic) {
  Impl& d = *impl_;
  DropWatches(topic);  // they call the listener erased below
  auto it = d.readers.find(topic);
  if (it == d.readers.end()) return;
  fdds::DataReader* reader = it->second;
  d.waitset.detach_condition(reader->get_statuscondition());
  const fdds::TopicDescription* description = reader->get_topicdescription();
  auto* subscriber = const_cast<fdds::Subscriber*>(reader->get_subscriber());
  if (subscriber->delete_datareader(reader) != ReturnCode_t::RETCODE_OK) {
    throw std::runtime_error(std::string("cannot delete the reader on ") + NamesOf(topic).name);
  }
  d.readers.erase(it);
  d.listeners.erase(topic);  // after the reader that called it
  auto filtered = std::find(d.filtered.begin(), d.filtered.end(), description);
  if (filtered != d.filtered.end()) {
    d.participant->delete_contentfilteredtopic(*filtered);
    d.filtered.erase(filtered);
  }
}

void Node::StartLiveliness() {
  Impl& d = *impl_;
  if (d.asserter.joinable()) return;
  {
    std::lock_guard<std::mutex> lock(d.assert_mutex);
    for (auto& [topic, writer] : d.every_writer) {
      const TopicQos spec = QosOf(topic, d.config.network);
      if (!spec.manual_liveliness) continue;
      // A topic's listener is this writer's alone but for the target's writers of ranges.
      const auto listener = d.writer_listeners.find(topic);
      const MatchListener* matches =
          topic != Topic::kRange && listener != d.writer_listeners.end() ? listener->second.get() : nullptr;
      using Thread = Impl::Asserted::Thread;
      d.asserted.push_back({writer, Seconds(AssertPeriodOf(spec, d.config)), matches,
                            spec.relay_lease                ? Thread::kRelay
                            : topic == Topic::kAgentState ? Thread::kState
                                                          : Thread::kOthers});
    }
    for (const Impl::Asserted& a : d.asserted) d.last_write[a.writer] = Clock::now() - a.period;
    // A write renews a writer's liveliness, so only writers idle for their period assert: in
    // a busy network every assertion is a message to every matched reader. A writer that no
    // reader matches (a leaf's relay writer) has nobody to tell.
    // The assertions are sent without the lock: a write (WriteSample) takes it too, and a
    // send can block for a while (a dead process's shared-memory port, docs/FASTDDS_NOTES.md:
    // 1 s per message). The relay writers have a thread of their own: their short lease
    // tells a relay's children that it is gone, and an assertion of another writer stuck at
    // a dead peer's port (every contribution writer has a reader there) must not let it
    // lapse (at 64 agents in real time that moved every relay's children at once). So has
    // the state writer, whose reader is the target's: most likely stuck at the port of a
    // target that crashed, it held back the contribution writer's assertions, and the peers
    // lost every agent waiting for the restarted target's range (4 agents, a lease of 0.4 s;
    // docs/FASTDDS_NOTES.md). Writers live until the threads are joined.
    const auto assert_loop = [&d](Impl::Asserted::Thread thread) {
      std::vector<fdds::DataWriter*> due;
      std::unique_lock<std::mutex> held(d.assert_mutex);
      while (!d.assert_stop) {
        const auto now = Clock::now();
        auto next = now + std::chrono::seconds(1);
        due.clear();
        for (const Impl::Asserted& a : d.asserted) {
          if (a.thread != thread) continue;
          auto& renewed = d.last_write[a.writer];
          if (now - renewed >= a.period) {
            if (a.matches == nullptr || a.matches->AnyReader()) due.push_back(a.writer);
            renewed = now;
          }
          next = std::min(next, renewed + a.period);
        }
        if (!due.empty()) {
          held.unlock();
          for (fdds::DataWriter* writer : due) writer->assert_liveliness();
          held.lock();
        }
        d.assert_cv.wait_until(held, next, [&d] { return d.assert_stop; });
      }
    };
    using Thread = Impl::Asserted::Thread;
    d.asserter = std::thread(assert_loop, Thread::kOthers);
    const auto any_of = [&d](Thread thread) {
      return std::any_of(d.asserted.begin(), d.asserted.end(),
                         [thread](const Impl::Asserted& a) { return a.thread == thread; });
    };
    if (any_of(Thread::kRelay)) d.relay_asserter = std::thread(assert_loop, Thread::kRelay);
    if (any_of(Thread::kState)) d.state_asserter = std::thread(assert_loop, Thread::kState);
  }
}

namespace {

template <typename Idl>
void WriteSample(Node::Impl& d, Topic topic, Idl sample, std::optional<AgentId> range_for = std::nullopt) {
  auto it = d.writers.find(topic);
  if (it == d.writers.end()) throw std::logic_error(std::string("no writer on ") + NamesOf(topic).name);
  fdds::DataWriter* writer = range_for && d.range_partitions ? RangeWriterFor(d, *range_for) : it->second;
  writer->write(&sample);
  std::lock_guard<std::mutex> lock(d.assert_mutex);
  d.last_write[writer] = Clock::now();
}

// At most this many samples from one reader per Wait(): a flood is handed out over several
// calls, and memory stays bounded whatever a reader returns.
constexpr std::size_t kMaxTakesPerWait = 20000;

template <typename Idl, typename Msg, typename Convert>
void TakeAll(Node::Impl& d, Topic topic, std::vector<Event>& out, Convert convert) {
  auto it = d.readers.find(topic);
  if (it == d.readers.end()) return;
  // Kept from call to call: a batch's sequence keeps its storage (docs/BENCHMARKS.md).
  thread_local Idl sample;
  // The writer and sequence number of the sample with data taken last in this call.
  std::optional<std::pair<protocol::SenderKey, std::int64_t>> last;
  fdds::SampleInfo info;
  for (std::size_t n = 0;
       n < kMaxTakesPerWait && it->second->take_next_sample(&sample, &info) == ReturnCode_t::RETCODE_OK; ++n) {
    if (!info.valid_data) continue;  // news of an instance's state: no writer's sample
    // Fast DDS 2.9.1 can lose track of a change in a keyed reader's history ("Change not
    // found on this key, something is wrong", remove_change_sub): take then hands out that
    // same change again and again, for good, each call the one before (docs/FASTDDS_NOTES.md,
    // "A reader that hands out one sample for ever"). Only a new reader gets out of it.
    const auto& id = info.sample_identity;
    const std::pair<protocol::SenderKey, std::int64_t> taken{
        ToKey(id.writer_guid()), static_cast<std::int64_t>(id.sequence_number().to64long())};
    if (last == taken) {
      d.readers_to_remake.insert(topic);
      return;
    }
    last = taken;
    const protocol::SenderKey from = ToKey(info.publication_handle);
    if (d.own_writers.count(from) > 0) continue;  // our own samples
    const double written_unix_s = static_cast<double>(info.source_timestamp.seconds()) +
                                  1e-9 * static_cast<double>(info.source_timestamp.nanosec());
    out.emplace_back(Received<Msg>{convert(sample), from, written_unix_s});
  }
}

template <typename Idl, typename Msg>
void TakeAll(Node::Impl& d, Topic topic, std::vector<Event>& out) {
  TakeAll<Idl, Msg>(d, topic, out, [](const Idl& sample) { return FromIdl(sample); });
}

void TakeTopic(Node::Impl& d, Topic topic, std::vector<Event>& out) {
  switch (topic) {
    case Topic::kTruth:
      return TakeAll<deif_msgs::Truth, protocol::TruthMsg>(d, topic, out);
    case Topic::kRange:
      return TakeAll<deif_msgs::Range, protocol::RangeMsg>(d, topic, out);
    case Topic::kContribution:
      return TakeAll<deif_msgs::Contribution, protocol::ContributionMsg>(d, topic, out);
    case Topic::kAgentState:
      return TakeAll<deif_msgs::AgentState, protocol::StateMsg>(d, topic, out);
    case Topic::kRelayUp:
    case Topic::kRelayDown: {
      const bool down = topic == Topic::kRelayDown;
      return TakeAll<deif_msgs::ContributionBatch, protocol::BatchMsg>(
          d, topic, out, [down](const deif_msgs::ContributionBatch& b) { return FromIdl(b, down); });
    }
  }
}

}  // namespace

void Node::Write(const protocol::TruthMsg& msg) { WriteSample(*impl_, Topic::kTruth, ToIdl(msg)); }
void Node::Write(const protocol::RangeMsg& msg) {
  WriteSample(*impl_, Topic::kRange, ToIdl(msg), msg.agent_id);
}
void Node::Write(const protocol::ContributionMsg& msg) {
  WriteSample(*impl_, Topic::kContribution, ToIdl(msg));
}
void Node::Write(const protocol::StateMsg& msg) { WriteSample(*impl_, Topic::kAgentState, ToIdl(msg)); }
void Node::Write(const protocol::BatchMsg& msg) {
  WriteSample(*impl_, msg.down ? Topic::kRelayDown : Topic::kRelayUp, ToIdl(msg));
}

std::vector<Event> Node::Wait(Clock::time_point deadline) {
  Impl& d = *impl_;
  const auto now = Clock::now();
  if (deadline > now && d.stashed.empty()) {
    fdds::ConditionSeq active;
    const double wait_s = std::chrono::duration<double>(deadline - now).count();
    d.waitset.wait(active, DdsDuration(std::min(wait_s, 3600.0)));
  }
  std::vector<Event> events;
  events.swap(d.stashed);
  for (const Topic topic : kAllTopics) TakeTopic(d, topic, events);
  for (const Topic topic : d.readers_to_remake) {
    ReplaceReader(d, topic);
    d.readers_made_anew.push_back(topic);
  }
  d.readers_to_remake.clear();
  std::vector<LivelinessChange> liveliness;
  {
    std::lock_guard<std::mutex> lock(d.events_mutex);
    liveliness.swap(d.liveliness_events);
    d.guard.set_trigger_value(false);
  }
  for (const LivelinessChange& change : liveliness) {
    if (d.own_writers.count(change.writer) == 0) events.emplace_back(change);
  }
  return events;
}

void Node::Wake() { impl_->guard.set_trigger_value(true); }

bool Node::WaitForAcknowledgments(double seconds) {
  // Every writer has the whole window at once: one at a time, a writer whose reader left
  // without a goodbye used it up before the next one was looked at.
  const auto deadline = Clock::now() + std::chrono::duration_cast<Clock::duration>(std::chrono::duration<double>(seconds));
  std::vector<fdds::DataWriter*> pending;
  for (auto& [topic, writer] : impl_->every_writer) pending.push_back(writer);
  while (true) {
    pending.erase(std::remove_if(pending.begin(), pending.end(),
                                 [](fdds::DataWriter* writer) {
                                   return writer->wait_for_acknowledgments(DdsDuration(0.0)) ==
                                          ReturnCode_t::RETCODE_OK;
                                 }),
                  pending.end());
    const auto now = Clock::now();
    if (pending.empty() || now >= deadline) return pending.empty();
    std::this_thread::sleep_for(std::min<Clock::duration>(deadline - now, std::chrono::milliseconds(2)));
  }
}

bool Node::Secure() const { return impl_->secure; }

std::optional<AgentId> Node::AuthorizedAgent(const protocol::SenderKey& writer) const {
  if (!impl_->secure) return std::nullopt;
  const auto partitions = impl_->participant_listener.Of(writer);
  if (!partitions) return std::nullopt;
  return AuthorizedAgentOf(*partitions, impl_->run_name);
}

protocol::SenderKey Node::WriterKey(Topic topic) const {
  return ToKey(impl_->writers.at(topic)->get_instance_handle());
}

int Node::AuthenticationRestarts() const { return impl_->authentication_restarts; }

void Node::Abandon() {
  Impl* leaked = impl_.release();  // DDS threads may still use it until the process ends
  (void)leaked;
}

bool Node::TargetUp() const { return impl_->participant_listener.WatchedUp(); }

std::optional<double> Node::DiscoveryServerSinceS() const { return impl_->participant_listener.ServerSinceS(); }

std::set<AgentId> Node::AgentsUp() const { return impl_->participant_listener.AgentsUp(); }

std::uint64_t Node::ParticipantsVersion() const { return impl_->participant_listener.Version(); }

std::uint64_t Node::EndpointsHeard() const { return impl_->participant_listener.EndpointsHeard(); }

bool Node::ReceiveStuck() { return g_receive_stuck.load(); }

void SetReaderLoopHandler(ReaderLoopHandler handler) { g_reader_loop_handler.store(handler); }

void LoopOverALostChangeForTest() {
  for (;;) {
    // In bursts, as Fast DDS's loop never sleeps: one error per wake-up of a thread that
    // sleeps came too seldom on a loaded host (a SCHED_BATCH agent waits long to run again)
    // and was never taken for the loop (docs/FASTDDS_NOTES.md).
    for (int i = 0; i < 100; ++i) {
      fdds::Log::QueueLog("Change not found on this key, something is wrong",
                          fdds::Log::Context{__FILE__, __LINE__, __func__, "SUBSCRIBER"}, fdds::Log::Kind::Error);
    }
    std::this_thread::sleep_for(std::chrono::milliseconds(1));
  }
}

std::string ShmPortsUsedSoFar() {
  std::set<int> ports = PortsOfList(std::getenv(kShmPortsUsedVariable));
  {
    std::lock_guard<std::mutex> lock(g_listened_mutex);
    ports.insert(g_listened_ports.begin(), g_listened_ports.end());
  }
  std::string list;
  for (int port : ports) list += (list.empty() ? "" : ",") + std::to_string(port);
  return list;
}

std::vector<int> Node::ShmPortsListened() const {
  return impl_->port_watch ? impl_->port_watch->ports() : std::vector<int>{};
}

std::vector<protocol::SenderKey> Node::EndedAgents(double every_s,
                                                   const std::function<std::set<AgentId>()>& suspects,
                                                   double suspects_every_s,
                                                   const std::function<std::set<AgentId>()>& waited_for) {
  Impl& d = *impl_;
  if (!d.config.network.process_watch || d.participant == nullptr) return {};
  const auto now = Clock::now();
  const auto after = [&now](double s) {
    return now + std::chrono::duration_cast<Clock::duration>(std::chrono::duration<double>(s));
  };
  const bool all = now >= d.next_ended_check;
  if (!all && ((!suspects && !waited_for) || now < d.next_suspects_check)) return {};
  if (all) {
    // Spread over the interval, so that the processes of a run do not all look at once.
    static thread_local std::minstd_rand jitter{std::random_device{}()};
    d.next_ended_check = after(every_s * std::uniform_real_distribution<double>(0.5, 1.5)(jitter));
    // This host's id as Fast DDS puts it in the GUID prefix (bytes 2-3) and in its
    // shared-memory locators (address bytes 1-2).
    const auto& prefix = d.participant->guid().guidPrefix.value;
    d.ended_watch.Watch(d.participant_listener.AgentShmPorts({prefix[2], prefix[3]}, d.ended_watch_agents));
    return d.ended_watch.Check();
  }
  // Due whether or not anyone is left out: working out who is costs a pass over the members
  // (not at every pass of the agent's loop).
  d.next_suspects_check = after(suspects_every_s);
  const std::set<AgentId> ids = suspects ? suspects() : std::set<AgentId>{};
  const std::set<AgentId> waited = waited_for ? waited_for() : std::set<AgentId>{};
  if (ids.empty() && waited.empty()) return {};
  std::set<protocol::SenderKey> only, twice;
  for (const auto& [key, id] : d.ended_watch_agents) {
    if (ids.count(id) > 0) {
      only.insert(key);
    } else if (waited.count(id) > 0) {
      twice.insert(key);
    }
  }
  // One free look: the target, which looked twice, left them out of its roll call. Two for
  // the others (a listener that makes its own port anew lets go of its lock for a moment).
  std::vector<protocol::SenderKey> ended = only.empty() ? std::vector<protocol::SenderKey>{} : d.ended_watch.Check(only, 1);
  if (!twice.empty()) {
    for (const protocol::SenderKey& key : d.ended_watch.Check(twice, 2)) ended.push_back(key);
  }
  return ended;
}

std::vector<int> Node::PortsLost() {
  Impl& d = *impl_;
  if (!d.port_watch || d.port_watch->ports().empty()) return {};
  const Clock::time_point now = Clock::now();
  if (now < d.next_port_check) return {};
  d.next_port_check = now + std::chrono::seconds(1);
  return d.port_watch->Lost(ToSeconds(now));
}

void Node::MakeReaderAnewForTest(Topic topic) { impl_->readers_to_remake.insert(topic); }

std::vector<Topic> Node::ReadersMadeAnew() {
  std::vector<Topic> out;
  out.swap(impl_->readers_made_anew);
  return out;
}

long Node::DroppedByIdRange() const { return impl_->filter_factory.dropped.load(); }

void Node::StopWriterSideFiltering() {
  Impl& d = *impl_;
  if (!d.writers.empty() || !d.filtered.empty()) {
    throw std::logic_error("StopWriterSideFiltering comes before any writer or filtered reader");
  }
  if (d.filters_registered) d.participant->unregister_content_filter_factory(kAgentIdFilterClass);
  d.filters_registered = false;
}

std::set<protocol::SenderKey> Node::MatchedReaderKeys(Topic topic) const {
  auto it = impl_->writer_listeners.find(topic);
  if (it == impl_->writer_listeners.end()) return {};
  return it->second->Readers();
}

int Node::MatchedWriters(Topic topic) const {
  auto it = impl_->readers.find(topic);
  if (it == impl_->readers.end()) return 0;
  fdds::SubscriptionMatchedStatus status;
  it->second->get_subscription_matched_status(status);
  return status.current_count;
}

int Node::MatchedReaders(Topic topic) const {
  if (topic == Topic::kRange && impl_->range_partitions) {  // the readers of any of them
    auto listener = impl_->writer_listeners.find(topic);
    return listener == impl_->writer_listeners.end() ? 0 : static_cast<int>(listener->second->Readers().size());
  }
  auto it = impl_->writers.find(topic);
  if (it == impl_->writers.end()) return 0;
  fdds::PublicationMatchedStatus status;
  it->second->get_publication_matched_status(status);
  return status.current_count;
}

double RestartWindowS(int restart, int agents) {
  return std::min(20.0, 0.2 * (std::max(agents, 1) + 1) * std::max(restart, 1));
}

std::uint64_t RandomInstanceToken() {
  std::random_device device;
  const std::uint64_t high = device();
  const std::uint64_t low = device();
  const auto now = static_cast<std::uint64_t>(Clock::now().time_since_epoch().count());
  return ((high << 32) ^ low ^ now) | 1u;  // never 0
}

}  // namespace deif::dds
