// The DDS floor of this stack: a ping-pong between two processes through dds::Node, with
// the project's own contribution message and QoS (reliable, keep last, MANUAL_BY_TOPIC
// liveliness) and the same WaitSet path the agents use, over one transport.
//
//   dds_pingpong --role pong --transport shm --domain 201 &
//   dds_pingpong --role ping --transport shm --domain 201 --samples 2000
//
// The ping writes a contribution as agent 1; the pong takes it and writes it back as agent
// 2; the ping measures the round trip with steady_clock and prints one JSON object.
#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <string>
#include <vector>

#include <CLI/CLI.hpp>

#include "bench/bench_sample.hpp"
#include "common/config/config.hpp"
#include "dds/node.hpp"

namespace {

using deif::dds::Clock;

struct Options {
  std::string role = "ping";
  std::string transport = "shm";
  int samples = 2000;
  int warmup = 200;
  int domain = 200;
  double timeout_s = 60.0;
};

deif::protocol::ContributionMsg Message(deif::AgentId id, long long step, const deif::Config& config) {
  return deif::bench::Contribution("pingpong", id, step, config);
}

double Percentile(std::vector<double> v, double p) {
  std::sort(v.begin(), v.end());
  const double last = static_cast<double>(v.size() - 1);
  const auto i = std::min(v.size() - 1, static_cast<std::size_t>(p / 100.0 * last + 0.5));
  return v[i];
}

int Run(const Options& opt) {
  deif::Config config;
  config.network.domain_id = opt.domain;
  config.network.transport = opt.transport == "shm" ? deif::TransportKind::kShm : deif::TransportKind::kUdp;
  config.agents.count = 2;
  deif::dds::Node node(config, "dds_pingpong_" + opt.role, "pingpong");
  node.AddWriter(deif::dds::Topic::kContribution);
  node.AddReader({deif::dds::Topic::kContribution, {}});
  node.StartLiveliness();
  const auto give_up = Clock::now() + std::chrono::duration_cast<Clock::duration>(
                                          std::chrono::duration<double>(opt.timeout_s));
  if (opt.role == "pong") {
    long echoed = 0;
    while (Clock::now() < give_up) {
      for (const auto& event : node.Wait(Clock::now() + std::chrono::milliseconds(200))) {
        const auto* c = std::get_if<deif::dds::Received<deif::protocol::ContributionMsg>>(&event);
        if (c == nullptr || c->msg.agent_id != 1) continue;
        if (c->msg.step < 0) {
          std::printf("{\"role\": \"pong\", \"transport\": \"%s\", \"echoed\": %ld}\n",
                      opt.transport.c_str(), echoed);
          return 0;
        }
        node.Write(Message(2, c->msg.step, config));
        ++echoed;
      }
    }
    return 1;
  }
  // ping: wait for the pong's writer, then measure
  while (node.MatchedWriters(deif::dds::Topic::kContribution) < 2 && Clock::now() < give_up) {
    node.Wait(Clock::now() + std::chrono::milliseconds(50));
  }
  std::vector<double> rtt_us;
  for (int i = 1; i <= opt.warmup + opt.samples && Clock::now() < give_up; ++i) {
    const auto t0 = Clock::now();
    node.Write(Message(1, i, config));
    bool back = false;
    while (!back && Clock::now() < give_up) {
      for (const auto& event : node.Wait(Clock::now() + std::chrono::milliseconds(500))) {
        const auto* c = std::get_if<deif::dds::Received<deif::protocol::ContributionMsg>>(&event);
        back = back || (c != nullptr && c->msg.agent_id == 2 && c->msg.step == i);
      }
    }
    if (i > opt.warmup) rtt_us.push_back(std::chrono::duration<double, std::micro>(Clock::now() - t0).count());
  }
  node.Write(Message(1, -1, config));
  node.WaitForAcknowledgments(1.0);
  if (rtt_us.empty()) return 1;
  std::printf("{\"role\": \"ping\", \"transport\": \"%s\", \"samples\": %zu, \"rtt_p50_us\": %.1f, "
              "\"rtt_p90_us\": %.1f, \"rtt_p99_us\": %.1f, \"rtt_max_us\": %.1f}\n",
              opt.transport.c_str(), rtt_us.size(), Percentile(rtt_us, 50), Percentile(rtt_us, 90),
              Percentile(rtt_us, 99), Percentile(rtt_us, 100));
  return 0;
}

}  // namespace

int main(int argc, char** argv) {
  CLI::App app{"DDS ping-pong through the project's DDS layer (benchmark floor)"};
  Options opt;
  app.add_option("--role", opt.role, "ping or pong")->check(CLI::IsMember({"ping", "pong"}));
  app.add_option("--transport", opt.transport, "shm or udp")->check(CLI::IsMember({"shm", "udp"}));
  app.add_option("--samples", opt.samples, "measured round trips (after the warm-up)");
  app.add_option("--warmup", opt.warmup, "round trips discarded first");
  app.add_option("--domain", opt.domain, "DDS domain id")->check(CLI::Range(0, 232));
  app.add_option("--timeout", opt.timeout_s, "give up after this many seconds");
  CLI11_PARSE(app, argc, argv);
  try {
    return Run(opt);
  } catch (const std::exception& e) {
    std::fprintf(stderr, "dds_pingpong: error: %s\n", e.what());
    return 1;
  }
}
