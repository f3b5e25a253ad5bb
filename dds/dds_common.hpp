// Fast DDS plumbing shared by deif_agent and deif_target: topic names, QoS profiles, an
// RAII participant, a generic reader listener, the writer-liveness tracker, the liveliness
// asserter thread, the event inbox and signal handling. No estimation logic lives here.
#pragma once

#include <array>
#include <atomic>
#include <chrono>
#include <condition_variable>
#include <cstdint>
#include <deque>
#include <functional>
#include <map>
#include <memory>
#include <mutex>
#include <optional>
#include <set>
#include <string>
#include <thread>
#include <vector>

#include <fastdds/dds/domain/DomainParticipant.hpp>
#include <fastdds/dds/publisher/DataWriter.hpp>
#include <fastdds/dds/publisher/Publisher.hpp>
#include <fastdds/dds/subscriber/DataReader.hpp>
#include <fastdds/dds/subscriber/DataReaderListener.hpp>
#include <fastdds/dds/subscriber/SampleInfo.hpp>
#include <fastdds/dds/subscriber/Subscriber.hpp>
#include <fastdds/dds/topic/Topic.hpp>
#include <spdlog/logger.h>

#include "common/config/config.hpp"

namespace deif::dds {

namespace fdds = eprosima::fastdds::dds;

// Topic names: a contract (DESIGN.md).
inline constexpr const char* kTruthTopic = "deif/truth";
inline constexpr const char* kRangeTopic = "deif/range";
inline constexpr const char* kContributionTopic = "deif/contribution";
inline constexpr const char* kAgentStateTopic = "deif/agent_state";

// Truth.step value that announces the end of the run.
inline constexpr std::int64_t kEndOfRunStep = -1;

// Depths of the keyed histories (per instance, i.e. per agent id).
inline constexpr int kRangeDepth = 4;
inline constexpr int kContributionDepth = 8;
inline constexpr int kAgentStateDepth = 8;
inline constexpr int kTruthDepth = 4;

using Clock = std::chrono::steady_clock;
using Seconds = std::chrono::duration<double>;

Clock::duration ToDuration(double seconds);

// ---------------------------------------------------------------------------------------
// QoS. Every topic is RELIABLE; data sharing is off (no fast_datasharing_* files left in
// /dev/shm after a kill -9). See the .cpp for each choice.
fdds::DomainParticipantQos ParticipantQos(const NetworkConfig& network, const std::string& name);
fdds::DataWriterQos TruthWriterQos();
fdds::DataReaderQos TruthReaderQos();
fdds::DataWriterQos RangeWriterQos();
fdds::DataReaderQos RangeReaderQos();
fdds::DataWriterQos ContributionWriterQos(const NetworkConfig& network);
fdds::DataReaderQos ContributionReaderQos(const NetworkConfig& network);
fdds::DataWriterQos AgentStateWriterQos(const NetworkConfig& network);
fdds::DataReaderQos AgentStateReaderQos(const NetworkConfig& network);

// ---------------------------------------------------------------------------------------
// A participant with its four topics, one publisher and one subscriber. The destructor
// deletes every contained entity and then the participant. Listeners given to readers
// must outlive this object (declare them before it, or reset() it first).
class DdsParticipant {
 public:
  DdsParticipant(int domain_id, const NetworkConfig& network, const std::string& name);
  ~DdsParticipant();
  DdsParticipant(const DdsParticipant&) = delete;
  DdsParticipant& operator=(const DdsParticipant&) = delete;

  fdds::DataWriter* CreateWriter(const char* topic_name, const fdds::DataWriterQos& qos);
  fdds::DataReader* CreateReader(const char* topic_name, const fdds::DataReaderQos& qos,
                                 fdds::DataReaderListener* listener);

 private:
  fdds::Topic* TopicByName(const char* topic_name) const;

  fdds::DomainParticipant* participant_ = nullptr;
  fdds::Publisher* publisher_ = nullptr;
  fdds::Subscriber* subscriber_ = nullptr;
  std::map<std::string, fdds::Topic*> topics_;
};

// ---------------------------------------------------------------------------------------
// The identity of a remote writer: its GUID, as the 16 bytes of an InstanceHandle_t.
using WriterKey = std::array<std::uint8_t, 16>;
WriterKey ToWriterKey(const fdds::InstanceHandle_t& handle);
std::string ToString(const WriterKey& key);
// The participant of a writer: the first 12 bytes (GUID prefix) of its GUID.
using ParticipantPrefix = std::array<std::uint8_t, 12>;
ParticipantPrefix ParticipantOf(const WriterKey& key);

// A reader listener that takes every sample and forwards it, and reports each remote
// writer becoming alive / not alive (liveliness or unmatching). Runs on DDS threads: the
// callbacks must be thread-safe (they push into an Inbox).
template <typename T>
class ReaderListener : public fdds::DataReaderListener {
 public:
  using SampleFn = std::function<void(const T&, const WriterKey&)>;
  using WriterFn = std::function<void(const WriterKey&, bool alive)>;

  ReaderListener(SampleFn on_sample, WriterFn on_writer)
      : on_sample_(std::move(on_sample)), on_writer_(std::move(on_writer)) {}

  void on_data_available(fdds::DataReader* reader) override {
    T sample;
    fdds::SampleInfo info;
    while (reader->take_next_sample(&sample, &info) == ReturnCode_t::RETCODE_OK) {
      if (info.valid_data) on_sample_(sample, ToWriterKey(info.publication_handle));
    }
  }

  void on_liveliness_changed(fdds::DataReader*,
                             const fdds::LivelinessChangedStatus& status) override {
    if (!on_writer_) return;
    if (status.alive_count_change > 0) on_writer_(ToWriterKey(status.last_publication_handle), true);
    if (status.alive_count_change < 0) on_writer_(ToWriterKey(status.last_publication_handle), false);
  }

  void on_subscription_matched(fdds::DataReader*,
                               const fdds::SubscriptionMatchedStatus& status) override {
    if (on_writer_ && status.current_count_change < 0) {
      on_writer_(ToWriterKey(status.last_publication_handle), false);
    }
  }

 private:
  SampleFn on_sample_;
  WriterFn on_writer_;
};

// ---------------------------------------------------------------------------------------
// Which remote writers are alive and which agent id each one speaks for. get_key_value is
// unsupported in Fast DDS 2.9, so ids are learnt from the samples themselves. Not
// thread-safe: used by the application thread only.
class WriterTracker {
 public:
  // A sample from writer claimed agent id. Returns true the first time this writer is seen.
  bool OnSample(const WriterKey& writer, AgentId id, Clock::time_point now);
  // Learn a writer's id without a sample of its own.
  void Identify(const WriterKey& writer, AgentId id) { ids_.emplace(writer, id); }
  // Liveliness / matching change. Returns the agent id when a known writer changed state.
  std::optional<AgentId> OnWriterChanged(const WriterKey& writer, bool alive);

  bool IsAlive(const WriterKey& writer) const { return alive_.count(writer) > 0; }
  std::optional<AgentId> IdOf(const WriterKey& writer) const;
  // Ids of alive writers whose id is known.
  std::set<AgentId> AliveIds() const;
  // Alive writers that have not sent a sample yet (id unknown).
  std::set<WriterKey> AliveUnknown() const;
  // When the last sample of an agent id arrived.
  std::optional<Clock::time_point> LastSampleOf(AgentId id) const;

 private:
  std::set<WriterKey> alive_;
  std::map<WriterKey, AgentId> ids_;
  std::map<AgentId, Clock::time_point> last_sample_;
};

// ---------------------------------------------------------------------------------------
// A thread-safe queue of events from DDS listener threads to the application thread.
template <typename Event>
class Inbox {
 public:
  void Push(Event event) {
    {
      std::lock_guard<std::mutex> lock(mutex_);
      events_.push_back(std::move(event));
    }
    cv_.notify_all();
  }
  // Wakes a waiter without an event (stop requests).
  void Wake() {
    {
      std::lock_guard<std::mutex> lock(mutex_);
      woken_ = true;
    }
    cv_.notify_all();
  }
  // Waits until an event arrives, Wake() is called, or the deadline passes; returns what
  // arrived (possibly nothing).
  std::vector<Event> WaitUntil(Clock::time_point deadline) {
    std::unique_lock<std::mutex> lock(mutex_);
    cv_.wait_until(lock, deadline, [this] { return woken_ || !events_.empty(); });
    woken_ = false;
    std::vector<Event> out(std::make_move_iterator(events_.begin()),
                           std::make_move_iterator(events_.end()));
    events_.clear();
    return out;
  }

 private:
  std::mutex mutex_;
  std::condition_variable cv_;
  std::deque<Event> events_;
  bool woken_ = false;
};

// ---------------------------------------------------------------------------------------
// Asserts the liveliness of MANUAL_BY_TOPIC writers from its own thread, so a process that
// is blocked waiting stays alive to its peers. A write() renews a writer's liveliness too, so
// a writer that wrote within the last period is not asserted again: in a busy network every
// assertion is one message to every matched reader (N^2 a period), which at 64 agents on
// two cores was enough traffic to starve the processes and make the liveliness flap.
class LivelinessAsserter {
 public:
  LivelinessAsserter(std::vector<fdds::DataWriter*> writers, double period_s);
  ~LivelinessAsserter();  // stops and joins
  LivelinessAsserter(const LivelinessAsserter&) = delete;
  LivelinessAsserter& operator=(const LivelinessAsserter&) = delete;
  void Stop();
  // Call after writer->write(): its liveliness was just renewed.
  void NoteWrite(const fdds::DataWriter* writer);

 private:
  std::vector<fdds::DataWriter*> writers_;
  std::vector<Clock::time_point> last_write_;  // guarded by mutex_
  Clock::duration period_;
  std::mutex mutex_;
  std::condition_variable cv_;
  bool stop_ = false;
  std::thread thread_;
};

// ---------------------------------------------------------------------------------------
// Process plumbing.

// The process logger: console plus <log_dir>/<name>.log when log_dir is not empty.
std::shared_ptr<spdlog::logger> MakeLogger(const std::string& name, const std::string& log_dir);

// Blocks SIGINT/SIGTERM in the calling thread (call first in main, before any thread
// exists) and, from a dedicated thread, calls on_signal when one arrives.
class SignalStopper {
 public:
  SignalStopper();
  ~SignalStopper();
  SignalStopper(const SignalStopper&) = delete;
  SignalStopper& operator=(const SignalStopper&) = delete;
  void SetHandler(std::function<void(int)> on_signal);

 private:
  std::mutex mutex_;
  std::function<void(int)> on_signal_;
  std::thread thread_;
};

// A random 64-bit token, different at every process start.
std::uint64_t RandomInstanceToken();

}  // namespace deif::dds
