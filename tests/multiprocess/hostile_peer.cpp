// A hostile (or stray) participant for the multi-process tests: it joins a running
// network's DDS domain and sends what a misbehaving peer could (docs/ARCHITECTURE.md, "Peer
// data is untrusted"). Every test using it checks that the run completes unharmed and that
// each bad message was counted.
//
//   deif_hostile --config RUN/config.yaml --run NAME --attack KIND --follow RUN [--seconds S]
//
// KIND:
//   contributions  NaN, infinite, asymmetric, indefinite, huge, bad-basis, far-future,
//                  stale, unknown-id, impersonating and duplicate contributions, aimed at the
//                  step after the one the target last published (inside the fusion window)
//   truth          an end-of-run marker (step -1) and a step of 1e12 on deif/truth
//   ranges         ranges with variance 0, a 50 m range and a step of 1e12, for every agent
//   states         agent states for an id outside 1..count, and NaN positions
//   flood          contributions with unknown ids, as fast as it can, for --seconds
//   impersonate    well-formed contributions and states under the id --claim, for every step
//                  the target publishes during --seconds
//   listen         nothing: it only reads, for --seconds
// It prints "sent <n> <kind>" and "received <n>" (samples on every topic it could read) when
// done. --run "" joins no run partition (a stray process).
//
// DDS Security (docs/SECURITY.md): --name is the participant's name, which picks its files in
// the security folder; --security DIR uses the files in DIR, --security off joins without
// security, and without it the config decides. A writer or reader that its permissions refuse
// is reported as "refused <topic>"; an attack whose writer is refused exits 3. --linger keeps
// it in the domain after that until SIGTERM.
#include <chrono>
#include <csignal>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <fstream>
#include <limits>
#include <map>
#include <memory>
#include <string>
#include <thread>

#include <CLI/CLI.hpp>

#include "common/config/config.hpp"
#include "dds/node.hpp"

namespace {

using deif::protocol::ContributionMsg;

// The step of the last complete row of target.csv (0 when there is none).
long long CurrentStep(const std::string& run_dir) {
  std::ifstream in(run_dir + "/target.csv");
  std::string line, last;
  while (std::getline(in, line)) {
    if (!line.empty() && line[0] != 's') last = line;
  }
  return last.empty() ? 0 : std::stoll(last.substr(0, last.find(',')));
}

ContributionMsg Valid(const deif::Config& config, deif::protocol::RunToken run, int id, long long step) {
  ContributionMsg c;
  c.run = run;
  c.agent_id = id;
  c.instance_token = 0xbadbadbad;
  c.step = step;
  c.info_vector = deif::InfoVector(1.0, 2.0);
  c.info_matrix << 3.0, 0.5, 0.5, 4.0;
  c.p_sensor = deif::Vector2(1.0, 1.0);
  c.basis = deif::ToInfoState(deif::InitialState(config), deif::InitialCovariance(config));
  return c;
}

void Pause(int ms) { std::this_thread::sleep_for(std::chrono::milliseconds(ms)); }

volatile std::sig_atomic_t g_stop = 0;

// With --linger: stays (reading, so nothing backs up) until SIGTERM or SIGINT, so that a test
// decides when this participant leaves the domain.
void Linger(bool linger, deif::dds::Node& node) {
  if (!linger) return;
  std::signal(SIGTERM, [](int) { g_stop = 1; });
  std::signal(SIGINT, [](int) { g_stop = 1; });
  while (g_stop == 0) node.Wait(std::chrono::steady_clock::now() + std::chrono::milliseconds(50));
}

// Lingers if asked, then exits with `code`. The run goes on without this process, so it
// deletes its participant: a process that ends without it while one of Fast DDS's threads
// holds the lock of a shared-memory port leaves that lock held, and every peer's write to
// the port then waits 1 s per message for about 5 s (docs/FASTDDS_NOTES.md, "Leaving while the
// run goes on"; seen once in mp_hostile_truth: an agent's loop blocked for 6 s and it lost
// the run). Not a secure participant: deleting one can hang for good in Fast DDS 2.9.1
// (docs/FASTDDS_NOTES.md, "Security"), and a test waits for this process's exit status. The
// deletion is bounded as the agents' is (10 s).
[[noreturn]] void Leave(bool linger, std::unique_ptr<deif::dds::Node>& node, int code) {
  Linger(linger, *node);
  std::fflush(stdout);
  std::fflush(stderr);
  if (node->Secure()) {
    node->Abandon();
  } else {
    std::thread([code] {
      std::this_thread::sleep_for(std::chrono::seconds(10));
      std::fprintf(stderr, "deif_hostile: the participant was not deleted within 10 s; exiting without it\n");
      std::_Exit(code);
    }).detach();
    node.reset();
  }
  std::fflush(stdout);
  std::fflush(stderr);
  std::_Exit(code);
}

}  // namespace

int main(int argc, char** argv) {
  CLI::App app{"Sends what a misbehaving peer could into a running network (test tool)."};
  std::string config_path, run_name, attack, run_dir;
  double seconds = 10.0;
  std::string name = "hostile";
  std::string security;
  int claim = 1;
  int peers = -1;
  bool linger = false;
  app.add_option("--config", config_path, "the run's config.yaml")->required();
  app.add_option("--run", run_name, "the run's name (\"\": no run partition)")->required();
  app.add_option("--attack", attack, "contributions | truth | ranges | states | flood")->required();
  app.add_option("--follow", run_dir, "run folder whose target.csv tells the current step")->required();
  app.add_option("--seconds", seconds, "how long the flood, impersonation or listening lasts");
  app.add_option("--name", name, "participant name; with security it picks the files (agent-2, ...)");
  app.add_option("--security", security, "DIR: security with the files in DIR; off: none");
  app.add_option("--claim", claim, "the agent id an impersonation claims");
  app.add_option("--peers", peers, "how many live agents to wait for (default: agents.count)");
  app.add_flag("--linger", linger, "when done, stay in the domain until SIGTERM or SIGINT");
  CLI11_PARSE(app, argc, argv);

  deif::Config config = deif::LoadConfig(config_path);
  if (security == "off") {
    config.network.security.enabled = false;
  } else if (!security.empty()) {
    config.network.security.enabled = true;
    config.network.security.dir = security;
  }
  const auto run = deif::protocol::RunTokenOf(run_name);
  auto owned = std::make_unique<deif::dds::Node>(config, name, run_name.empty() ? "no-such-run" : run_name);
  deif::dds::Node& node = *owned;
  node.StopWriterSideFiltering();  // an attacker sends everything, whatever its peers filter
  using deif::dds::Topic;
  const auto topic_name = [](Topic t) {
    switch (t) {
      case Topic::kTruth: return "deif/truth";
      case Topic::kRange: return "deif/range";
      case Topic::kContribution: return "deif/contribution";
      case Topic::kAgentState: return "deif/agent_state";
      case Topic::kRelayUp: return "deif/relay_up";
      case Topic::kRelayDown: return "deif/relay_down";
    }
    return "?";
  };
  std::map<Topic, bool> can_write;
  std::map<Topic, bool> can_read;
  for (Topic t : {Topic::kContribution, Topic::kTruth, Topic::kRange, Topic::kAgentState}) {
    try {
      node.AddWriter(t);
      can_write[t] = true;
    } catch (const std::exception&) {  // refused by this participant's permissions
      std::printf("refused %s\n", topic_name(t));
      can_write[t] = false;
    }
    try {
      node.AddReader({t, {}});
      can_read[t] = true;
    } catch (const std::exception&) {
      std::printf("refused reading %s\n", topic_name(t));
    }
  }
  std::fflush(stdout);
  const std::map<std::string, Topic> needs = {
      {"contributions", Topic::kContribution}, {"truth", Topic::kTruth}, {"ranges", Topic::kRange},
      {"states", Topic::kAgentState}, {"flood", Topic::kContribution},
      {"impersonate", Topic::kContribution}};
  if (needs.count(attack) != 0 && !can_write[needs.at(attack)]) {
    std::printf("sent 0 %s\nreceived 0\n", attack.c_str());
    std::fflush(stdout);
    Leave(linger, owned, 3);
  }
  node.StartLiveliness();
  long received = 0;
  // Reads for `ms` milliseconds (Wait returns at the first batch of samples).
  const auto drain = [&](int ms) {
    const auto until = std::chrono::steady_clock::now() + std::chrono::milliseconds(ms);
    while (std::chrono::steady_clock::now() < until) {
      received += static_cast<long>(node.Wait(until).size());
    }
  };
  // Wait until this participant has discovered every agent (so every agent receives every
  // sample), then a little more for the agents to discover it.
  // (A node's counts include its own endpoints: its reader matches its own writer.)
  const int live_agents = peers >= 0 ? peers : config.agents.count;
  const auto give_up = std::chrono::steady_clock::now() + std::chrono::seconds(10);
  const int own_writer = can_write[Topic::kContribution] ? 1 : 0;
  while (node.MatchedWriters(deif::dds::Topic::kContribution) < live_agents + own_writer &&
         std::chrono::steady_clock::now() < give_up) {
    drain(20);
  }
  // ... and, for the topics every agent reads (ranges, contributions), until every agent's
  // reader matched this writer: on a loaded machine a fixed pause was not always enough.
  if (needs.count(attack) != 0 &&
      (needs.at(attack) == Topic::kRange || needs.at(attack) == Topic::kContribution)) {
    const int own_reader = can_read[needs.at(attack)] ? 1 : 0;
    while (node.MatchedReaders(needs.at(attack)) < live_agents + own_reader &&
           std::chrono::steady_clock::now() < give_up) {
      drain(20);
    }
    if (node.MatchedReaders(needs.at(attack)) < live_agents + own_reader) {
      std::fprintf(stderr, "deif_hostile: warning: not every agent's reader matched in 10 s\n");
    }
  }
  drain(300);

  const double nan = std::numeric_limits<double>::quiet_NaN();
  const double inf = std::numeric_limits<double>::infinity();
  const int count = config.agents.count;
  long sent = 0;
  const auto send = [&](const auto& msg, int pause_ms) {
    node.Write(msg);
    ++sent;
    if (pause_ms > 0) Pause(pause_ms);
  };

  if (attack == "contributions") {
    for (int round = 0; round < 3; ++round) {
      // The highest id first (the test kills that agent: its id is free to be claimed, so
      // the content checks apply), then ids of live agents (refused by identity).
      const int live_id = round == 0 ? count : round;
      const auto next = [&] { return CurrentStep(run_dir) + 1; };
      auto c = Valid(config, run, live_id, next());
      c.info_vector.x() = nan;
      send(c, 2);  // non-finite i_j
      c = Valid(config, run, live_id, next());
      c.info_matrix(1, 1) = inf;
      send(c, 2);  // non-finite I_j
      c = Valid(config, run, live_id, next());
      c.info_matrix(1, 0) = -3.0;
      send(c, 2);  // not symmetric
      c = Valid(config, run, live_id, next());
      c.info_matrix << 1.0, 5.0, 5.0, 1.0;
      send(c, 2);  // symmetric but indefinite (eigenvalues 6 and -4)
      c = Valid(config, run, live_id, next());
      c.info_matrix(0, 0) = 1e300;
      send(c, 2);  // absurd magnitude
      c = Valid(config, run, live_id, next());
      c.basis.Y(0, 0) = -1.0;
      send(c, 2);  // a basis that is not a valid information state
      send(Valid(config, run, live_id, next() + 1000), 2);  // a step far ahead
      send(Valid(config, run, live_id, next() - 1000), 2);  // a stale step
      send(Valid(config, run, count + 7, next()), 2);       // an id no agent has
      const long long step = next();
      send(Valid(config, run, live_id, step), 2);  // well formed, under a live agent's id ...
      send(Valid(config, run, live_id, step), 2);  // ... and again
    }
  } else if (attack == "truth") {
    deif::protocol::TruthMsg end;
    end.run = run;
    end.step = -1;
    send(end, 2);
    deif::protocol::TruthMsg far = end;
    far.step = static_cast<long long>(1e12);
    send(far, 2);
  } else if (attack == "ranges") {
    for (int id = 1; id <= count; ++id) {
      deif::protocol::RangeMsg r;
      r.run = run;
      r.agent_id = id;
      r.step = CurrentStep(run_dir) + 1;
      r.measured = true;
      r.range_m = 2.0;
      r.variance_m2 = 0.0;
      r.roll_call = {id};
      send(r, 2);  // variance 0
      r.variance_m2 = 5.3e-4;
      r.range_m = 50.0;
      send(r, 2);  // a 50 m range (from a writer that is not the run's target)
      r.step = static_cast<long long>(1e12);
      send(r, 2);  // a step beyond any run
    }
  } else if (attack == "states") {
    deif::protocol::StateMsg s;
    s.run = run;
    s.agent_id = count + 95;  // an id outside 1..count
    s.step = CurrentStep(run_dir);
    s.instance_token = 0xbadbadbad;
    send(s, 2);
    s.agent_id = 1;
    s.position_m = deif::Vector2(nan, 0.0);
    send(s, 2);  // a NaN position under a live id
  } else if (attack == "flood") {
    const auto end = std::chrono::steady_clock::now() + std::chrono::duration_cast<std::chrono::steady_clock::duration>(
                                                            std::chrono::duration<double>(seconds));
    long long i = 0;
    long long step = CurrentStep(run_dir) + 1;
    while (std::chrono::steady_clock::now() < end) {
      send(Valid(config, run, count + 1, step), 0);  // one unknown id (one DDS instance)
      ++i;
      if (i % 1000 == 0) step = CurrentStep(run_dir) + 1;
    }
  } else if (attack == "impersonate") {
    const auto end = std::chrono::steady_clock::now() +
                     std::chrono::duration_cast<std::chrono::steady_clock::duration>(
                         std::chrono::duration<double>(seconds));
    while (std::chrono::steady_clock::now() < end) {  // every 10 ms, for the next step
      const long long step = CurrentStep(run_dir) + 1;
      send(Valid(config, run, claim, step), 0);
      deif::protocol::StateMsg s;
      s.run = run;
      s.agent_id = claim;
      s.step = step - 1;
      s.instance_token = 0xbadbadbad;
      s.position_m = deif::Vector2(0.5, 0.5);
      send(s, 0);
      // Reads for the whole 10 ms (Wait returns at the first sample): a steady stream, not a
      // flood (that is --attack flood).
      const auto next = std::chrono::steady_clock::now() + std::chrono::milliseconds(10);
      while (std::chrono::steady_clock::now() < next) {
        received += static_cast<long>(node.Wait(next).size());
      }
    }
  } else if (attack == "listen") {
    const auto end = std::chrono::steady_clock::now() +
                     std::chrono::duration_cast<std::chrono::steady_clock::duration>(
                         std::chrono::duration<double>(seconds));
    while (std::chrono::steady_clock::now() < end) drain(50);
  } else {
    std::fprintf(stderr, "deif_hostile: error: unknown --attack '%s'\n", attack.c_str());
    return 2;
  }
  std::printf("sent %ld %s\n", sent, attack.c_str());
  if (!run_dir.empty()) std::printf("done at step %lld\n", CurrentStep(run_dir));
  std::fflush(stdout);
  // Every matched reader acknowledges what was sent (a lost sample is repaired first; a
  // reader of a killed agent never acknowledges, hence the bound), then a little more reading.
  if (!node.WaitForAcknowledgments(3.0)) {
    std::fprintf(stderr, "deif_hostile: note: not every sample was acknowledged in 3 s\n");
  }
  drain(200);
  std::printf("received %ld\n", received);
  std::fflush(stdout);
  Leave(linger, owned, 0);
}
