// A rogue participant for the multi-process tests: it joins a running network and writes
// malformed contributions on deif/contribution. Every one of them must be rejected or
// dropped by every agent, and none may reach an estimate.
//
//   deif_rogue --domain D --count N --follow RUN_DIR
//
// It follows the run's progress from RUN_DIR/target.csv and aims every message at the step
// after the one the target last published (inside the agents' fusion window), and prints
// "sent <n> bad contributions" at the end.
#include <chrono>
#include <cmath>
#include <fstream>
#include <limits>
#include <string>
#include <thread>
#include <vector>

#include <CLI/CLI.hpp>

#include "dds/dds_common.hpp"
#include "deif.h"

namespace {

// The step of the last complete row of target.csv (0 when there is none).
long long CurrentStep(const std::string& run_dir) {
  std::ifstream in(run_dir + "/target.csv");
  std::string line, last;
  while (std::getline(in, line)) {
    if (!line.empty() && line[0] != 's') last = line;
  }
  return last.empty() ? 0 : std::stoll(last.substr(0, last.find(',')));
}

deif_msgs::Contribution Valid(int agent_id, long long step) {
  deif_msgs::Contribution c;
  c.agent_id(agent_id);
  c.step(step);
  c.info_x(1.0);
  c.info_y(2.0);
  c.info_xx(3.0);
  c.info_xy(0.5);
  c.info_yx(0.5);
  c.info_yy(4.0);
  return c;
}

}  // namespace

int main(int argc, char** argv) {
  CLI::App app{"Writes malformed contributions into a running network (test tool)."};
  int domain = 0;
  int count = 4;
  std::string run_dir;
  app.add_option("--domain", domain, "DDS domain of the run")->required();
  app.add_option("--count", count, "number of agents in the run (ids 1..count)");
  app.add_option("--follow", run_dir, "run folder whose target.csv tells the current step")->required();
  CLI11_PARSE(app, argc, argv);

  deif::NetworkConfig network;
  network.domain_id = domain;
  deif::dds::DdsParticipant participant(domain, network, "rogue");
  auto* writer = participant.CreateWriter(deif::dds::kContributionTopic,
                                          deif::dds::ContributionWriterQos(network));
  // Let discovery and matching settle so that every agent receives every sample.
  std::this_thread::sleep_for(std::chrono::milliseconds(2500));

  const double nan = std::numeric_limits<double>::quiet_NaN();
  const double inf = std::numeric_limits<double>::infinity();
  int sent = 0;
  auto send = [&](deif_msgs::Contribution c) {
    writer->write(&c);
    ++sent;
    // Paced, so that no keyed history (depth 8 per agent id) overwrites an unread sample.
    std::this_thread::sleep_for(std::chrono::milliseconds(40));
  };

  for (int round = 0; round < 3; ++round) {
    // Cycle the claimed id over the live agents and one that no agent has.
    const int live_id = 1 + round % count;
    const int unknown_id = count + 7;

    auto c = Valid(live_id, CurrentStep(run_dir) + 1);
    c.info_x(nan);
    send(c);  // non-finite i_j

    c = Valid(live_id, CurrentStep(run_dir) + 1);
    c.info_yy(inf);
    send(c);  // non-finite I_j

    c = Valid(live_id, CurrentStep(run_dir) + 1);
    c.info_xy(0.5);
    c.info_yx(-3.0);
    send(c);  // not symmetric

    c = Valid(live_id, CurrentStep(run_dir) + 1);
    c.info_xx(1.0);
    c.info_yy(1.0);
    c.info_xy(5.0);
    c.info_yx(5.0);
    send(c);  // symmetric but indefinite (eigenvalues 6 and -4)

    c = Valid(live_id, CurrentStep(run_dir) + 1);
    c.info_xx(1e300);
    send(c);  // absurd magnitude

    send(Valid(live_id, CurrentStep(run_dir) + 1000));   // a step far in the future
    send(Valid(live_id, CurrentStep(run_dir) - 1000));   // a stale step
    send(Valid(unknown_id, CurrentStep(run_dir) + 1));   // an id no configured agent has
    const long long next = CurrentStep(run_dir) + 1;
    send(Valid(live_id, next));  // a well-formed one under a live agent's id ...
    send(Valid(live_id, next));  // ... and its duplicate
  }
  std::printf("sent %d bad contributions\n", sent);
  std::fflush(stdout);
  std::this_thread::sleep_for(std::chrono::milliseconds(500));
  return 0;
}
