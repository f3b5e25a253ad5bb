// The raw floor of the lock-step protocol: a Fast DDS ping-pong between two processes with
// the project's own message type (deif_msgs::Contribution) and the project's own QoS for it
// (deif::dds::ContributionWriterQos / ContributionReaderQos: reliable, keep last, data
// sharing off, MANUAL_BY_TOPIC liveliness), over one forced transport.
//
//   dds_pingpong --role pong --transport shm --domain 201 &
//   dds_pingpong --role ping --transport shm --domain 201 --samples 2000
//
// The ping writes a sample on "bench/ping"; the pong's application thread takes it and writes
// it back on "bench/pong"; the ping measures the round trip with steady_clock. Both sides
// receive through a listener that hands samples to the application thread, the same path the
// agents use (listener -> inbox -> step loop). The ping prints one JSON object on stdout.
//
// Transports: shm = SharedMemTransportDescriptor only; udp = UDPv4TransportDescriptor only.
// The builtin transports are disabled in both cases; data sharing is off (project QoS).
#include <algorithm>
#include <atomic>
#include <chrono>
#include <cmath>
#include <condition_variable>
#include <cstdio>
#include <deque>
#include <memory>
#include <mutex>
#include <stdexcept>
#include <string>
#include <thread>
#include <vector>

#include <CLI/CLI.hpp>
#include <fastdds/dds/domain/DomainParticipant.hpp>
#include <fastdds/dds/domain/DomainParticipantFactory.hpp>
#include <fastdds/dds/publisher/DataWriter.hpp>
#include <fastdds/dds/publisher/DataWriterListener.hpp>
#include <fastdds/dds/publisher/Publisher.hpp>
#include <fastdds/dds/subscriber/DataReader.hpp>
#include <fastdds/dds/subscriber/DataReaderListener.hpp>
#include <fastdds/dds/subscriber/SampleInfo.hpp>
#include <fastdds/dds/subscriber/Subscriber.hpp>
#include <fastdds/dds/topic/Topic.hpp>
#include <fastdds/rtps/transport/UDPv4TransportDescriptor.h>
#include <fastdds/rtps/transport/shared_mem/SharedMemTransportDescriptor.h>

#include "dds/dds_common.hpp"
#include "deifPubSubTypes.h"

namespace {

namespace fdds = eprosima::fastdds::dds;
using Clock = std::chrono::steady_clock;

constexpr const char* kPingTopic = "bench/ping";
constexpr const char* kPongTopic = "bench/pong";
constexpr long long kQuitStep = -1;

// Samples from the listener thread to the application thread.
class SampleQueue {
 public:
  void Push(const deif_msgs::Contribution& sample) {
    {
      std::lock_guard<std::mutex> lock(mutex_);
      samples_.push_back(sample);
    }
    cv_.notify_one();
  }
  // The next sample, or false at the deadline.
  bool Pop(deif_msgs::Contribution& out, Clock::time_point deadline) {
    std::unique_lock<std::mutex> lock(mutex_);
    if (!cv_.wait_until(lock, deadline, [this] { return !samples_.empty(); })) return false;
    out = samples_.front();
    samples_.pop_front();
    return true;
  }

 private:
  std::mutex mutex_;
  std::condition_variable cv_;
  std::deque<deif_msgs::Contribution> samples_;
};

class Listener : public fdds::DataReaderListener {
 public:
  explicit Listener(SampleQueue& queue) : queue_(queue) {}
  void on_data_available(fdds::DataReader* reader) override {
    deif_msgs::Contribution sample;
    fdds::SampleInfo info;
    while (reader->take_next_sample(&sample, &info) == ReturnCode_t::RETCODE_OK) {
      if (info.valid_data) queue_.Push(sample);
    }
  }
  void on_subscription_matched(fdds::DataReader*,
                               const fdds::SubscriptionMatchedStatus& status) override {
    matched_writers = status.current_count;
  }
  std::atomic<int> matched_writers{0};

 private:
  SampleQueue& queue_;
};

class WriterListener : public fdds::DataWriterListener {
 public:
  void on_publication_matched(fdds::DataWriter*,
                              const fdds::PublicationMatchedStatus& status) override {
    matched_readers = status.current_count;
  }
  std::atomic<int> matched_readers{0};
};

fdds::DomainParticipantQos TransportQos(const std::string& transport) {
  deif::NetworkConfig network;  // the agents' defaults: 1 s participant lease, 0.25 s announce
  fdds::DomainParticipantQos qos = deif::dds::ParticipantQos(network, "dds_pingpong");
  qos.transport().use_builtin_transports = false;
  if (transport == "shm") {
    qos.transport().user_transports.push_back(
        std::make_shared<eprosima::fastdds::rtps::SharedMemTransportDescriptor>());
  } else {
    qos.transport().user_transports.push_back(
        std::make_shared<eprosima::fastdds::rtps::UDPv4TransportDescriptor>());
  }
  return qos;
}

double Percentile(std::vector<double> v, double p) {
  if (v.empty()) return std::nan("");
  std::sort(v.begin(), v.end());
  const double rank = p / 100.0 * static_cast<double>(v.size() - 1);
  const auto lo = static_cast<std::size_t>(std::floor(rank));
  const auto hi = std::min(lo + 1, v.size() - 1);
  return v[lo] + (rank - static_cast<double>(lo)) * (v[hi] - v[lo]);
}

struct Options {
  std::string role = "ping";
  std::string transport = "shm";
  int samples = 2000;
  int warmup = 200;
  int domain = 200;
  double timeout_s = 30.0;
};

int Run(const Options& opt) {
  auto* factory = fdds::DomainParticipantFactory::get_instance();
  fdds::DomainParticipant* participant = factory->create_participant(
      static_cast<fdds::DomainId_t>(opt.domain), TransportQos(opt.transport));
  if (participant == nullptr) throw std::runtime_error("cannot create the participant");

  fdds::TypeSupport type(new deif_msgs::ContributionPubSubType());
  type.register_type(participant);
  const bool is_ping = opt.role == "ping";
  fdds::Topic* out_topic = participant->create_topic(is_ping ? kPingTopic : kPongTopic,
                                                     type.get_type_name(), fdds::TOPIC_QOS_DEFAULT);
  fdds::Topic* in_topic = participant->create_topic(is_ping ? kPongTopic : kPingTopic,
                                                    type.get_type_name(), fdds::TOPIC_QOS_DEFAULT);
  fdds::Publisher* publisher = participant->create_publisher(fdds::PUBLISHER_QOS_DEFAULT);
  fdds::Subscriber* subscriber = participant->create_subscriber(fdds::SUBSCRIBER_QOS_DEFAULT);

  deif::NetworkConfig network;
  SampleQueue queue;
  Listener reader_listener(queue);
  WriterListener writer_listener;
  fdds::DataWriter* writer = publisher->create_datawriter(
      out_topic, deif::dds::ContributionWriterQos(network), &writer_listener,
      fdds::StatusMask::publication_matched());
  fdds::DataReader* reader = subscriber->create_datareader(
      in_topic, deif::dds::ContributionReaderQos(network), &reader_listener,
      fdds::StatusMask::data_available() << fdds::StatusMask::subscription_matched());
  if (writer == nullptr || reader == nullptr) throw std::runtime_error("cannot create entities");

  const Clock::time_point give_up = Clock::now() + std::chrono::duration_cast<Clock::duration>(
                                                       std::chrono::duration<double>(opt.timeout_s));
  int status = 0;
  const Clock::time_point t_launch = Clock::now();
  while ((writer_listener.matched_readers < 1 || reader_listener.matched_writers < 1) &&
         Clock::now() < give_up) {
    std::this_thread::sleep_for(std::chrono::milliseconds(1));
  }
  const double match_s = std::chrono::duration<double>(Clock::now() - t_launch).count();

  deif_msgs::Contribution msg;
  msg.agent_id(is_ping ? 1 : 2);
  msg.info_x(1.0);
  msg.info_y(2.0);
  msg.info_xx(3.0);
  msg.info_xy(0.5);
  msg.info_yx(0.5);
  msg.info_yy(4.0);

  if (is_ping) {
    std::vector<double> rtt_us;
    rtt_us.reserve(static_cast<std::size_t>(opt.samples));
    int lost = 0;
    const int total = opt.warmup + opt.samples;
    deif_msgs::Contribution echo;
    for (int i = 0; i < total && Clock::now() < give_up; ++i) {
      msg.step(i);
      const Clock::time_point t0 = Clock::now();
      writer->write(&msg);
      bool got = false;
      // One outstanding sample at a time; a stale echo (of an earlier, timed-out step) is skipped.
      while (queue.Pop(echo, t0 + std::chrono::seconds(1))) {
        if (echo.step() == i) {
          got = true;
          break;
        }
      }
      const Clock::time_point t1 = Clock::now();
      if (!got) {
        ++lost;
        continue;
      }
      if (i >= opt.warmup) {
        rtt_us.push_back(std::chrono::duration<double, std::micro>(t1 - t0).count());
      }
    }
    msg.step(kQuitStep);
    writer->write(&msg);
    // Give the reliable protocol a moment to deliver the quit sample before we go away.
    writer->wait_for_acknowledgments(eprosima::fastrtps::Duration_t(1, 0));
    double mean = 0.0;
    for (double v : rtt_us) mean += v;
    if (!rtt_us.empty()) mean /= static_cast<double>(rtt_us.size());
    std::printf(
        "{\"transport\": \"%s\", \"samples\": %zu, \"warmup\": %d, \"lost\": %d, "
        "\"match_s\": %.4f, \"rtt_us\": {\"p50\": %.2f, \"p90\": %.2f, \"p99\": %.2f, "
        "\"min\": %.2f, \"max\": %.2f, \"mean\": %.2f}, \"payload_bytes\": %u}\n",
        opt.transport.c_str(), rtt_us.size(), opt.warmup, lost, match_s,
        Percentile(rtt_us, 50), Percentile(rtt_us, 90), Percentile(rtt_us, 99),
        Percentile(rtt_us, 0), Percentile(rtt_us, 100), mean,
        static_cast<unsigned>(deif_msgs::Contribution::getCdrSerializedSize(msg)));
    std::fflush(stdout);
    if (rtt_us.size() < static_cast<std::size_t>(opt.samples) / 2) status = 1;
  } else {
    deif_msgs::Contribution in;
    long echoed = 0;
    while (Clock::now() < give_up && queue.Pop(in, give_up)) {
      if (in.step() == kQuitStep) break;
      msg.step(in.step());
      writer->write(&msg);
      ++echoed;
    }
    std::printf("{\"role\": \"pong\", \"transport\": \"%s\", \"echoed\": %ld}\n",
                opt.transport.c_str(), echoed);
    std::fflush(stdout);
  }

  // Entities before the listeners they point to (PITFALLS.md).
  participant->delete_contained_entities();
  factory->delete_participant(participant);
  return status;
}

}  // namespace

int main(int argc, char** argv) {
  Options opt;
  CLI::App app{"Fast DDS ping-pong with deif_msgs::Contribution and the project's QoS"};
  app.add_option("--role", opt.role, "ping or pong")->check(CLI::IsMember({"ping", "pong"}));
  app.add_option("--transport", opt.transport, "shm or udp")
      ->check(CLI::IsMember({"shm", "udp"}));
  app.add_option("--samples", opt.samples, "measured round trips (after the warm-up)")
      ->check(CLI::PositiveNumber);
  app.add_option("--warmup", opt.warmup, "round trips discarded first")
      ->check(CLI::NonNegativeNumber);
  app.add_option("--domain", opt.domain, "DDS domain id")->check(CLI::Range(0, 232));
  app.add_option("--timeout", opt.timeout_s, "give up after this many seconds");
  CLI11_PARSE(app, argc, argv);
  try {
    return Run(opt);
  } catch (const std::exception& e) {
    std::fprintf(stderr, "dds_pingpong: error: %s\n", e.what());
    return 2;
  }
}
