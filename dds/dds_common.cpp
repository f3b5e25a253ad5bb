#include "dds/dds_common.hpp"

#include <pthread.h>
#include <signal.h>

#include <cstdio>
#include <cstdlib>
#include <random>
#include <stdexcept>

#include <fastdds/dds/domain/DomainParticipantFactory.hpp>
#include <fastdds/rtps/transport/UDPv4TransportDescriptor.h>
#include <spdlog/sinks/basic_file_sink.h>
#include <spdlog/sinks/stdout_color_sinks.h>
#include <spdlog/spdlog.h>

#include "deifPubSubTypes.h"

namespace deif::dds {

Clock::duration ToDuration(double seconds) {
  return std::chrono::duration_cast<Clock::duration>(Seconds(seconds));
}

namespace {

eprosima::fastrtps::Duration_t DdsDuration(double seconds) {
  return eprosima::fastrtps::Duration_t(static_cast<long double>(seconds));
}

// MANUAL_BY_TOPIC: AUTOMATIC liveliness does not detect a killed writer in Fast DDS 2.9.1
// (PITFALLS.md). The writer renews it with every write() and with assert_liveliness().
fdds::LivelinessQosPolicy ManualByTopic(double lease_s) {
  fdds::LivelinessQosPolicy liveliness;
  liveliness.kind = fdds::MANUAL_BY_TOPIC_LIVELINESS_QOS;
  liveliness.lease_duration = DdsDuration(lease_s);
  liveliness.announcement_period = DdsDuration(lease_s / 4.0);
  return liveliness;
}

constexpr int kMaxAgentInstances = 512;

template <typename Qos>
void Common(Qos& qos, fdds::DurabilityQosPolicyKind durability, int depth) {
  qos.reliability().kind = fdds::RELIABLE_RELIABILITY_QOS;
  qos.durability().kind = durability;
  qos.history().kind = fdds::KEEP_LAST_HISTORY_QOS;
  qos.history().depth = depth;
  // Keyed topics have one instance per agent. Fast DDS 2.9 defaults to max_instances = 10:
  // with more than 10 agents the 11th instance was silently refused (measured: a 64-agent
  // run saw exactly 10 agents). Instances are unbounded; each keeps `depth` samples.
  // (LENGTH_UNLIMITED is refused here in combination with KEEP_LAST: the entities are
  // not created.) kMaxAgentInstances is well above the ~100 processes one host can run on
  // one domain (PITFALLS.md).
  qos.resource_limits().max_instances = kMaxAgentInstances;
  qos.resource_limits().max_samples_per_instance = depth;
  qos.resource_limits().max_samples = kMaxAgentInstances * depth;
  qos.data_sharing().off();
}

}  // namespace

fdds::DomainParticipantQos ParticipantQos(const NetworkConfig& network, const std::string& name) {
  // Start from the factory default, so that an XML profile named by
  // FASTRTPS_DEFAULT_PROFILES_FILE (initial peers, maxInitialPeersRange, transports: see
  // docs/RUNNING.md, several hosts) applies to every process.
  fdds::DomainParticipantQos qos =
      fdds::DomainParticipantFactory::get_instance()->get_default_participant_qos();
  qos.name(name);
  auto& discovery = qos.wire_protocol().builtin.discovery_config;
  // The default lease is 20 s; a short one lets peers drop a killed process quickly.
  discovery.leaseDuration = DdsDuration(network.participant_lease_s);
  discovery.leaseDuration_announcementperiod = DdsDuration(network.participant_announcement_s);
  // UDPv4 only by default. Fast DDS's shared-memory transport keeps a killed process's port
  // segment in /dev/shm; a process restarted into the same participant slot then received
  // nothing from its peers (measured here with kill -9 + restart of an agent). UDP also lets
  // tc/netem inject faults. DEIF_DDS_TRANSPORT=shm restores Fast DDS's SHM + UDPv4 default.
  const char* transport = std::getenv("DEIF_DDS_TRANSPORT");
  const bool profile_sets_transports = !qos.transport().user_transports.empty();
  if (!profile_sets_transports && (transport == nullptr || std::string(transport) != "shm")) {
    qos.transport().use_builtin_transports = false;
    qos.transport().user_transports.push_back(
        std::make_shared<eprosima::fastdds::rtps::UDPv4TransportDescriptor>());
  }
  return qos;
}

// Truth: logging and the end-of-run signal only. Volatile, so a late joiner does not see
// the end signal of an earlier run.
fdds::DataWriterQos TruthWriterQos() {
  fdds::DataWriterQos qos = fdds::DATAWRITER_QOS_DEFAULT;
  Common(qos, fdds::VOLATILE_DURABILITY_QOS, kTruthDepth);
  return qos;
}
fdds::DataReaderQos TruthReaderQos() {
  fdds::DataReaderQos qos = fdds::DATAREADER_QOS_DEFAULT;
  Common(qos, fdds::VOLATILE_DURABILITY_QOS, kTruthDepth);
  return qos;
}

// Range: keyed by agent id. Transient-local so that a range written just before the
// target's writer discovered an agent's reader still reaches it.
fdds::DataWriterQos RangeWriterQos() {
  fdds::DataWriterQos qos = fdds::DATAWRITER_QOS_DEFAULT;
  Common(qos, fdds::TRANSIENT_LOCAL_DURABILITY_QOS, kRangeDepth);
  return qos;
}
fdds::DataReaderQos RangeReaderQos() {
  fdds::DataReaderQos qos = fdds::DATAREADER_QOS_DEFAULT;
  Common(qos, fdds::TRANSIENT_LOCAL_DURABILITY_QOS, kRangeDepth);
  return qos;
}

// Contribution: keep last per agent id; its writer's liveliness is the agent's liveness.
fdds::DataWriterQos ContributionWriterQos(const NetworkConfig& network) {
  fdds::DataWriterQos qos = fdds::DATAWRITER_QOS_DEFAULT;
  Common(qos, fdds::TRANSIENT_LOCAL_DURABILITY_QOS, kContributionDepth);
  qos.liveliness() = ManualByTopic(network.liveliness_lease_s);
  return qos;
}
fdds::DataReaderQos ContributionReaderQos(const NetworkConfig& network) {
  fdds::DataReaderQos qos = fdds::DATAREADER_QOS_DEFAULT;
  Common(qos, fdds::TRANSIENT_LOCAL_DURABILITY_QOS, kContributionDepth);
  qos.liveliness() = ManualByTopic(network.liveliness_lease_s);
  return qos;
}

// Agent state: transient-local, so late joiners (a restarted target, a new agent) get the
// latest states; MANUAL_BY_TOPIC liveliness tells the target which agents are alive.
fdds::DataWriterQos AgentStateWriterQos(const NetworkConfig& network) {
  fdds::DataWriterQos qos = fdds::DATAWRITER_QOS_DEFAULT;
  Common(qos, fdds::TRANSIENT_LOCAL_DURABILITY_QOS, kAgentStateDepth);
  qos.liveliness() = ManualByTopic(network.liveliness_lease_s);
  return qos;
}
fdds::DataReaderQos AgentStateReaderQos(const NetworkConfig& network) {
  fdds::DataReaderQos qos = fdds::DATAREADER_QOS_DEFAULT;
  Common(qos, fdds::TRANSIENT_LOCAL_DURABILITY_QOS, kAgentStateDepth);
  qos.liveliness() = ManualByTopic(network.liveliness_lease_s);
  return qos;
}

// ---------------------------------------------------------------------------------------
DdsParticipant::DdsParticipant(int domain_id, const NetworkConfig& network,
                               const std::string& name) {
  auto* factory = fdds::DomainParticipantFactory::get_instance();
  participant_ = factory->create_participant(static_cast<fdds::DomainId_t>(domain_id),
                                             ParticipantQos(network, name));
  if (participant_ == nullptr) {
    throw std::runtime_error("cannot create a DDS participant on domain " +
                             std::to_string(domain_id));
  }
  const std::vector<std::pair<const char*, fdds::TypeSupport>> topics = {
      {kTruthTopic, fdds::TypeSupport(new deif_msgs::TruthPubSubType())},
      {kRangeTopic, fdds::TypeSupport(new deif_msgs::RangePubSubType())},
      {kContributionTopic, fdds::TypeSupport(new deif_msgs::ContributionPubSubType())},
      {kAgentStateTopic, fdds::TypeSupport(new deif_msgs::AgentStatePubSubType())},
  };
  for (const auto& [topic_name, type] : topics) {
    fdds::TypeSupport support = type;
    if (support.register_type(participant_) != ReturnCode_t::RETCODE_OK) {
      throw std::runtime_error(std::string("cannot register the type of ") + topic_name);
    }
    fdds::Topic* topic =
        participant_->create_topic(topic_name, support.get_type_name(), fdds::TOPIC_QOS_DEFAULT);
    if (topic == nullptr) throw std::runtime_error(std::string("cannot create topic ") + topic_name);
    topics_[topic_name] = topic;
  }
  publisher_ = participant_->create_publisher(fdds::PUBLISHER_QOS_DEFAULT);
  subscriber_ = participant_->create_subscriber(fdds::SUBSCRIBER_QOS_DEFAULT);
  if (publisher_ == nullptr || subscriber_ == nullptr) {
    throw std::runtime_error("cannot create the DDS publisher/subscriber");
  }
}

DdsParticipant::~DdsParticipant() {
  if (participant_ == nullptr) return;
  participant_->delete_contained_entities();
  fdds::DomainParticipantFactory::get_instance()->delete_participant(participant_);
}

fdds::Topic* DdsParticipant::TopicByName(const char* topic_name) const {
  auto it = topics_.find(topic_name);
  if (it == topics_.end()) throw std::logic_error(std::string("unknown topic ") + topic_name);
  return it->second;
}

fdds::DataWriter* DdsParticipant::CreateWriter(const char* topic_name,
                                               const fdds::DataWriterQos& qos) {
  fdds::DataWriter* writer = publisher_->create_datawriter(TopicByName(topic_name), qos);
  if (writer == nullptr) throw std::runtime_error(std::string("cannot create a writer on ") + topic_name);
  return writer;
}

fdds::DataReader* DdsParticipant::CreateReader(const char* topic_name,
                                               const fdds::DataReaderQos& qos,
                                               fdds::DataReaderListener* listener) {
  fdds::DataReader* reader = subscriber_->create_datareader(
      TopicByName(topic_name), qos, listener,
      fdds::StatusMask::data_available() << fdds::StatusMask::liveliness_changed()
                                         << fdds::StatusMask::subscription_matched());
  if (reader == nullptr) throw std::runtime_error(std::string("cannot create a reader on ") + topic_name);
  return reader;
}

// ---------------------------------------------------------------------------------------
WriterKey ToWriterKey(const fdds::InstanceHandle_t& handle) {
  WriterKey key{};
  for (std::size_t i = 0; i < key.size(); ++i) key[i] = handle.value[static_cast<unsigned>(i)];
  return key;
}

std::string ToString(const WriterKey& key) {
  std::string out;
  char byte[3];
  for (std::size_t i = 0; i < key.size(); ++i) {
    std::snprintf(byte, sizeof byte, "%02x", key[i]);
    out += byte;
    if (i == 11) out += '|';
  }
  return out;
}

ParticipantPrefix ParticipantOf(const WriterKey& key) {
  ParticipantPrefix prefix{};
  for (std::size_t i = 0; i < prefix.size(); ++i) prefix[i] = key[i];
  return prefix;
}

bool WriterTracker::OnSample(const WriterKey& writer, AgentId id, Clock::time_point now) {
  last_sample_[id] = now;
  return ids_.emplace(writer, id).second;
}

std::optional<AgentId> WriterTracker::OnWriterChanged(const WriterKey& writer, bool alive) {
  const bool changed = alive ? alive_.insert(writer).second : alive_.erase(writer) > 0;
  if (!changed) return std::nullopt;
  return IdOf(writer);
}

std::optional<AgentId> WriterTracker::IdOf(const WriterKey& writer) const {
  auto it = ids_.find(writer);
  if (it == ids_.end()) return std::nullopt;
  return it->second;
}

std::set<AgentId> WriterTracker::AliveIds() const {
  std::set<AgentId> out;
  for (const auto& writer : alive_) {
    if (auto id = IdOf(writer)) out.insert(*id);
  }
  return out;
}

std::set<WriterKey> WriterTracker::AliveUnknown() const {
  std::set<WriterKey> out;
  for (const auto& writer : alive_) {
    if (ids_.count(writer) == 0) out.insert(writer);
  }
  return out;
}

std::optional<Clock::time_point> WriterTracker::LastSampleOf(AgentId id) const {
  auto it = last_sample_.find(id);
  if (it == last_sample_.end()) return std::nullopt;
  return it->second;
}

// ---------------------------------------------------------------------------------------
LivelinessAsserter::LivelinessAsserter(std::vector<fdds::DataWriter*> writers, double period_s)
    : writers_(std::move(writers)),
      period_(ToDuration(period_s)) {
  last_write_.assign(writers_.size(), Clock::now() - period_);  // assert at once
  thread_ = std::thread([this] {
    std::unique_lock<std::mutex> lock(mutex_);
    while (!stop_) {
      const auto now = Clock::now();
      for (std::size_t i = 0; i < writers_.size(); ++i) {
        if (now - last_write_[i] >= period_) writers_[i]->assert_liveliness();
      }
      cv_.wait_for(lock, period_, [this] { return stop_; });
    }
  });
}

void LivelinessAsserter::NoteWrite(const fdds::DataWriter* writer) {
  std::lock_guard<std::mutex> lock(mutex_);
  for (std::size_t i = 0; i < writers_.size(); ++i) {
    if (writers_[i] == writer) last_write_[i] = Clock::now();
  }
}

LivelinessAsserter::~LivelinessAsserter() { Stop(); }

void LivelinessAsserter::Stop() {
  {
    std::lock_guard<std::mutex> lock(mutex_);
    stop_ = true;
  }
  cv_.notify_all();
  if (thread_.joinable()) thread_.join();
}

// ---------------------------------------------------------------------------------------
std::shared_ptr<spdlog::logger> MakeLogger(const std::string& name, const std::string& log_dir) {
  std::vector<spdlog::sink_ptr> sinks;
  sinks.push_back(std::make_shared<spdlog::sinks::stderr_color_sink_mt>());
  if (!log_dir.empty()) {
    sinks.push_back(
        std::make_shared<spdlog::sinks::basic_file_sink_mt>(log_dir + "/" + name + ".log", true));
  }
  auto logger = std::make_shared<spdlog::logger>(name, sinks.begin(), sinks.end());
  logger->set_pattern("[%Y-%m-%d %H:%M:%S.%e] [%n] [%l] %v");
  logger->flush_on(spdlog::level::info);
  spdlog::register_logger(logger);
  return logger;
}

namespace {
sigset_t StopSignals() {
  sigset_t set;
  sigemptyset(&set);
  sigaddset(&set, SIGINT);
  sigaddset(&set, SIGTERM);
  return set;
}
std::atomic<bool> g_signal_thread_exiting{false};
}  // namespace

SignalStopper::SignalStopper() {
  sigset_t set = StopSignals();
  pthread_sigmask(SIG_BLOCK, &set, nullptr);  // inherited by every thread created later
  thread_ = std::thread([this] {
    sigset_t wait_set = StopSignals();
    for (;;) {
      int signal_number = 0;
      if (sigwait(&wait_set, &signal_number) != 0) continue;
      if (g_signal_thread_exiting.load()) return;
      std::lock_guard<std::mutex> lock(mutex_);
      if (on_signal_) on_signal_(signal_number);
    }
  });
}

SignalStopper::~SignalStopper() {
  g_signal_thread_exiting.store(true);
  pthread_kill(thread_.native_handle(), SIGTERM);
  thread_.join();
}

void SignalStopper::SetHandler(std::function<void(int)> on_signal) {
  std::lock_guard<std::mutex> lock(mutex_);
  on_signal_ = std::move(on_signal);
}

std::uint64_t RandomInstanceToken() {
  std::random_device device;
  const std::uint64_t high = device();
  const std::uint64_t low = device();
  const auto now = static_cast<std::uint64_t>(Clock::now().time_since_epoch().count());
  return ((high << 32) ^ low ^ now) | 1u;  // never 0
}

}  // namespace deif::dds
