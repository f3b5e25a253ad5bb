// The liveliness, heartbeat and announcement timings the DDS adapter derives from the config
// and the number of agents (dds/node.hpp, EffectiveTimings; docs/BENCHMARKS.md, "Liveliness
// at large N", "Heartbeats at large N" and "Participant announcements at large N").
#include <catch2/catch.hpp>

#include <string>

#include "common/config/config.hpp"
#include "dds/node.hpp"

namespace {

deif::Config WithAgents(int n, int assertions_per_lease = 8) {
  return deif::ParseConfig("agents: {count: " + std::to_string(n) +
                               "}\n"
                               "network: {liveliness_lease_s: 0.4, liveliness_assertions_per_lease: " +
                               std::to_string(assertions_per_lease) + ", heartbeat_period_s: 0.005}\n",
                           "timings");
}

}  // namespace

TEST_CASE("few agents keep the configured timings", "[dds][timings]") {
  // 4 agents: 20 writer-reader pairs; 8 assertions per 0.4 s are 400 messages/s.
  const deif::dds::Timings t = deif::dds::EffectiveTimings(WithAgents(4));
  CHECK(t.liveliness_lease_s == Approx(0.4));
  CHECK(t.assertions_per_lease == 8);
  CHECK(t.heartbeat_period_s == Approx(0.005));
}

TEST_CASE("16 agents: fewer assertions, the same lease", "[dds][timings]") {
  // 272 pairs: the 4000 messages/s budget affords 5.9 assertions per 0.4 s.
  const deif::dds::Timings t = deif::dds::EffectiveTimings(WithAgents(16));
  CHECK(t.liveliness_lease_s == Approx(0.4));
  CHECK(t.assertions_per_lease == 5);
  CHECK(t.heartbeat_period_s == Approx(272.0 / 20000.0));
}

TEST_CASE("64 agents: the lease grows so that two assertions fit in it", "[dds][timings]") {
  // 4160 pairs: two assertions per lease within 4000 messages/s need a lease of 2.08 s. One
  // assertion per lease (a 1.04 s lease) made about 60 false losses at every start-up.
  const deif::dds::Timings t = deif::dds::EffectiveTimings(WithAgents(64));
  CHECK(t.liveliness_lease_s == Approx(2.08));
  CHECK(t.assertions_per_lease == 2);
  CHECK(t.heartbeat_period_s == Approx(0.208));
}

TEST_CASE("one assertion per lease stays one when configured so", "[dds][timings]") {
  const deif::dds::Timings t = deif::dds::EffectiveTimings(WithAgents(64, 1));
  CHECK(t.liveliness_lease_s == Approx(1.04));
  CHECK(t.assertions_per_lease == 1);
}

TEST_CASE("at every N the assertions stay within the budget and at least two per lease",
          "[dds][timings]") {
  for (int n = 2; n <= 256; ++n) {
    const deif::dds::Timings t = deif::dds::EffectiveTimings(WithAgents(n));
    const double pairs = static_cast<double>(n) * (n + 1);
    INFO("N = " << n);
    CHECK(t.assertions_per_lease >= 2);
    CHECK(t.assertions_per_lease <= 8);
    CHECK(t.liveliness_lease_s >= 0.4);
    CHECK(t.assertions_per_lease * pairs / t.liveliness_lease_s <= 4000.0 * (1 + 1e-9));
  }
}

TEST_CASE("a peer's lapse is held until four renewals in a row went missing, in a tree",
          "[dds][timings]") {
  // All to all (4 agents, or chosen) the contribution writers write every step: the
  // configured grace. In a tree they only assert: 32 agents renew every 0.264 s (a lease of
  // 0.528 s, two renewals), so five and a half renewal periods of silence (half a period
  // past the fifth renewal's time, so that a loss never falls on a renewal's arrival) need a
  // grace of 0.924 s; 64 agents renew every 1.04 s, 5.72 s of silence.
  CHECK(deif::dds::EffectiveTimings(WithAgents(4)).peer_grace_s == Approx(0.2));
  CHECK(deif::dds::EffectiveTimings(WithAgents(32)).peer_grace_s == Approx(5.5 * 0.264 - 0.528));
  CHECK(deif::dds::EffectiveTimings(WithAgents(64)).peer_grace_s == Approx(5.5 * 1.04 - 2.08));
  deif::Config all = WithAgents(64);
  all.network.exchange = deif::ExchangeKind::kAllToAll;
  CHECK(deif::dds::EffectiveTimings(all).peer_grace_s == Approx(0.2));
  for (int n = 2; n <= 256; ++n) {
    const deif::Config config = WithAgents(n);
    const deif::dds::Timings t = deif::dds::EffectiveTimings(config);
    INFO("N = " << n);
    CHECK(t.peer_grace_s >= config.network.liveliness_grace_s);
    if (deif::EffectiveExchange(config) == deif::ExchangeKind::kTree) {
      const double renewal_s = t.liveliness_lease_s / t.assertions_per_lease;
      CHECK(t.liveliness_lease_s + t.peer_grace_s >= 5.5 * renewal_s * (1 - 1e-9));
    }
  }
}

TEST_CASE("participant announcements: the configured period up to a budget, then longer with "
          "a lease as many periods long", "[dds][timings]") {
  // The defaults: an announcement every 0.5 s, a lease of 5 s (10 periods). 16 agents: 272
  // pairs, 544 announcements a second, within the 2000 a second budget.
  const deif::dds::Timings few = deif::dds::EffectiveTimings(WithAgents(16));
  CHECK(few.participant_announcement_s == Approx(0.5));
  CHECK(few.participant_lease_s == Approx(5.0));
  // 64 agents: 4160 pairs; 2000 a second allow one every 2.08 s, and the lease is 10 of them.
  const deif::dds::Timings many = deif::dds::EffectiveTimings(WithAgents(64));
  CHECK(many.participant_announcement_s == Approx(2.08));
  CHECK(many.participant_lease_s == Approx(20.8));
  for (int n = 2; n <= 256; ++n) {
    const deif::dds::Timings t = deif::dds::EffectiveTimings(WithAgents(n));
    const double pairs = static_cast<double>(n) * (n + 1);
    INFO("N = " << n);
    CHECK(t.participant_announcement_s >= 0.5);
    CHECK(pairs / t.participant_announcement_s <= 2000.0 * (1 + 1e-9));
    CHECK(t.participant_lease_s == Approx(10.0 * t.participant_announcement_s));
  }
}

TEST_CASE("a stalled secure participant waits longer in a larger network and at each restart",
          "[dds][security]") {
  // 0.2 s per process (agents and the target) and restart: 16 agents spread their first
  // restarts over 3.4 s, their second over 6.8 s.
  CHECK(deif::dds::RestartWindowS(1, 16) == Approx(3.4));
  CHECK(deif::dds::RestartWindowS(2, 16) == Approx(6.8));
  CHECK(deif::dds::RestartWindowS(1, 4) == Approx(1.0));
  CHECK(deif::dds::RestartWindowS(1, 64) == Approx(13.0));
  CHECK(deif::dds::RestartWindowS(5, 64) == Approx(20.0));  // capped
  CHECK(deif::dds::RestartWindowS(0, 0) == Approx(0.4));    // never a zero window
}

TEST_CASE("writers' heartbeats: the budget, and sooner repairs in real time where readers are few",
          "[dds][timings]") {
  using deif::dds::Topic;
  using deif::dds::WriterHeartbeatS;
  deif::Config c = WithAgents(64);  // budgeted: 4160 pairs within 20 000 a second, 0.208 s
  c.network.transport = deif::TransportKind::kUdp;
  // Lock-step: the budget for every writer.
  for (Topic topic : deif::dds::kAllTopics) CHECK(WriterHeartbeatS(topic, c, true) == Approx(0.208));
  c.scenario.mode = deif::StepMode::kRealTime;
  // Real time: relays (at most fan-out readers each) and the target's writer of one agent's
  // ranges over UDPv4 at 2 N / 20 000 s; the agents' states, all read by the target, at
  // N / 2000 s; the rest at the budget.
  CHECK(WriterHeartbeatS(Topic::kRelayUp, c) == Approx(0.0064));
  CHECK(WriterHeartbeatS(Topic::kRelayDown, c) == Approx(0.0064));
  CHECK(WriterHeartbeatS(Topic::kRange, c, /*per_agent_writer=*/true) == Approx(0.0064));
  CHECK(WriterHeartbeatS(Topic::kRange, c, /*per_agent_writer=*/false) == Approx(0.208));
  CHECK(WriterHeartbeatS(Topic::kAgentState, c) == Approx(0.032));
  CHECK(WriterHeartbeatS(Topic::kContribution, c) == Approx(0.208));
  CHECK(WriterHeartbeatS(Topic::kTruth, c) == Approx(0.208));
  // Over shared memory nothing is lost in transit: ranges and states keep the budget.
  c.network.transport = deif::TransportKind::kShm;
  CHECK(WriterHeartbeatS(Topic::kRange, c, true) == Approx(0.208));
  CHECK(WriterHeartbeatS(Topic::kAgentState, c) == Approx(0.208));
  CHECK(WriterHeartbeatS(Topic::kRelayDown, c) == Approx(0.0064));
  // Never shorter than configured: 4 agents keep the configured 5 ms.
  deif::Config few = WithAgents(4);
  few.network.transport = deif::TransportKind::kUdp;
  few.scenario.mode = deif::StepMode::kRealTime;
  for (Topic topic : deif::dds::kAllTopics) CHECK(WriterHeartbeatS(topic, few, true) == Approx(0.005));
}
