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
// --relay-group S measures a relayed exchange instead (docs/BENCHMARKS.md, "A relayed
// exchange"): the processes form groups of S consecutive ids; each hears only its group's
// contributions directly (a partition per group), and the group's lowest id, once it holds
// the round's contribution of every member, writes one sample for the whole group that
// every process reads. A round then costs N (S - 1) + G (N - 1) deliveries for G groups,
// instead of N (N - 1). The group's sample is a deif/truth (40 bytes): a real batch of S
// contributions would be about S x 250 bytes, which over shared memory costs a copy, not a
// delivery more.
//
// --tree F measures the exchange along a tree instead: process i's parent is
// (i - 2) / F + 1 (process 1 is the root). Each process waits for the round's sample of
// each of its children, then writes one to its parent (a partition per parent); the root,
// once it holds its children's, writes one down to them, and each process passes it on to
// its own children (a partition per parent). 2 (N - 1) deliveries a round, over about
// 2 log_F N hops in a row. The up samples are contributions, the down ones deif/truth: a
// real one would carry the subtree's contributions, up to N x 250 bytes.
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
#include <vector>

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
  int relay_group = 0;  // 0: all to all
  int tree = 0;         // fan-out of the tree exchange; 0: none
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

void Report(const Options& opt, Clock::time_point t0, double cpu0) {
  const double wall_s = std::chrono::duration<double>(Clock::now() - t0).count();
  const double cpu_s = CpuSeconds() - cpu0;
  std::printf("{\"id\": %d, \"peers\": %d, \"transport\": \"%s\", \"relay_group\": %d, \"tree\": %d, \"rounds\": %ld, "
              "\"rounds_per_s\": %.2f, \"cpu_s\": %.4f, \"wall_s\": %.4f}\n",
              opt.id, opt.peers, opt.transport.c_str(), opt.relay_group, opt.tree, opt.rounds,
              static_cast<double>(opt.rounds) / wall_s, cpu_s, wall_s);
  std::fflush(stdout);
}

// The relayed exchange (--relay-group): see the top of this file.
int RunRelayed(const Options& opt, deif::Config& config) {
  using deif::dds::Topic;
  const int size = opt.relay_group;
  const int group = (opt.id - 1) / size;
  const int groups = (opt.peers + size - 1) / size;
  const auto lo = static_cast<deif::AgentId>(group * size + 1);
  const auto hi = static_cast<deif::AgentId>(std::min(opt.peers, (group + 1) * size));
  const int members = static_cast<int>(hi - lo + 1);
  const auto me = static_cast<deif::AgentId>(opt.id);
  const bool leader = me == lo;
  deif::dds::Node node(config, "dds_alltoall_" + std::to_string(opt.id), "alltoall");
  node.SetSubPartition(Topic::kContribution, "group." + std::to_string(group));
  node.AddWriter(Topic::kContribution);
  node.AddReader({Topic::kContribution, {}, std::make_pair(lo, hi)});
  node.AddWriter(Topic::kTruth);
  node.AddReader({Topic::kTruth, {}});
  node.StartLiveliness();
  const auto give_up = Clock::now() + std::chrono::duration_cast<Clock::duration>(
                                          std::chrono::duration<double>(opt.timeout_s));
  while ((node.MatchedWriters(Topic::kContribution) < members ||
          node.MatchedReaders(Topic::kContribution) < members || node.MatchedWriters(Topic::kTruth) < opt.peers ||
          node.MatchedReaders(Topic::kTruth) < opt.peers) &&
         Clock::now() < give_up) {
    node.Wait(Clock::now() + std::chrono::milliseconds(50));
  }
  const auto run = deif::protocol::RunTokenOf("alltoall");
  const auto batch = [&](long long r) {
    deif::protocol::TruthMsg m;
    m.run = run;
    m.step = r;
    m.p_true.x() = group;
    return m;
  };
  std::map<int, long long> mates;    // group mate id -> newest round heard
  std::map<int, long long> batches;  // other group -> newest round relayed
  const long last = opt.warmup + opt.rounds;
  Clock::time_point t0{};
  double cpu0 = 0.0;
  for (long r = 1; r <= last; ++r) {
    if (r == opt.warmup + 1) {
      t0 = Clock::now();
      cpu0 = CpuSeconds();
    }
    node.Write(Message(me, r, config));
    bool relayed = false;
    auto resend = Clock::now() + std::chrono::seconds(1);
    const auto heard = [r](const std::map<int, long long>& newest, int want) {
      return static_cast<int>(newest.size()) >= want &&
             std::all_of(newest.begin(), newest.end(), [r](const auto& p) { return p.second >= r; });
    };
    while (true) {
      const bool group_done = heard(mates, members - 1);
      if (leader && group_done && !relayed) {
        node.Write(batch(r));
        relayed = true;
      }
      if (group_done && heard(batches, groups - 1)) break;
      if (Clock::now() >= give_up) {
        std::fprintf(stderr, "dds_alltoall %d: gave up in round %ld (%zu mates, %zu groups heard)\n", opt.id, r,
                     mates.size(), batches.size());
        return 1;
      }
      if (Clock::now() >= resend) {  // a peer that matched us late missed the round: again
        node.Write(Message(me, r, config));
        if (relayed) node.Write(batch(r));
        resend = Clock::now() + std::chrono::seconds(1);
      }
      for (const auto& event : node.Wait(std::min(resend, give_up))) {
        if (const auto* c = std::get_if<deif::dds::Received<deif::protocol::ContributionMsg>>(&event)) {
          if (c->msg.agent_id == me) continue;
          long long& n = mates[static_cast<int>(c->msg.agent_id)];
          n = std::max(n, static_cast<long long>(c->msg.step));
        } else if (const auto* b = std::get_if<deif::dds::Received<deif::protocol::TruthMsg>>(&event)) {
          const int from = static_cast<int>(b->msg.p_true.x());
          if (from == group || b->msg.run != run) continue;
          long long& n = batches[from];
          n = std::max(n, static_cast<long long>(b->msg.step));
        }
      }
    }
  }
  Report(opt, t0, cpu0);
  node.WaitForAcknowledgments(5.0);
  node.Abandon();
  std::_Exit(0);
}

// The tree exchange (--tree): see the top of this file.
int RunTree(const Options& opt, deif::Config& config) {
  using deif::dds::Topic;
  const int f = opt.tree;
  const int me = opt.id;
  const int parent = me == 1 ? 0 : (me - 2) / f + 1;
  std::vector<int> children;
  for (int c = f * (me - 1) + 2; c <= std::min(opt.peers, f * (me - 1) + f + 1); ++c) children.push_back(c);
  deif::dds::Node node(config, "dds_alltoall_" + std::to_string(me), "alltoall");
  node.SetSubPartitions(Topic::kContribution, "up." + std::to_string(parent), "up." + std::to_string(me));
  node.SetSubPartitions(Topic::kTruth, "down." + std::to_string(me), "down." + std::to_string(parent));
  node.AddWriter(Topic::kContribution);
  node.AddReader({Topic::kContribution, {}, std::make_pair(deif::AgentId{1}, static_cast<deif::AgentId>(opt.peers))});
  node.AddWriter(Topic::kTruth);
  node.AddReader({Topic::kTruth, {}});
  node.StartLiveliness();
  const int kids = static_cast<int>(children.size());
  const int up = parent == 0 ? 0 : 1;
  const auto give_up = Clock::now() + std::chrono::duration_cast<Clock::duration>(
                                          std::chrono::duration<double>(opt.timeout_s));
  while ((node.MatchedWriters(Topic::kContribution) < kids || node.MatchedReaders(Topic::kContribution) < up ||
          node.MatchedWriters(Topic::kTruth) < up || node.MatchedReaders(Topic::kTruth) < kids) &&
         Clock::now() < give_up) {
    node.Wait(Clock::now() + std::chrono::milliseconds(50));
  }
  const auto run = deif::protocol::RunTokenOf("alltoall");
  const auto down = [&](long long r) {
    deif::protocol::TruthMsg m;
    m.run = run;
    m.step = r;
    return m;
  };
  std::map<int, long long> from_children;  // child id -> newest round heard
  long long from_parent = 0;
  const long last = opt.warmup + opt.rounds;
  Clock::time_point t0{};
  double cpu0 = 0.0;
  for (long r = 1; r <= last; ++r) {
    if (r == opt.warmup + 1) {
      t0 = Clock::now();
      cpu0 = CpuSeconds();
    }
    bool sent_up = false, sent_down = false;
    auto resend = Clock::now() + std::chrono::seconds(1);
    while (true) {
      const bool subtree = static_cast<int>(from_children.size()) >= kids &&
                           std::all_of(from_children.begin(), from_children.end(),
                                       [r](const auto& p) { return p.second >= r; });
      if (subtree && !sent_up) {
        if (parent != 0) node.Write(Message(static_cast<deif::AgentId>(me), r, config));
        sent_up = true;
      }
      if (sent_up && (parent == 0 || from_parent >= r) && !sent_down) {
        if (kids > 0) node.Write(down(r));
        sent_down = true;
      }
      if (sent_down) break;
      if (Clock::now() >= give_up) {
        std::fprintf(stderr, "dds_alltoall %d: gave up in round %ld (%zu children heard)\n", me, r,
                     from_children.size());
        return 1;
      }
      if (Clock::now() >= resend) {
        if (sent_up && parent != 0) node.Write(Message(static_cast<deif::AgentId>(me), r, config));
        resend = Clock::now() + std::chrono::seconds(1);
      }
      for (const auto& event : node.Wait(std::min(resend, give_up))) {
        if (const auto* c = std::get_if<deif::dds::Received<deif::protocol::ContributionMsg>>(&event)) {
          long long& n = from_children[static_cast<int>(c->msg.agent_id)];
          n = std::max(n, static_cast<long long>(c->msg.step));
        } else if (const auto* b = std::get_if<deif::dds::Received<deif::protocol::TruthMsg>>(&event)) {
          if (b->msg.run == run) from_parent = std::max(from_parent, static_cast<long long>(b->msg.step));
        }
      }
    }
  }
  Report(opt, t0, cpu0);
  node.WaitForAcknowledgments(5.0);
  node.Abandon();
  std::_Exit(0);
}

int Run(const Options& opt) {
  deif::Config config;
  config.network.domain_id = opt.domain;
  config.network.transport = opt.transport == "shm" ? deif::TransportKind::kShm : deif::TransportKind::kUdp;
  config.agents.count = opt.peers;
  if (opt.relay_group > 0) return RunRelayed(opt, config);
  if (opt.tree > 0) return RunTree(opt, config);
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
  Report(opt, t0, cpu0);
  // The last round's sample must reach the peers still waiting for it.
  node.WaitForAcknowledgments(5.0);
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
  auto* relay = app.add_option("--relay-group", opt.relay_group,
                 "0: all to all; S: groups of S ids, each relayed to all by its lowest id")
      ->check(CLI::Range(0, 1024));
  app.add_option("--tree", opt.tree, "0: all to all; F: along a tree of fan-out F")
      ->check(CLI::Range(0, 1024))
      ->excludes(relay);
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
