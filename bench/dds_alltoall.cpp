// The DDS floor of an all-to-all exchange: N processes, each writes one contribution per
// round through dds::Node (the project's message, QoS, content filter and WaitSet path, the
// timings the network of N agents uses) and starts the next round once it holds the
// round's contribution of every other process. It is the contribution exchange of a
// lock-step without the range before it, the state after it, or any maths: what every
// agent hearing every other once per step costs on this host (docs/BENCHMARKS.md, "The
// floor"). No protocol where each agent receives N - 1 samples a step runs faster.
//
//   for j in 1 2 3 4; do dds_alltoall --id $j --peers 4 --domain 202 & done; wait
//
// Each process prints one JSON object: its rounds per second over the measured rounds
// (after the warm-up) and the CPU it used over them (getrusage). Like an agent, it ends
// without a goodbye and leaves its /dev/shm/fastrtps_* files (scripts/deif-bench removes
// them).
#include <sys/resource.h>

#include <algorithm>
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <map>
#include <string>

#include <CLI/CLI.hpp>

#include "bench/bench_sample.hpp"
#include "common/config/config.hpp"
#include "dds/node.hpp"

namespace {

using deif::dds::Clock;

struct Options {
  int id = 1;
  int peers = 4;
  std::string transport = "shm";
  long rounds = 1000;
  long warmup = 50;
  int domain = 202;
  double timeout_s = 120.0;
};

double CpuSeconds() {
  rusage u{};
  getrusage(RUSAGE_SELF, &u);
  return static_cast<double>(u.ru_utime.tv_sec + u.ru_stime.tv_sec) +
         1e-6 * static_cast<double>(u.ru_utime.tv_usec + u.ru_stime.tv_usec);
}

deif::protocol::ContributionMsg Message(deif::AgentId id, long long round, const deif::Config& config) {
  return deif::bench::Contribution("alltoall", id, round, config);
}

int Run(const Options& opt) {
  deif::Config config;
  config.network.domain_id = opt.domain;
  config.network.transport = opt.transport == "shm" ? deif::TransportKind::kShm : deif::TransportKind::kUdp;
  config.agents.count = opt.peers;
  const auto me = static_cast<deif::AgentId>(opt.id);
  deif::dds::Node node(config, "dds_alltoall_" + std::to_string(opt.id), "alltoall");
  node.AddWriter(deif::dds::Topic::kContribution);
  node.AddReader({deif::dds::Topic::kContribution, {},
                  std::make_pair(deif::AgentId{1}, static_cast<deif::AgentId>(opt.peers))});
  node.StartLiveliness();
  const auto give_up = Clock::now() + std::chrono::duration_cast<Clock::duration>(
                                          std::chrono::duration<double>(opt.timeout_s));
  // Every writer matched to this reader, and every reader to this writer (own included).
  while ((node.MatchedWriters(deif::dds::Topic::kContribution) < opt.peers ||
          node.MatchedReaders(deif::dds::Topic::kContribution) < opt.peers) &&
         Clock::now() < give_up) {
    node.Wait(Clock::now() + std::chrono::milliseconds(50));
  }
  std::map<int, long long> newest;  // peer id -> newest round received from it
  const long last = opt.warmup + opt.rounds;
  Clock::time_point t0{};
  double cpu0 = 0.0;
  for (long r = 1; r <= last; ++r) {
    if (r == opt.warmup + 1) {
      t0 = Clock::now();
      cpu0 = CpuSeconds();
    }
    node.Write(Message(me, r, config));
    auto resend = Clock::now() + std::chrono::seconds(1);
    auto complete = [&] {
      if (static_cast<int>(newest.size()) < opt.peers - 1) return false;
      return std::all_of(newest.begin(), newest.end(), [&](const auto& p) { return p.second >= r; });
    };
    while (!complete()) {
      if (Clock::now() >= give_up) {
        std::fprintf(stderr, "dds_alltoall %d: gave up in round %ld (%zu peers heard)\n", opt.id, r,
                     newest.size());
        return 1;
      }
      if (Clock::now() >= resend) {  // a peer that matched us late missed the round: again
        node.Write(Message(me, r, config));
        resend = Clock::now() + std::chrono::seconds(1);
      }
      for (const auto& event : node.Wait(std::min(resend, give_up))) {
        const auto* c = std::get_if<deif::dds::Received<deif::protocol::ContributionMsg>>(&event);
        if (c == nullptr || c->msg.agent_id == me) continue;
        long long& n = newest[static_cast<int>(c->msg.agent_id)];
        n = std::max(n, static_cast<long long>(c->msg.step));
      }
    }
  }
  const double wall_s = std::chrono::duration<double>(Clock::now() - t0).count();
  const double cpu_s = CpuSeconds() - cpu0;
  // The last round's sample must reach the peers still waiting for it.
  node.WaitForAcknowledgments(5.0);
  std::printf("{\"id\": %d, \"peers\": %d, \"transport\": \"%s\", \"rounds\": %ld, "
              "\"rounds_per_s\": %.2f, \"cpu_s\": %.4f, \"wall_s\": %.4f}\n",
              opt.id, opt.peers, opt.transport.c_str(), opt.rounds, static_cast<double>(opt.rounds) / wall_s,
              cpu_s, wall_s);
  std::fflush(stdout);
  // Leave without a goodbye, as the agents do at the end of a run: 64 participants saying
  // goodbye at once aborted one in Fast DDS 2.9.1 (PDP.cpp:1140; docs/FASTDDS_NOTES.md).
  // The shared-memory files stay behind; scripts/deif-bench removes them.
  node.Abandon();
  std::_Exit(0);
}

}  // namespace

int main(int argc, char** argv) {
  CLI::App app{"All-to-all exchange of N processes through the project's DDS layer (benchmark floor)"};
  Options opt;
  app.add_option("--id", opt.id, "this process's id, 1..peers")->check(CLI::Range(1, 1024));
  app.add_option("--peers", opt.peers, "how many processes exchange")->check(CLI::Range(2, 1024));
  app.add_option("--transport", opt.transport, "shm or udp")->check(CLI::IsMember({"shm", "udp"}));
  app.add_option("--rounds", opt.rounds, "measured rounds (after the warm-up)")->check(CLI::Range(1L, 10000000L));
  app.add_option("--warmup", opt.warmup, "rounds discarded first")->check(CLI::Range(0L, 1000000L));
  app.add_option("--domain", opt.domain, "DDS domain id")->check(CLI::Range(0, 232));
  app.add_option("--timeout", opt.timeout_s, "give up after this many seconds");
  CLI11_PARSE(app, argc, argv);
  if (opt.id > opt.peers) {
    std::fprintf(stderr, "dds_alltoall: error: --id %d is not in 1..--peers %d\n", opt.id, opt.peers);
    return 2;
  }
  try {
    return Run(opt);
  } catch (const std::exception& e) {
    std::fprintf(stderr, "dds_alltoall: error: %s\n", e.what());
    return 1;
  }
}
