// The agent's step protocol, driven through a scripted network (scripted_network.hpp): which
// contributions it waits for, fuses, fuses late, drops or rejects, and how agents that
// missed information come back into exact agreement.
#include <catch2/catch.hpp>

#include <algorithm>
#include <cmath>
#include <deque>
#include <limits>
#include <optional>
#include <string>
#include <variant>
#include <vector>

#include "common/protocol/validation.hpp"
#include "tests/protocol/scripted_network.hpp"

using deif::AgentId;
using deif::InfoState;
using deif::StepIndex;
using deif::Vector2;
using deif::testing::Envelope;
using deif::testing::KeyOf;
using deif::testing::ScriptedNetwork;
namespace protocol = deif::protocol;

namespace {

constexpr const char* kThreeAgents =
    "scenario: {steps: 30, dt_s: 0.1}\n"
    "agents: {count: 3}\n"
    "network: {history_steps: 8, step_timeout_s: 0.5}\n";

// Real time at 10 Hz; an agent's deadline is 0.05 s after its range.
constexpr const char* kThreeAgentsRealTime =
    "scenario: {steps: 20, mode: realtime, period_s: 0.1}\n"
    "agents: {count: 3}\n"
    "network: {history_steps: 8, deadline_fraction: 0.5}\n";

bool IsContribution(const Envelope& e, AgentId from, AgentId to, StepIndex step) {
  const auto* c = std::get_if<protocol::ContributionMsg>(&e.message);
  return c != nullptr && e.from == from && e.to == to && c->step == step;
}

bool IsRangeToAgent1(const Envelope& e) {
  return e.to == 1 && std::holds_alternative<protocol::RangeMsg>(e.message);
}

bool SameBits(const InfoState& a, const InfoState& b) { return a.y == b.y && a.Y == b.Y; }

// Every live agent's posterior of step k is bit-identical to agent `reference`'s.
bool AllAgreeAt(ScriptedNetwork& net, StepIndex k, AgentId reference = 1) {
  const auto ref = net.agents.at(reference)->PosteriorOf(k);
  if (!ref) return false;
  for (auto& [id, agent] : net.agents) {
    if (net.dead.count(id) > 0) continue;
    const auto p = agent->PosteriorOf(k);
    if (!p || !SameBits(*p, *ref)) return false;
  }
  return true;
}

protocol::ContributionMsg ValidContributionFrom(ScriptedNetwork& net, AgentId id, StepIndex step) {
  for (const auto& c : net.ContributionsOf(id)) {
    if (c.step == step) return c;
  }
  FAIL("agent " << id << " published no contribution for step " << step);
  return {};
}

// Starts the network and runs it until the other agents' contributions to agent 1 (at least
// two) are held in net.held, undelivered.
void HoldContributionsToAgent1(ScriptedNetwork& net) {
  net.Start();
  const auto to1 = [](const Envelope& e) {
    return e.to == 1 && std::holds_alternative<protocol::ContributionMsg>(e.message);
  };
  for (int i = 0; i < 100 && net.held.size() < 2; ++i) {
    net.Pump(to1);
    net.AdvanceTime(0.01);
  }
  REQUIRE(net.held.size() >= 2);
}

}  // namespace

TEST_CASE("In lock-step every agent fuses the whole roll call and all hold bit-identical estimates",
          "[protocol]") {
  // GIVEN three agents on a perfect network
  ScriptedNetwork net(kThreeAgents);
  net.Start();
  // WHEN the run goes to its end
  net.RunUntil(30);
  // THEN every agent wrote every step, each with all three contributions, complete
  for (AgentId id = 1; id <= 3; ++id) {
    const auto& rows = net.rows.at(id);
    REQUIRE(rows.size() == 30);
    for (std::size_t i = 0; i < rows.size(); ++i) {
      CHECK(rows[i].step == static_cast<StepIndex>(i + 1));
      CHECK(rows[i].fused == 3);
      CHECK(rows[i].complete);
    }
    CHECK(net.exit_codes.at(id) == protocol::kExitOk);
  }
  // AND the three estimates are bit-identical at every step
  for (std::size_t i = 0; i < 30; ++i) {
    CHECK(net.rows.at(1)[i].estimate_m == net.rows.at(2)[i].estimate_m);
    CHECK(net.rows.at(1)[i].estimate_m == net.rows.at(3)[i].estimate_m);
  }
  net.Pump();  // the last states reach the target
  CHECK(net.exit_codes.at(deif::testing::kTarget) == protocol::kExitOk);
}

TEST_CASE("A measured agent contributes (i, I) of eqs (4.49)-(4.51) at its own prediction",
          "[protocol]") {
  ScriptedNetwork net(kThreeAgents);
  net.Start();
  net.RunUntil(1);
  const protocol::ContributionMsg c = ValidContributionFrom(net, 2, 1);
  // Recompute it by hand from the common prior and the range the target published.
  const deif::Config& config = net.config;
  const InfoState prior = deif::Predict(
      config.filter.motion_model, deif::ToInfoState(deif::InitialState(config),
                                                    deif::InitialCovariance(config)));
  const deif::Eif filter(config.filter.motion_model, prior);
  deif::RangeObservation z;
  for (const auto& r : net.ranges) {
    if (r.step == 1 && r.agent_id == 2) {
      z.agent_id = 2;
      z.range_m = r.range_m;
      z.variance_m2 = r.variance_m2;
      z.p_sensor = r.p_sensor;
    }
  }
  const deif::Contribution expected =
      deif::ComputeContribution(1, z, filter.PositionEstimate(), config.sensing);
  CHECK(c.info_vector == expected.info_vector);
  CHECK(c.info_matrix == expected.info_matrix);
  CHECK(c.p_sensor == z.p_sensor);
  // The posterior it was linearised on: the common prior of step 0.
  CHECK(SameBits(c.basis, deif::ToInfoState(deif::InitialState(config), deif::InitialCovariance(config))));
}

TEST_CASE("In lock-step an agent waits for a roll-call member's delayed contribution", "[protocol]") {
  ScriptedNetwork net(kThreeAgents);
  net.Start();
  net.RunUntil(1);
  // GIVEN agent 3's contribution of step 2 to agent 1 is delayed
  net.Pump([](const Envelope& e) { return IsContribution(e, 3, 1, 2); });
  // THEN agent 1 has not written step 2 yet (it waits, within the step timeout)
  CHECK(net.agents.at(1)->last_written_step() == 1);
  CHECK(net.agents.at(2)->last_written_step() == 2);
  // WHEN it arrives
  net.ReleaseHeld();
  net.RunUntil(2);
  // THEN agent 1 writes step 2 with all three, identical to the others
  CHECK(net.rows.at(1)[1].fused == 3);
  CHECK(net.rows.at(1)[1].complete);
  CHECK(AllAgreeAt(net, 2));
}

TEST_CASE("A contribution that comes after its step was written is fused into its step and the "
          "agents agree again bit for bit",
          "[protocol]") {
  ScriptedNetwork net(kThreeAgents);
  net.Start();
  net.RunUntil(2);
  // GIVEN agent 3's contribution of step 3 to agent 1 is held back beyond the step timeout
  const auto late = [](const Envelope& e) { return IsContribution(e, 3, 1, 3); };
  net.RunUntil(3, late);  // time moves on while agent 1 waits, up to its step timeout
  REQUIRE(net.agents.at(1)->last_written_step() >= 3);
  CHECK(net.rows.at(1)[2].fused == 2);  // step 3 written without it
  CHECK_FALSE(net.rows.at(1)[2].complete);
  CHECK(net.agents.at(1)->counters().deadline_misses == 1);
  CHECK_FALSE(AllAgreeAt(net, 3));
  // WHEN it finally arrives, a few steps later
  net.RunUntil(6, late);
  net.ReleaseHeld();
  net.RunUntil(7);
  // THEN it is fused into step 3, and every later posterior equals the other agents'
  CHECK(net.agents.at(1)->counters().late == 1);
  for (StepIndex k = 3; k <= 7; ++k) CHECK(AllAgreeAt(net, k));
}

TEST_CASE("A step that leaves the history incomplete leads to one merge after which every "
          "agent agrees",
          "[protocol]") {
  ScriptedNetwork net(kThreeAgents);
  net.Start();
  net.RunUntil(2);
  // GIVEN agent 3's contribution of step 3 never reaches agent 1
  const auto lose = [](const Envelope& e) { return IsContribution(e, 3, 1, 3); };
  // WHEN the run goes on past the history (8 steps)
  net.RunUntil(20, lose);
  // THEN agent 1 asked for a merge, every agent merged once, and all agree afterwards
  for (AgentId id = 1; id <= 3; ++id) CHECK(net.agents.at(id)->counters().merges == 1);
  // The merged step's contributions carry two distinct posteriors (agent 1's, which lacks
  // agent 3's contribution of step 3, and the others'): the covariance intersection is
  // computed again only when the set of distinct posteriors grew, so at most twice per agent,
  // however the contributions come.
  for (AgentId id = 1; id <= 3; ++id) {
    CHECK(net.agents.at(id)->merges_computed() >= 1);
    CHECK(net.agents.at(id)->merges_computed() <= 2);
  }
  CHECK(AllAgreeAt(net, 20));
  CHECK(net.rows.at(1).back().estimate_m == net.rows.at(2).back().estimate_m);
  CHECK(net.rows.at(3).back().estimate_m == net.rows.at(2).back().estimate_m);
}

TEST_CASE("A duplicate contribution is dropped, counted and changes nothing", "[protocol]") {
  ScriptedNetwork net(kThreeAgents);
  net.Start();
  net.RunUntil(3);
  const auto before = *net.agents.at(1)->PosteriorOf(3);
  const protocol::ContributionMsg c = ValidContributionFrom(net, 2, 3);
  net.agents.at(1)->OnContribution(c, KeyOf(2), net.now);
  CHECK(net.agents.at(1)->counters().dropped == 1);
  CHECK(SameBits(*net.agents.at(1)->PosteriorOf(3), before));
}

TEST_CASE("Peer data is validated before it can touch an estimate", "[protocol][validation]") {
  ScriptedNetwork net(kThreeAgents);
  net.Start();
  net.RunUntil(3);
  protocol::AgentProtocol& agent = *net.agents.at(1);
  const InfoState before = *agent.PosteriorOf(3);
  const protocol::ContributionMsg good = ValidContributionFrom(net, 2, 3);
  std::int64_t rejected = agent.counters().rejected;
  const auto expect_rejected = [&](protocol::ContributionMsg bad, const deif::testing::SenderKey& from,
                                   const std::string& reason) {
    agent.OnContribution(bad, from, net.now);
    CHECK(agent.counters().rejected == ++rejected);
    CHECK(agent.counters().by_reason.count("rejected: " + reason) == 1);
    CHECK(SameBits(*agent.PosteriorOf(3), before));
  };
  auto c = good;
  c.step = 4;  // aimed at the next step, inside the window
  c.info_vector.x() = std::numeric_limits<double>::quiet_NaN();
  expect_rejected(c, KeyOf(2), "non_finite");
  c = good;
  c.step = 4;
  c.info_matrix(0, 1) += 1.0;
  expect_rejected(c, KeyOf(2), "not_symmetric");
  c = good;
  c.step = 4;
  c.info_matrix << -1.0, 0.0, 0.0, 1.0;
  expect_rejected(c, KeyOf(2), "not_psd");
  c = good;
  c.step = 4;
  c.basis.Y(0, 0) = -5.0;
  expect_rejected(c, KeyOf(2), "bad_basis");
  c = good;
  c.run = 7;  // another run on the same domain
  expect_rejected(c, KeyOf(2), "other_run");
  c = good;
  c.agent_id = 99;
  expect_rejected(c, KeyOf(9), "unknown_agent_id");
  c = good;
  c.agent_id = 1;  // our own id, from someone else
  expect_rejected(c, KeyOf(9), "agent_id_clash");
  c = good;
  c.step = 4;  // a second live writer claiming agent 2
  expect_rejected(c, KeyOf(9), "agent_id_clash");
  c = good;
  c.step = 1000000;
  expect_rejected(c, KeyOf(2), "step_outside_run");
  // The run goes on unharmed.
  net.RunUntil(6);
  CHECK(AllAgreeAt(net, 6));
}

TEST_CASE("A contribution from an agent that is not in the step's roll call is not fused",
          "[protocol][validation]") {
  ScriptedNetwork net(
      "scenario: {steps: 30}\n"
      "agents: {count: 3}\n"
      "network: {history_steps: 8, step_timeout_s: 0.5, start_timeout_s: 1}\n");
  // GIVEN agent 3 never comes up, so the target starts with 1 and 2 after its start timeout
  const auto silent3 = [](const Envelope& e) { return e.from == 3 || e.to == 3; };
  net.dead.insert(3);
  net.Start();
  net.RunUntil(2, silent3);
  CHECK(net.rows.at(1)[0].fused == 2);
  // WHEN a contribution claiming to be agent 3's for step 3 arrives (a replay)
  protocol::ContributionMsg forged = ValidContributionFrom(net, 2, 2);
  forged.agent_id = 3;
  forged.step = 3;
  net.agents.at(1)->OnContribution(forged, KeyOf(3), net.now);
  net.RunUntil(3, silent3);
  // THEN it is rejected as not in the roll call, and step 3 fuses 1 and 2 only
  CHECK(net.agents.at(1)->counters().by_reason.count("rejected: not_in_roll_call") == 1);
  CHECK(net.rows.at(1)[2].fused == 2);
  CHECK(AllAgreeAt(net, 3));
}

TEST_CASE("Ranges are validated: zero variance, a step beyond the run, a second live target",
          "[protocol][validation]") {
  ScriptedNetwork net(kThreeAgents);
  net.Start();
  net.RunUntil(2);
  protocol::AgentProtocol& agent = *net.agents.at(1);
  const std::int64_t rejected = agent.counters().rejected;
  protocol::RangeMsg range;
  range.run = ScriptedNetwork::kRun;
  range.agent_id = 1;
  range.step = 3;
  range.measured = true;
  range.range_m = 2.0;
  range.variance_m2 = 0.0;
  range.p_sensor = net.rows.at(1).back().position_m;
  range.roll_call = {1, 2, 3};
  agent.OnRange(range, KeyOf(0), net.now);
  CHECK(agent.counters().by_reason.count("rejected: variance_out_of_bounds") == 1);
  range.variance_m2 = 5.3e-4;
  range.step = static_cast<StepIndex>(1e12);
  agent.OnRange(range, KeyOf(0), net.now);
  CHECK(agent.counters().by_reason.count("rejected: step_outside_run") == 1);
  range.step = 3;
  agent.OnRange(range, KeyOf(50), net.now);  // another writer while the target lives
  net.Liveliness(1, 0, true);
  agent.OnRange(range, KeyOf(51), net.now);
  CHECK(agent.counters().by_reason.count("rejected: second_target") >= 1);
  CHECK(agent.counters().rejected >= rejected + 3);
  net.RunUntil(5);
  CHECK(AllAgreeAt(net, 5));
}

TEST_CASE("An agent that hears a restarted target before it sees the old one lost uses the new "
          "target's ranges once it does; a stray writer's are never used", "[protocol]") {
  for (const bool stray : {false, true}) {
    CAPTURE(stray);
    ScriptedNetwork net(kThreeAgents);
    net.Start();
    net.RunUntil(2);
    // GIVEN agent 1 (just resumed from a freeze) still believes the first target alive,
    // and its range of step 3 comes from another writer: the target's next incarnation
    net.Pump(IsRangeToAgent1);
    REQUIRE(net.held.size() == 1);
    const auto range = std::get<protocol::RangeMsg>(net.held.front().message);
    net.held.clear();
    protocol::AgentProtocol& agent = *net.agents.at(1);
    const deif::protocol::SenderKey next = KeyOf(deif::testing::kTarget, 1);
    agent.OnRange(range, next, net.now);
    // THEN it is refused for now, and step 3 stays closed
    CHECK(agent.counters().by_reason.count("rejected: second_target") == 1);
    net.AdvanceTime(0.01);
    CHECK(agent.last_written_step() == 2);
    CHECK(net.ContributionsOf(1).back().step == 2);
    if (stray) {  // the other writer leaves first: a stray, whose ranges are dropped
      agent.OnWriterLiveliness(next, false, net.now);
      net.AdvanceTime(net.config.network.liveliness_grace_s + 0.01);
    }
    // WHEN agent 1 sees the first target lost (past the liveliness grace)
    net.Liveliness(1, deif::testing::kTarget, false);
    net.AdvanceTime(net.config.network.liveliness_grace_s + 0.01);
    const auto contributed3 = [&net] {
      const auto sent = net.ContributionsOf(1);
      return std::any_of(sent.begin(), sent.end(),
                         [](const protocol::ContributionMsg& c) { return c.step == 3; });
    };
    if (stray) {
      // THEN nothing of the stray's is used
      CHECK_FALSE(contributed3());
      continue;
    }
    // THEN it takes the held range as the restarted target's, contributes to step 3, and
    // the run goes on with the new incarnation in exact agreement
    CHECK(contributed3());
    net.Liveliness(2, deif::testing::kTarget, false);  // the others see the old one go too
    net.Liveliness(3, deif::testing::kTarget, false);
    net.incarnation[deif::testing::kTarget] = 1;
    net.AdvanceTime(net.config.network.liveliness_grace_s + 0.01);
    net.RunUntil(6);
    for (StepIndex k = 1; k <= 6; ++k) CHECK(AllAgreeAt(net, k));
    CHECK(net.rows.at(1)[2].fused == 3);
  }
}

TEST_CASE("A range far from the prediction fails the innovation gate and carries no information",
          "[protocol][validation]") {
  ScriptedNetwork net(kThreeAgents);
  net.Start();
  net.RunUntil(3);
  // GIVEN the target's range for agent 2 at step 4 is replaced by one 50 m long
  net.Pump([](const Envelope& e) {
    const auto* r = std::get_if<protocol::RangeMsg>(&e.message);
    return r != nullptr && r->agent_id == 2 && r->step == 4;
  });
  REQUIRE(net.held.size() == 1);
  auto& range = std::get<protocol::RangeMsg>(net.held.front().message);
  range.range_m = 50.0;
  net.ReleaseHeld();
  net.RunUntil(4);
  // THEN agent 2's contribution of step 4 is empty and nobody's estimate jumps
  const protocol::ContributionMsg c = ValidContributionFrom(net, 2, 4);
  CHECK(c.info_matrix.isZero(0.0));
  CHECK(c.info_vector.isZero(0.0));
  CHECK(net.rows.at(1)[3].complete);  // nobody waited for it
  CHECK(AllAgreeAt(net, 4));
  CHECK((net.rows.at(1)[3].estimate_m - net.truth[3].p_true).norm() < 0.5);
}

TEST_CASE("The innovation gate relents after five of an agent's own ranges in a row failed it",
          "[protocol][validation]") {
  ScriptedNetwork net(kThreeAgents);
  net.Start();
  net.RunUntil(3);
  // GIVEN agent 2's ranges of steps 4 to 10 are each 50 m long (the estimate says about 2 m)
  for (StepIndex k = 4; k <= 10; ++k) {
    net.Pump([k](const Envelope& e) {
      const auto* r = std::get_if<protocol::RangeMsg>(&e.message);
      return r != nullptr && r->agent_id == 2 && r->step == k;
    });
    REQUIRE(net.held.size() == 1);
    std::get<protocol::RangeMsg>(net.held.front().message).range_m = 50.0;
    net.ReleaseHeld();
    net.RunUntil(k);
  }
  // THEN its contributions of steps 4 to 8 are empty, those of 9 and 10 carry the range
  for (StepIndex k = 4; k <= 8; ++k) {
    INFO("step " << k);
    CHECK(ValidContributionFrom(net, 2, k).info_matrix.isZero(0.0));
  }
  for (StepIndex k = 9; k <= 10; ++k) {
    INFO("step " << k);
    CHECK_FALSE(ValidContributionFrom(net, 2, k).info_matrix.isZero(0.0));
  }
  CHECK(net.agents.at(2)->counters().by_reason.at("gated: own range failed the innovation gate") == 5);
  for (StepIndex k = 4; k <= 10; ++k) CHECK(AllAgreeAt(net, k));  // the owner decides: all fuse the same
}

TEST_CASE("A member that dies after its contribution reached only some peers leads to one merge "
          "at the next step, long before the step leaves the history",
          "[protocol]") {
  ScriptedNetwork net(kThreeAgents);
  net.Start();
  net.RunUntil(2);
  // GIVEN agent 3's contribution of step 3 reaches agent 2 but not agent 1, and agent 3 dies
  net.Pump([](const Envelope& e) { return IsContribution(e, 3, 1, 3); });
  net.AdvanceTime(0.1);
  net.Kill(3);
  net.Pump();
  // WHEN the run goes on (8 steps of history; 30 steps)
  net.RunUntil(30);
  // THEN agents 1 and 2 wrote step 3 with different sets and estimates; agent 1's next
  // contribution asked for a merge, both merged once, at step 4, and their estimates are
  // identical from step 4 to the end (waiting for step 3 to leave the history would have
  // kept them apart until step 11)
  const auto& rows1 = net.rows.at(1);
  const auto& rows2 = net.rows.at(2);
  REQUIRE(rows1.size() == 30);
  REQUIRE(rows2.size() == 30);
  CHECK(rows1[2].fused == 2);
  CHECK(rows2[2].fused == 3);
  CHECK(rows1[2].estimate_m != rows2[2].estimate_m);
  CHECK(net.agents.at(1)->counters().merges == 1);
  CHECK(net.agents.at(2)->counters().merges == 1);
  for (std::size_t i = 3; i < 30; ++i) {
    INFO("step " << i + 1);
    CHECK(rows1[i].estimate_m == rows2[i].estimate_m);
  }
}

TEST_CASE("In real time, a member that dies after its contribution reached only some peers, and "
          "is seen lost after they wrote the step, leads to one merge long before the step "
          "leaves the history",
          "[protocol]") {
  ScriptedNetwork net(kThreeAgentsRealTime);
  net.Start();
  net.Pump();
  REQUIRE(net.agents.at(1)->last_written_step() == 1);
  // GIVEN agent 3's contribution of step 2 reaches agent 2 but not agent 1, which writes
  // step 2 at its deadline without it, and then agent 3 dies (seen lost later, by its
  // liveliness)
  net.AdvanceTime(0.1);
  net.Pump([](const Envelope& e) { return IsContribution(e, 3, 1, 2); });
  net.AdvanceTime(0.06);
  REQUIRE(net.agents.at(1)->last_written_step() == 2);
  net.Kill(3);
  net.held.clear();  // died with it
  // WHEN the run goes on (8 steps of history; 20 steps)
  net.RunUntil(20);
  // THEN agents 1 and 2 wrote step 2 with different sets; once agent 3 was lost, agent 1's
  // next contribution asked for a merge, both merged once, and they are identical from
  // step 5 on (waiting for step 2 to leave the history kept them apart until step 11)
  const auto& rows1 = net.rows.at(1);
  const auto& rows2 = net.rows.at(2);
  REQUIRE(rows1.size() == 20);
  REQUIRE(rows2.size() == 20);
  CHECK(rows1[1].fused == 2);
  CHECK(rows2[1].fused == 3);
  CHECK(net.agents.at(1)->counters().merges == 1);
  CHECK(net.agents.at(2)->counters().merges == 1);
  for (std::size_t i = 4; i < 20; ++i) {
    INFO("step " << i + 1);
    CHECK(rows1[i].estimate_m == rows2[i].estimate_m);
  }
}

TEST_CASE("A lost member is not waited for in lock-step", "[protocol]") {
  ScriptedNetwork net(kThreeAgents);
  net.Start();
  net.RunUntil(2);
  // GIVEN agent 3 dies after the target measured it at step 3: its contribution never comes
  const auto from3 = [](const Envelope& e) {
    const auto* c = std::get_if<protocol::ContributionMsg>(&e.message);
    return e.from == 3 && c != nullptr && c->step >= 3;
  };
  net.Pump(from3);
  CHECK(net.agents.at(1)->last_written_step() == 2);  // waiting for it
  // WHEN agents 1 and 2 see it lost, during the step, and it stays silent for the grace
  net.AdvanceTime(0.1);
  net.Liveliness(1, 3, false);
  net.Liveliness(2, 3, false);
  net.AdvanceTime(net.config.network.liveliness_grace_s);  // 0.3 s: before the step timeout
  // THEN agents 1 and 2 wrote step 3 then, with two contributions
  REQUIRE(net.agents.at(1)->last_written_step() >= 3);
  CHECK(net.rows.at(1)[2].fused == 2);
  CHECK(net.rows.at(1)[2].alive == 2);
}

TEST_CASE("A liveliness lapse shorter than network.liveliness_grace_s excludes nobody: the "
          "member is waited for and fused", "[protocol]") {
  ScriptedNetwork net(kThreeAgents);
  net.Start();
  net.RunUntil(2);
  // GIVEN agent 3's contribution to step 3 is delayed, and agent 1 sees its liveliness lapse
  const auto from3 = [](const Envelope& e) {
    const auto* c = std::get_if<protocol::ContributionMsg>(&e.message);
    return e.from == 3 && c != nullptr && c->step == 3;
  };
  net.Pump(from3);
  net.Liveliness(1, 3, false);
  net.AdvanceTime(0.5 * net.config.network.liveliness_grace_s);
  // WHEN the lapse ends within the grace, and the contribution arrives
  net.Liveliness(1, 3, true);
  net.AdvanceTime(net.config.network.liveliness_grace_s);  // past the lapse's grace
  CHECK(net.agents.at(1)->last_written_step() == 2);  // still waiting for agent 3
  net.ReleaseHeld();
  net.RunUntil(5);
  // THEN agent 1 fused all three at step 3, never excluded agent 3, and agrees with the others
  CHECK(net.rows.at(1)[2].fused == 3);
  CHECK(net.rows.at(1)[2].alive == 3);
  CHECK(net.agents.at(1)->Members().size() == 3);
  CHECK(net.agents.at(1)->lapses_forgiven() == 1);  // counted for the run's summary
  CHECK(net.agents.at(2)->lapses_forgiven() == 0);
  for (StepIndex k = 1; k <= 5; ++k) CHECK(AllAgreeAt(net, k));
  const auto& log = net.logs.at(1);
  CHECK(std::none_of(log.begin(), log.end(),
                     [](const std::string& l) { return l.find("lost") != std::string::npos; }));
}

TEST_CASE("A peer's lapse is held for peer_grace_s, the target's for network.liveliness_grace_s",
          "[protocol]") {
  // Where the peers' writers renew their liveliness rarely (the tree exchange at large N),
  // the agent holds their lapses longer (dds::Timings::peer_grace_s); the target's writer
  // writes every step and keeps the configured grace.
  ScriptedNetwork net(kThreeAgents);
  const double grace_s = net.config.network.liveliness_grace_s;
  net.SetPeerGrace(4.0 * grace_s);
  net.Start();
  net.RunUntil(2);
  const auto has = [&](const std::string& text) {
    const auto& log = net.logs.at(1);
    return std::any_of(log.begin(), log.end(), [&](const std::string& l) { return l.find(text) != std::string::npos; });
  };
  // WHEN agent 1 sees agent 3's writer and the target's lapse at once
  net.Liveliness(1, 3, false);
  net.Liveliness(1, deif::testing::kTarget, false);
  net.AdvanceTime(1.5 * grace_s);
  // THEN the target's lapse counts after the configured grace, agent 3's not yet
  CHECK(has("the target is lost"));
  CHECK(net.agents.at(1)->Members().size() == 3);
  CHECK_FALSE(has("agent 3 lost"));
  // AND agent 3's counts once it outlasts peer_grace_s
  net.AdvanceTime(3.0 * grace_s);
  CHECK(net.agents.at(1)->Members().size() == 2);
  CHECK(has("agent 3 lost (liveliness)"));
}

TEST_CASE("A peer lost by its liveliness and back at once makes the agent hold lapses longer",
          "[protocol]") {
  // A lossy link drops several renewals of a live peer in a row now and then: the loss is
  // undone by the next renewal. The agent then holds every lapse twice as long, so the same
  // gap in the renewals is forgiven next time (docs/PROTOCOL.md, "Losses that are undone").
  ScriptedNetwork net(kThreeAgents);
  const double grace_s = net.config.network.liveliness_grace_s;
  net.Start();
  net.RunUntil(2);
  const auto count = [&](const std::string& text) {
    const auto& log = net.logs.at(1);
    return std::count_if(log.begin(), log.end(), [&](const std::string& l) { return l.find(text) != std::string::npos; });
  };
  // WHEN agent 3's renewals stop reaching agent 1 for a little longer than the grace
  net.Liveliness(1, 3, false);
  net.AdvanceTime(1.1 * grace_s);
  CHECK(count("agent 3 lost (liveliness)") == 1);
  net.Liveliness(1, 3, true);  // the next renewal
  // THEN the loss is undone, said once, with the longer grace
  CHECK(net.agents.at(1)->Members().size() == 3);
  CHECK(count("agent 3, taken for lost by its liveliness, is back: the network loses renewals, so a lapse is "
              "now held for 2 x the grace") == 1);
  CHECK(net.agents.at(1)->losses_undone() == 1);
  // AND the same gap again is forgiven: no loss, nothing written without agent 3
  net.Liveliness(1, 3, false);
  net.AdvanceTime(1.1 * grace_s);
  net.Liveliness(1, 3, true);
  CHECK(count("agent 3 lost (liveliness)") == 1);
  CHECK(net.agents.at(1)->lapses_forgiven() == 1);
  // AND a peer that stays silent is still lost, after twice the grace
  net.Liveliness(1, 2, false);
  net.AdvanceTime(1.5 * grace_s);
  CHECK(net.agents.at(1)->Members().count(2) == 1);
  net.AdvanceTime(0.6 * grace_s);
  CHECK(net.agents.at(1)->Members().count(2) == 0);
}

TEST_CASE("A held lapse of a peer the target's roll call no longer names counts at once",
          "[protocol]") {
  // The longer peer grace spares a peer the rest of the network still hears; a peer the
  // target dropped too (its state writer renews at every step) is gone.
  ScriptedNetwork net(kThreeAgents);
  const double grace_s = net.config.network.liveliness_grace_s;
  net.SetPeerGrace(20.0 * grace_s);
  net.Start();
  net.RunUntil(3);
  const double killed_at = net.now;
  // WHEN agent 3 is killed: everyone sees its writers lapse
  net.Kill(3);
  net.RunUntil(8);
  // THEN agents 1 and 2 lost it well before the peer grace, once a roll call left it out
  for (AgentId id : {1, 2}) {
    INFO("agent " << id);
    CHECK(net.agents.at(id)->Members().size() == 2);
    const auto& log = net.logs.at(id);
    CHECK(std::any_of(log.begin(), log.end(),
                      [](const std::string& l) { return l.find("agent 3 lost (liveliness)") != std::string::npos; }));
  }
  CHECK(net.now - killed_at < net.peer_grace_s);
  // AND a peer the target still names keeps its lapse held for the whole peer grace
  net.Liveliness(1, 2, false);
  net.RunUntil(12);
  CHECK(net.agents.at(1)->Members().count(2) == 1);
}

TEST_CASE("An agent whose process ended is lost at once, without the grace, for the target and its "
          "peers", "[protocol]") {
  // docs/PROTOCOL.md, "A process that ended": the kernel released its ports' locks; a slow
  // process keeps them, so there is nothing to wait for.
  ScriptedNetwork net(kThreeAgents);
  const double grace_s = net.config.network.liveliness_grace_s;
  net.SetPeerGrace(20.0 * grace_s);
  net.Start();
  net.RunUntil(3);
  const double killed_at = net.now;
  // WHEN agent 3 is killed and no lapse is seen yet, but everyone learns its process ended
  net.Kill(3, /*lapse=*/false);
  // (a process that is not a member changes nothing)
  net.ProcessEnded(1, 9);
  CHECK(net.agents.at(1)->Members().size() == 3);
  for (int reader : {deif::testing::kTarget, 1, 2}) net.ProcessEnded(reader, 3);
  net.RunUntil(8);
  // THEN the run went on with agents 1 and 2 before any grace could have passed
  CHECK(net.now - killed_at < grace_s);
  CHECK(net.target->AliveAgents() == std::set<AgentId>{1, 2});
  for (AgentId id : {1, 2}) {
    INFO("agent " << id);
    CHECK(net.agents.at(id)->Members().size() == 2);
    const auto& log = net.logs.at(id);
    CHECK(std::any_of(log.begin(), log.end(), [](const std::string& l) {
      return l.find("agent 3 lost (its process ended") != std::string::npos;
    }));
    CHECK(net.rows.at(id).back().complete);
  }
  for (StepIndex k = 4; k <= 8; ++k) CHECK(AllAgreeAt(net, k));
}

TEST_CASE("A peer that leaves after its contribution to the last step is logged as finished, "
          "not lost", "[protocol]") {
  ScriptedNetwork net(kThreeAgents);  // 30 steps
  net.Start();
  // GIVEN agent 3 is behind at the last step (its range is held back), and agent 2's
  // contribution to the last step has not reached it
  const auto held = [](const Envelope& e) {
    const auto* r = std::get_if<protocol::RangeMsg>(&e.message);
    return (e.to == 3 && r != nullptr && r->step == 30) || IsContribution(e, 2, 3, 30);
  };
  for (int i = 0; i < 10000 && !(net.agents.at(1)->finished() && net.agents.at(2)->finished()); ++i) {
    net.Pump(held);
    net.AdvanceTime(0.01);
  }
  REQUIRE(net.agents.at(1)->finished());
  REQUIRE(net.agents.at(2)->finished());
  REQUIRE(net.agents.at(3)->last_written_step() == 29);
  REQUIRE_FALSE(net.agents.at(3)->finished());
  // WHEN agents 1 and 2 leave
  net.Liveliness(3, 1, false);
  net.Liveliness(3, 2, false);
  net.AdvanceTime(net.config.network.liveliness_grace_s);
  // THEN agent 1, whose last contribution arrived, left; agent 2, whose did not, is lost
  const auto& log = net.logs.at(3);
  const auto has = [&](const std::string& text) {
    return std::any_of(log.begin(), log.end(), [&](const std::string& l) { return l.find(text) != std::string::npos; });
  };
  CHECK(has("agent 1 left after the last step"));
  CHECK_FALSE(has("agent 1 lost"));
  CHECK(has("agent 2 lost (liveliness)"));
}

TEST_CASE("An agent that joins mid-run adopts the lowest-id contributor's posterior and agrees",
          "[protocol]") {
  ScriptedNetwork net(kThreeAgents);
  net.Start();
  net.RunUntil(4);
  // GIVEN agent 3 is killed and a new process takes its place a few steps later
  net.Kill(3);
  net.RunUntil(7);
  net.dead.erase(3);
  net.incarnation[3] = 1;
  net.agents[3] = net.MakeAgent(3, /*token=*/99);
  net.agents.at(3)->Start(net.now);
  net.AdvanceTime(0.0);
  net.RunUntil(12);
  // THEN it adopted a posterior once and, from its first step on, agrees bit for bit
  CHECK(net.agents.at(3)->counters().adoptions == 1);
  const auto& rows = net.rows.at(3);
  REQUIRE(rows.size() > 4);  // its old rows 1..4, then the new process's
  const StepIndex first_back = rows[4].step;
  CHECK(first_back >= 8);
  for (StepIndex k = first_back; k <= 12; ++k) CHECK(AllAgreeAt(net, k));
  CHECK(net.rows.at(1).back().fused == 3);  // and it is measured again
}

TEST_CASE("A member frozen for fewer steps than the history catches up exactly", "[protocol]") {
  ScriptedNetwork net(kThreeAgents);
  net.Start();
  net.RunUntil(3);
  // GIVEN agent 3 is frozen: nothing reaches it, it sends nothing, the others see it lost
  const auto frozen = net.Freeze(3);
  net.RunUntil(8, frozen);
  CHECK(net.agents.at(3)->last_written_step() == 3);
  // WHEN it resumes and its backlog arrives
  net.frozen.erase(3);
  net.ReleaseHeld();
  net.RunUntil(8);
  // THEN it caught up without adopting anything, and agrees with the others bit for bit
  CHECK(net.agents.at(3)->counters().adoptions == 0);
  CHECK(net.agents.at(3)->last_written_step() >= 8);
  for (StepIndex k = 4; k <= 8; ++k) {
    INFO("step " << k);
    CHECK(AllAgreeAt(net, k));
  }
}

TEST_CASE("In real time a step is written at its deadline with what arrived, and a step without "
          "a range on the clock",
          "[protocol]") {
  ScriptedNetwork net(kThreeAgentsRealTime);
  net.Start();
  net.Pump();
  // The target published step 1 at t = 0; everything arrives at once: complete.
  CHECK(net.agents.at(1)->last_written_step() == 1);
  // GIVEN agent 3's contribution of step 2 to agent 1 is late
  net.AdvanceTime(0.1);
  net.Pump([](const Envelope& e) { return IsContribution(e, 3, 1, 2); });
  CHECK(net.agents.at(1)->last_written_step() == 1);  // before its deadline it waits
  net.AdvanceTime(0.06);                              // past the deadline (0.05 s)
  CHECK(net.agents.at(1)->last_written_step() == 2);
  CHECK(net.agents.at(1)->counters().deadline_misses == 1);
  // AND GIVEN the target's range for agent 1 at step 3 never comes in time
  net.AdvanceTime(0.04);  // t = 0.2: step 3 is published
  net.Pump([](const Envelope& e) {
    const auto* r = std::get_if<protocol::RangeMsg>(&e.message);
    return (r != nullptr && r->agent_id == 1 && r->step == 3) || IsContribution(e, 3, 1, 2);
  });
  net.AdvanceTime(0.06);
  // THEN step 3 is written on the clock anyway
  CHECK(net.agents.at(1)->last_written_step() == 3);
  // AND when the late messages come, they are fused into their steps: the agents agree
  net.ReleaseHeld();
  net.Pump();
  net.AdvanceTime(0.1);
  net.Pump();
  CHECK(net.agents.at(1)->counters().late >= 1);
  CHECK(AllAgreeAt(net, 3));
}

TEST_CASE("In real time an agent that resumes writes the steps it slept through with what its sockets held, "
          "not on the clock before reading them",
          "[protocol]") {
  ScriptedNetwork net(kThreeAgentsRealTime);
  net.Start();
  net.Pump();
  REQUIRE(net.agents.at(3)->last_written_step() == 1);
  // GIVEN agent 3 frozen while the target publishes steps 2..5 (its messages wait in its
  // sockets)
  const auto frozen = net.Freeze(3);
  for (int k = 2; k <= 5; ++k) {
    net.AdvanceTime(0.1);
    net.Pump(frozen);
  }
  // WHEN it runs again, its loop wakes before its readers hold the backlog (the transport's
  // threads deliver it a moment later): the loop came back long after its wake-up
  net.frozen.erase(3);
  const double hold_s = net.agents.at(3)->OnResumed(net.now);
  CHECK(hold_s == Approx(0.1));  // twice the step's deadline: 2 x deadline_fraction x period_s
  net.agents.at(3)->OnTimer(net.now);
  // THEN it writes nothing on the clock yet
  CHECK(net.agents.at(3)->last_written_step() == 1);
  // AND once the backlog is read, the steps it slept through are written with it
  net.ReleaseHeld();
  net.Pump();
  net.AdvanceTime(hold_s + 0.001);
  net.Pump();
  CHECK(net.agents.at(3)->last_written_step() >= 5);
  for (const auto& row : net.rows.at(3)) {
    INFO("step " << row.step);
    if (row.step >= 2 && row.step <= 5) CHECK(row.fused >= 2);
  }
  // AND in lock-step there is nothing to hold: a step waits for its members anyway
  ScriptedNetwork lock_step(kThreeAgents);
  lock_step.Start();
  CHECK(lock_step.agents.at(1)->OnResumed(lock_step.now) == 0.0);
}

TEST_CASE("In real time an agent whose ranges come after their deadline follows the target's "
          "clock instead of missing every step",
          "[protocol]") {
  ScriptedNetwork net(kThreeAgentsRealTime);
  net.Start();
  net.Pump();
  REQUIRE(net.agents.at(1)->last_written_step() == 1);
  // GIVEN from step 2 on every range for agent 1 arrives 0.07 s after the target wrote it,
  // past the agent's deadline (0.05 s), as from a target whose clock runs behind its own
  net.AdvanceTime(0.1);  // t = 0.1: the target writes step 2
  for (int k = 2; k <= 10; ++k) {
    net.Pump(IsRangeToAgent1);
    net.AdvanceTime(0.07);
    net.ReleaseHeld();
    net.Pump();
    net.AdvanceTime(0.03);  // t = 0.1 k: the target writes step k + 1
  }
  // THEN only the first late range is missed: the agent's deadlines follow the target
  CHECK(net.agents.at(1)->last_written_step() >= 9);
  CHECK(net.agents.at(1)->counters().deadline_misses <= 1);
  for (const auto& row : net.rows.at(1)) {
    if (row.step >= 3) CHECK(row.fused == 3);
  }
}

namespace {

// The state agent `id` publishes at `step`, present and hearing all `agents` (for a target
// that resumes a run).
protocol::StateMsg StateOfAgent(AgentId id, StepIndex step, int agents) {
  protocol::StateMsg state;
  state.run = ScriptedNetwork::kRun;
  state.agent_id = id;
  state.instance_token = static_cast<std::uint64_t>(id);
  state.step = step;
  state.position_m = Vector2(2.0, static_cast<double>(id));
  state.matched = agents;
  return state;
}

}  // namespace

TEST_CASE("A real-time target that resumes a run starts after the newest step the agents wrote, "
          "even when their states arrive as one backlog",
          "[protocol]") {
  const deif::Config config = deif::ParseConfig(
      "scenario: {steps: 100, mode: realtime, period_s: 0.1}\nagents: {count: 3}\n", "inline");
  protocol::TargetProtocol::Options options;
  options.run = ScriptedNetwork::kRun;
  options.start_step = 6;  // killed before step 6; the agents went on on their clock
  protocol::TargetProtocol target(config, options);
  target.Start(0.0);
  // GIVEN every agent's states of steps 5..20 arrive at once, oldest first (a new reader's
  // backlog), each agent present and hearing the others
  for (StepIndex k = 5; k <= 20; ++k) {
    for (AgentId id = 1; id <= 3; ++id) target.OnState(StateOfAgent(id, k, 3), KeyOf(id), 0.0);
  }
  const auto first_range = [&target]() -> StepIndex {
    for (auto& action : target.TakeActions()) {
      if (const auto* r = std::get_if<protocol::target_action::PublishRange>(&action)) return r->msg.step;
    }
    return 0;
  };
  // THEN it does not start in the middle of that backlog, and starts at step 21
  CHECK(first_range() == 0);
  target.OnTimer(1.5);
  CHECK(first_range() == 21);
}

TEST_CASE("A lock-step target that resumes a run never goes back before its start step, and "
          "starts after the agents' newest step if that is later",
          "[protocol]") {
  const deif::Config config =
      deif::ParseConfig("scenario: {steps: 300}\nagents: {count: 3}\n", "inline");
  // A target restarted in place at step 216, say, finds agents that restarted too: their
  // states are of step 0 (not yet rejoined); or agents that went on to a later step.
  const StepIndex agents_at = GENERATE(StepIndex{0}, StepIndex{215}, StepIndex{240});
  protocol::TargetProtocol::Options options;
  options.run = ScriptedNetwork::kRun;
  options.start_step = 216;
  protocol::TargetProtocol target(config, options);
  target.Start(0.0);
  for (AgentId id = 1; id <= 3; ++id) target.OnState(StateOfAgent(id, agents_at, 3), KeyOf(id), 0.0);
  target.OnTimer(2.0);
  StepIndex first = 0;
  for (auto& action : target.TakeActions()) {
    if (const auto* r = std::get_if<protocol::target_action::PublishRange>(&action)) {
      first = first == 0 ? r->msg.step : first;
    }
  }
  CHECK(first == (agents_at == 240 ? 241 : 216));
}

TEST_CASE("The target holds a faulted step until told to go, and leaves a killed agent out of "
          "its roll call",
          "[protocol]") {
  ScriptedNetwork net(
      "scenario: {steps: 10}\n"
      "agents: {count: 3}\n"
      "faults: [{step: 4, action: kill, agent: 2}]\n",
      /*hold_for_faults=*/true);
  net.Start();
  net.RunUntil(3);
  net.Pump();
  // THEN the target holds step 4 for the fault
  REQUIRE(net.holds == std::vector<StepIndex>{4});
  CHECK(net.target->current_step() == 4);
  CHECK(net.agents.at(1)->last_written_step() == 3);
  // WHEN agent 2 is killed and the target told to go, it waits to see agent 2 lost
  net.Kill(2);
  net.target->OnGo(4, net.now);
  net.Pump();
  net.RunUntil(10);
  // THEN step 4's roll call is {1, 3}: the survivors fuse two from step 4 on
  for (AgentId id : {1, 3}) {
    CHECK(net.rows.at(id)[3].fused == 2);
    CHECK(net.rows.at(id)[3].complete);
  }
  for (const auto& r : net.ranges) {
    if (r.step >= 4) CHECK(r.agent_id != 2);
  }
}

TEST_CASE("A fault the network never shows holds the target for half the start timeout, so "
          "agents waiting for its next range do not give up first", "[protocol]") {
  // GIVEN agent 2 is to be stopped at step 4, but the stop never happens (nobody sees it go)
  ScriptedNetwork net(
      "scenario: {steps: 8}\n"
      "agents: {count: 3}\n"
      "network: {start_timeout_s: 4}\n"
      "faults: [{step: 4, action: stop, agent: 2}]\n",
      /*hold_for_faults=*/true);
  net.Start();
  net.RunUntil(3);
  net.Pump();
  REQUIRE(net.holds == std::vector<StepIndex>{4});
  const double go_s = net.now;
  net.target->OnGo(4, net.now);
  // WHEN time passes
  net.RunUntil(4);
  // THEN step 4 went out after half the start timeout, and every agent wrote it
  CHECK(net.now >= go_s + 2.0);
  CHECK(net.now < go_s + 2.5);
  for (AgentId id : {1, 2, 3}) {
    CHECK_FALSE(net.agents.at(id)->finished());
    CHECK(net.agents.at(id)->last_written_step() == 4);
  }
}

TEST_CASE("The target's start timeout counts from the last agent that appeared, so a slow "
          "discovery still under way is waited for", "[protocol]") {
  // GIVEN 4 agents whose participants are all up, start_timeout_s 5, and the states of
  // agents 3 and 4 not yet through to the target (their discovery is still under way)
  ScriptedNetwork net(
      "scenario: {steps: 6}\n"
      "agents: {count: 4}\n"
      "network: {start_timeout_s: 5}\n");
  for (AgentId id = 1; id <= 4; ++id) net.agents.at(id)->OnTargetParticipant(true, net.now);
  const auto late = [](const Envelope& e) { return e.to == deif::testing::kTarget && (e.from == 3 || e.from == 4); };
  net.Start();
  net.Pump(late);
  const auto wait_until = [&net, &late](double t_s) {
    while (net.now < t_s - 1e-9) {
      net.AdvanceTime(0.05);
      net.Pump(late);
    }
  };
  // WHEN agent 3's state gets through at 4 s
  wait_until(4.0);
  REQUIRE_FALSE(net.target->started());
  std::deque<Envelope> held;
  held.swap(net.held);
  for (Envelope& e : held) {
    if (e.from == 3) {
      net.Deliver(e);
    } else {
      net.held.push_back(std::move(e));
    }
  }
  // THEN the target has not started at 5 s from its start, nor 4.9 s after agent 3 came
  wait_until(8.9);
  CHECK_FALSE(net.target->started());
  // but 5 s after agent 3 it starts with the three it has, and they run to the end
  wait_until(9.1);
  CHECK(net.target->started());
  net.Pump(late);
  net.RunUntil(6, late);
  for (AgentId id : {1, 2, 3}) CHECK(net.agents.at(id)->last_written_step() == 6);
  CHECK(net.target->current_step() == 6);
}

TEST_CASE("In lock-step the target waits while no agent is alive, goes on when one is back, and "
          "ends with an error after start_timeout_s without one",
          "[protocol]") {
  const std::string yaml =
      "scenario: {steps: 30}\n"
      "agents: {count: 2}\n"
      "network: {start_timeout_s: 5}\n";
  ScriptedNetwork net(yaml);
  net.Start();
  net.RunUntil(3);
  const StepIndex at = net.target->current_step();
  REQUIRE(at < 10);
  // GIVEN both agents lost (frozen, so that they can come back)
  net.frozen.insert(1);
  net.frozen.insert(2);
  net.Liveliness(deif::testing::kTarget, 1, false);
  net.Liveliness(deif::testing::kTarget, 2, false);
  // WHEN 4 s pass (less than start_timeout_s)
  for (int i = 0; i < 40; ++i) net.AdvanceTime(0.1);
  // THEN the target is still at the step it was at, and running
  CHECK(net.target->current_step() == at);
  CHECK_FALSE(net.target->finished());
  // WHEN agent 1 is back, THEN the run goes on to the end
  net.frozen.erase(1);
  net.Liveliness(deif::testing::kTarget, 1, true);
  net.RunUntil(30);
  CHECK(net.target->current_step() == 30);
  // GIVEN a second run in which both agents are lost for good
  ScriptedNetwork dead(yaml);
  dead.Start();
  dead.RunUntil(3);
  dead.Kill(1);
  dead.Kill(2);
  for (int i = 0; i < 60; ++i) dead.AdvanceTime(0.1);
  // THEN after 5 s it ended with the runtime-error exit code, long before step 30
  REQUIRE(dead.target->finished());
  CHECK(dead.exit_codes.at(deif::testing::kTarget) == protocol::kExitRuntimeError);
  CHECK(dead.target->current_step() < 30);
}

TEST_CASE("A negative noisy range is a measurement like any other", "[protocol][validation]") {
  // (Without the innovation gate: a range 2 m off the prediction would fail that one.)
  ScriptedNetwork net(std::string(kThreeAgents) + "filter: {innovation_gate_sigma: 0}\n");
  net.Start();
  net.RunUntil(2);
  net.Pump([](const Envelope& e) {
    const auto* r = std::get_if<protocol::RangeMsg>(&e.message);
    return r != nullptr && r->agent_id == 2 && r->step == 3;
  });
  REQUIRE(net.held.size() == 1);
  std::get<protocol::RangeMsg>(net.held.front().message).range_m = -0.2;  // noise can do that
  net.ReleaseHeld();
  net.RunUntil(3);
  CHECK(net.agents.at(2)->counters().rejected == 0);
  const protocol::ContributionMsg c = ValidContributionFrom(net, 2, 3);
  CHECK_FALSE(c.info_matrix.isZero(0.0));
  CHECK(net.rows.at(1)[2].complete);
}

TEST_CASE("A measurement from the target that fails validation is counted, and the step goes "
          "on with an empty contribution so nobody waits for it",
          "[protocol][validation]") {
  ScriptedNetwork net(kThreeAgents);
  net.Start();
  net.RunUntil(2);
  net.Pump([](const Envelope& e) {
    const auto* r = std::get_if<protocol::RangeMsg>(&e.message);
    return r != nullptr && r->agent_id == 2 && r->step == 3;
  });
  REQUIRE(net.held.size() == 1);
  std::get<protocol::RangeMsg>(net.held.front().message).variance_m2 =
      std::numeric_limits<double>::quiet_NaN();
  net.ReleaseHeld();
  net.RunUntil(3);
  CHECK(net.agents.at(2)->counters().by_reason.count("rejected: non_finite") == 1);
  const protocol::ContributionMsg c = ValidContributionFrom(net, 2, 3);
  CHECK(c.info_matrix.isZero(0.0));
  CHECK(c.info_vector.isZero(0.0));
  for (AgentId id = 1; id <= 3; ++id) CHECK(net.rows.at(id)[2].complete);
  CHECK(net.now == 0.0);  // nobody waited for a timeout
  CHECK(AllAgreeAt(net, 3));
}

TEST_CASE("Contributions the transport dropped under unknown ids are counted once each, as "
          "rejections", "[protocol][validation]") {
  ScriptedNetwork net(kThreeAgents);
  net.Start();
  protocol::AgentProtocol& agent = *net.agents.at(1);
  agent.OnUnknownIdsDropped(5);
  agent.OnUnknownIdsDropped(5);  // the same total again: nothing new
  CHECK(agent.counters().rejected == 5);
  agent.OnUnknownIdsDropped(8);
  CHECK(agent.counters().rejected == 8);
  CHECK(agent.counters().by_reason.at("rejected: unknown_agent_id") == 8);
}

TEST_CASE("The target starts only when its range writer reaches every agent present, once the "
          "transport reports its readers", "[protocol]") {
  ScriptedNetwork net(kThreeAgents);
  // GIVEN a transport whose range writer has matched the readers of agents 1 and 2 only
  const auto reader_of = [](int node) {
    protocol::SenderKey key = deif::testing::KeyOf(node);
    key[15] = 0x07;  // another entity of the same participant
    return key;
  };
  net.target->OnRangeReaders({reader_of(1), reader_of(2)});
  net.Start();
  net.Pump();
  net.AdvanceTime(0.5);
  net.Pump();
  // THEN every agent's state is in, but no step is published: agent 3 is the one unreached
  CHECK_FALSE(net.target->started());
  CHECK(net.target->Unreached() == std::set<AgentId>{3});
  // WHEN agent 3's reader matches too
  net.target->OnRangeReaders({reader_of(1), reader_of(2), reader_of(3)});
  CHECK(net.target->Unreached().empty());
  net.AdvanceTime(0.01);
  net.Pump();
  // THEN the run starts
  CHECK(net.target->started());
  net.RunUntil(3);
  CHECK(net.agents.at(3)->last_written_step() >= 3);
}

TEST_CASE("An agent reports its peers matched only once its range reader has matched the "
          "target, and the target waits for it", "[protocol]") {
  ScriptedNetwork net(kThreeAgents);
  // GIVEN agents that match all three contribution writers both ways, agent 3's range reader
  // not yet matched to the target's writer (its announcement was lost), as their transports
  // report before they start (agent/agent_node.cpp)
  net.PeersMatched(1, 3, 1);
  net.PeersMatched(2, 3, 1);
  net.PeersMatched(3, 3, 0);
  net.Start();
  net.Pump();
  net.AdvanceTime(0.5);
  net.Pump();
  // THEN no step is published
  CHECK_FALSE(net.target->started());
  // WHEN agent 3's range reader matches the target's writer
  net.PeersMatched(3, 3, 1);
  net.Pump();
  net.AdvanceTime(0.01);
  net.Pump();
  // THEN the run starts, and every agent fuses all three at step 1
  CHECK(net.target->started());
  net.RunUntil(2);
  for (AgentId id = 1; id <= 3; ++id) {
    REQUIRE_FALSE(net.rows[id].empty());
    const deif::AgentRow& first = net.rows[id].front();
    CHECK(first.step == 1);
    CHECK(first.fused == 3);
    CHECK(first.complete);
    CHECK(first.estimate_m == net.rows[1].front().estimate_m);
  }
}

namespace {

StepIndex StepOf(const Envelope& e) {
  return std::visit([](const auto& m) -> StepIndex { return m.step; }, e.message);
}

bool IsContribution(const Envelope& e) { return std::holds_alternative<protocol::ContributionMsg>(e.message); }

// Agent 3 of three frozen from step 3 to step 20, longer than the history of 8 steps: what
// was sent to it meanwhile is held in `net.held`.
void FreezeAgent3ThroughStep20(ScriptedNetwork& net) {
  net.Start();
  net.RunUntil(3);
  const auto frozen = net.Freeze(3);
  net.RunUntil(20, frozen);
}

// Agent 3 resumes: `backlog` (in its order) is what reaches it of what was held, its peers and
// the target are alive again in its view, and the run goes on to its end (step 30).
void ResumeAgent3(ScriptedNetwork& net, std::deque<Envelope> backlog) {
  net.held = std::move(backlog);
  net.frozen.erase(3);
  net.Liveliness(1, 3, true);
  net.Liveliness(2, 3, true);
  net.Liveliness(deif::testing::kTarget, 3, true);
  net.ReleaseHeld();
  net.RunUntil(30);
}

// Agent 3 frozen through step 20; on resume only the newest history_steps samples of each
// writer are left for it (keep-last histories), delivered with the peers' contributions
// before the target's ranges when `contributions_first`, else the other way round. Returns
// agent 3's rows from the resume.
std::vector<deif::AgentRow> ResumeAfterLongFreeze(bool contributions_first, long* too_far_ahead) {
  ScriptedNetwork net(kThreeAgents);
  FreezeAgent3ThroughStep20(net);
  std::deque<Envelope> kept;
  for (Envelope& e : net.held) {
    if (e.to == 3 && StepOf(e) > 20 - 8) kept.push_back(std::move(e));
  }
  std::stable_partition(kept.begin(), kept.end(),
                        [&](const Envelope& e) { return IsContribution(e) == contributions_first; });
  ResumeAgent3(net, std::move(kept));
  const auto& c = net.agents.at(3)->counters().by_reason;
  *too_far_ahead = c.count("dropped: too_far_ahead") > 0 ? c.at("dropped: too_far_ahead") : 0;
  std::vector<deif::AgentRow> rows;
  for (const auto& r : net.rows[3]) {
    if (r.step > 3) rows.push_back(r);
  }
  return rows;
}

}  // namespace

TEST_CASE("After a freeze longer than the history, a backlog of contributions that arrives "
          "before the roll calls is kept: the agent resumes as when the roll calls come first",
          "[protocol]") {
  long dropped_ranges_first = 0;
  long dropped_contributions_first = 0;
  const auto ranges_first = ResumeAfterLongFreeze(false, &dropped_ranges_first);
  const auto contributions_first = ResumeAfterLongFreeze(true, &dropped_contributions_first);
  CHECK(dropped_ranges_first == 0);
  CHECK(dropped_contributions_first == 0);
  REQUIRE(ranges_first.size() == contributions_first.size());
  REQUIRE(ranges_first.size() >= 8);  // it wrote rows after the resume, to the end
  CHECK(ranges_first.back().step == 30);
  for (std::size_t i = 0; i < ranges_first.size(); ++i) {
    INFO("step " << ranges_first[i].step);
    CHECK(contributions_first[i].step == ranges_first[i].step);
    CHECK(contributions_first[i].estimate_m == ranges_first[i].estimate_m);
    CHECK(contributions_first[i].covariance == ranges_first[i].covariance);
    CHECK(contributions_first[i].fused == ranges_first[i].fused);
  }
}

TEST_CASE("Contributions held for the steps an agent skips when it rejoins beyond the history "
          "are counted as dropped, not lost uncounted",
          "[protocol]") {
  // GIVEN agent 3 frozen from step 3 to step 20 (the history is 8 steps)
  ScriptedNetwork net(kThreeAgents);
  FreezeAgent3ThroughStep20(net);
  // WHEN of its backlog only the peers' contributions of steps 13..20 reach it, then the
  // target's ranges of steps 17..20 (those of 13..16 are lost)
  std::deque<Envelope> kept;
  long skipped = 0;  // contributions of the steps it will skip
  for (Envelope& e : net.held) {
    if (e.to != 3 || StepOf(e) <= 12) continue;
    if (StepOf(e) < 17) {
      if (!IsContribution(e)) continue;
      ++skipped;
    }
    kept.push_back(std::move(e));
  }
  std::stable_partition(kept.begin(), kept.end(), [](const Envelope& e) { return IsContribution(e); });
  REQUIRE(skipped == 2 * 4);  // agents 1 and 2, steps 13..16
  ResumeAgent3(net, std::move(kept));
  // THEN it rejoins at step 17, and the contributions of 13..16 it held are counted as dropped
  std::vector<StepIndex> resumed;
  for (const auto& r : net.rows[3]) {
    if (r.step > 3) resumed.push_back(r.step);
  }
  REQUIRE_FALSE(resumed.empty());
  CHECK(resumed.front() == 17);
  CHECK(resumed.back() == 30);
  const auto& c = net.agents.at(3)->counters();
  REQUIRE(c.by_reason.count("dropped: skipped_step") == 1);
  CHECK(c.by_reason.at("dropped: skipped_step") == skipped);
  CHECK(c.dropped == skipped);
}

namespace {

// Starts `agent` (of run `run`, in a network of agents 1..3) and hands it the target's range
// of step 1, measured where it starts. Returns the actions of both.
std::vector<protocol::AgentAction> StartWithFirstRange(protocol::AgentProtocol& agent,
                                                       protocol::RunToken run) {
  agent.Start(0.0);
  std::vector<protocol::AgentAction> actions = agent.TakeActions();
  Vector2 start = Vector2::Zero();
  for (const auto& action : actions) {
    if (const auto* state = std::get_if<protocol::agent_action::PublishState>(&action)) {
      start = state->msg.position_m;
    }
  }
  protocol::RangeMsg range;
  range.run = run;
  range.agent_id = agent.id();
  range.step = 1;
  range.measured = true;
  range.range_m = 2.0;
  range.variance_m2 = 5.3e-4;
  range.p_sensor = start;
  range.roll_call = {1, 2, 3};
  protocol::SenderKey target{};
  target[0] = 7;
  agent.OnRange(range, target, 0.01);
  for (auto& action : agent.TakeActions()) actions.push_back(std::move(action));
  return actions;
}

// What an agent with options `resume_after` writes when the first range it hears is the
// target's range of step 1 measured for a predecessor at the same starting position (from
// the target's history), and then nothing until long after that step's deadline.
std::vector<StepIndex> RowsAfterAStaleFirstRange(StepIndex resume_after) {
  const deif::Config config = deif::ParseConfig(
      "scenario: {steps: 100, mode: realtime, period_s: 0.1}\nagents: {count: 3}\n", "resume_test");
  protocol::AgentProtocol::Options options;
  options.run = protocol::RunTokenOf("resume");
  options.resume_after = resume_after;
  protocol::AgentProtocol agent(config, 2, options);
  std::vector<protocol::AgentAction> actions = StartWithFirstRange(agent, options.run);
  agent.OnTimer(1.0);
  for (auto& action : agent.TakeActions()) actions.push_back(std::move(action));
  std::vector<StepIndex> written;
  for (const auto& action : actions) {
    if (const auto* row = std::get_if<protocol::agent_action::WriteRow>(&action)) {
      written.push_back(row->row.step);
    }
  }
  return written;
}

}  // namespace

TEST_CASE("A restarted agent that appends to its rows never writes a step at or before its last",
          "[protocol]") {
  // GIVEN an agent whose rows end at step 50 (a restart), and one that starts afresh
  // WHEN each hears first the target's old range of step 1, measured where both start
  // THEN the new agent takes it and writes from step 1 on, on its clock; the restarted one
  // writes nothing (it joins at the first range after step 50)
  const std::vector<StepIndex> fresh = RowsAfterAStaleFirstRange(0);
  CHECK((!fresh.empty() && fresh.front() == 1));
  CHECK(RowsAfterAStaleFirstRange(50).empty());
}

TEST_CASE("Ranges announced for steps an agent skips when it rejoins beyond the history are "
          "counted as dropped",
          "[protocol]") {
  // GIVEN agent 1 of 3 in lock-step (history 50 steps), its step 1 open and waiting for its peers
  const deif::Config config =
      deif::ParseConfig("agents: {count: 3}\nnetwork: {step_timeout_s: 2, history_steps: 50}\n", "skip_test");
  protocol::AgentProtocol::Options options;
  options.run = protocol::RunTokenOf("skip");
  protocol::AgentProtocol agent(config, 1, options);
  StartWithFirstRange(agent, options.run);
  protocol::SenderKey target{};
  target[0] = 7;  // the writer of the first range
  // WHEN the target, gone on without it, announces steps 60, 61 and 62 meanwhile
  for (StepIndex k = 60; k <= 62; ++k) {
    protocol::RangeMsg range;
    range.run = options.run;
    range.agent_id = 1;
    range.step = k;
    range.measured = false;
    range.roll_call = {1, 2, 3};
    agent.OnRange(range, target, 0.5);
  }
  REQUIRE(agent.counters().dropped == 0);
  // ... and step 1 ends at its timeout
  agent.OnTimer(2.5);
  agent.TakeActions();
  // THEN it rejoins at step 62, and the ranges of the two steps it skips are counted as dropped
  const auto& c = agent.counters();
  REQUIRE(c.by_reason.count("dropped: skipped_step") == 1);
  CHECK(c.by_reason.at("dropped: skipped_step") == 2);
  CHECK(c.dropped == 2);
}

namespace {

// When an agent that never gets a range gives up (its exit code), given what it sees of the
// target: `up_until` < 0, nothing; else, from the start until then, a range writer matched by
// its range reader (`by_participant` false) or the target's participant up without any
// endpoint (true). Timers every 0.5 s up to 200 s; returns (the time it finished, its exit
// code), or (inf, -1) if it never did.
// With `peer_step_at` >= 0, a peer's contribution to step 1 arrives then (the target has
// begun without a range for this agent).
std::pair<double, int> GivesUpAt(double up_until, bool by_participant = false,
                                 double peer_step_at = -1.0) {
  const deif::Config config = deif::ParseConfig(
      "agents: {count: 3}\nnetwork: {start_timeout_s: 10, step_timeout_s: 2}\n", "patience_test");
  protocol::AgentProtocol::Options options;
  options.run = protocol::RunTokenOf("patience");
  protocol::AgentProtocol agent(config, 1, options);
  agent.Start(0.0);
  // Agent 2's contribution to step 1, made by an agent 2 that got its range.
  protocol::AgentProtocol peer(config, 2, options);
  std::optional<protocol::ContributionMsg> peer_contribution;
  for (const auto& action : StartWithFirstRange(peer, options.run)) {
    if (const auto* c = std::get_if<protocol::agent_action::PublishContribution>(&action)) {
      peer_contribution = c->msg;
    }
  }
  REQUIRE(peer_contribution);
  protocol::SenderKey peer_key{};
  peer_key[0] = 2;
  const auto see = [&](bool up, double t) {
    if (by_participant) {
      agent.OnTargetParticipant(up, t);
    } else {
      agent.OnPeersMatched(3, up ? 1 : 0, t);
    }
  };
  if (up_until >= 0.0) see(true, 0.0);
  for (double t = 0.5; t <= 200.0; t += 0.5) {
    if (up_until >= 0.0 && std::abs(t - up_until) < 1e-9) see(false, t);
    if (peer_step_at >= 0.0 && std::abs(t - peer_step_at) < 1e-9) {
      agent.OnContribution(*peer_contribution, peer_key, t);
    }
    agent.OnTimer(t);
    for (const auto& action : agent.TakeActions()) {
      if (const auto* f = std::get_if<protocol::agent_action::Finish>(&action)) return {t, f->exit_code};
    }
  }
  return {std::numeric_limits<double>::infinity(), -1};
}

}  // namespace

TEST_CASE("Before its first range an agent waits while a target of its run is up and no peer has "
          "a step, and gives up start_timeout_s + step_timeout_s after that ends",
          "[protocol]") {
  // GIVEN start_timeout_s 10 and step_timeout_s 2 (a patience of 12 s before the first range)
  // WHEN no range writer is ever matched, THEN the agent gives up 12 s after its start
  const auto alone = GivesUpAt(-1.0);
  CHECK(alone.first == 12.0);
  CHECK(alone.second == protocol::kExitRuntimeError);
  // WHEN the target's range writer is matched from the start for 100 s (a target up and
  // waiting for agents that start one after another), THEN the agent waits, and gives up
  // 12 s after the writer is gone
  const auto waited = GivesUpAt(100.0);
  CHECK(waited.first == 112.0);
  CHECK(waited.second == protocol::kExitRuntimeError);
  // WHEN only the target's process is seen for 100 s (a target of a large run making its
  // writers), THEN the same
  const auto seen = GivesUpAt(100.0, /*by_participant=*/true);
  CHECK(seen.first == 112.0);
  CHECK(seen.second == protocol::kExitRuntimeError);
  // WHEN the target stays up but a peer's contribution to step 1 arrives at 50 s (the run
  // has begun, and this agent's ranges do not reach it), THEN it gives up 12 s after that
  const auto begun = GivesUpAt(150.0, /*by_participant=*/true, /*peer_step_at=*/50.0);
  CHECK(begun.first == 62.0);
  CHECK(begun.second == protocol::kExitRuntimeError);
}

TEST_CASE("Contributions delivered as one batch give what one by one gives, bit for bit",
          "[protocol][tree]") {
  // GIVEN two identical networks whose contributions to agent 1 are held back each step
  ScriptedNetwork single(kThreeAgents), batched(kThreeAgents);
  single.Start();
  batched.Start();
  const auto to_1 = [](const Envelope& e) {
    return e.to == 1 && std::holds_alternative<protocol::ContributionMsg>(e.message);
  };
  for (int round = 0; round < 12; ++round) {
    single.Pump(to_1);
    batched.Pump(to_1);
    // WHEN agent 1 gets them one by one in one network and as one batch in the other
    REQUIRE(single.held.size() == batched.held.size());
    for (const Envelope& e : single.held) single.Deliver(e);
    batched.DeliverBatch(1, std::vector<Envelope>(batched.held.begin(), batched.held.end()));
    single.held.clear();
    batched.held.clear();
  }
  // THEN its rows are the same, complete, bit for bit
  const auto& a = single.rows.at(1);
  const auto& b = batched.rows.at(1);
  REQUIRE(a.size() >= 10);
  REQUIRE(a.size() == b.size());
  for (std::size_t i = 0; i < a.size(); ++i) {
    CHECK(a[i].step == b[i].step);
    CHECK(a[i].fused == 3);
    CHECK(b[i].fused == 3);
    CHECK(a[i].estimate_m == b[i].estimate_m);
    CHECK(a[i].covariance == b[i].covariance);
  }
}

TEST_CASE("A relayed contribution of a peer seen lost does not make it a member again",
          "[protocol][tree]") {
  ScriptedNetwork net(kThreeAgents);
  net.Start();
  net.RunUntil(3);
  const protocol::ContributionMsg old = ValidContributionFrom(net, 2, 2);
  // GIVEN agent 1 saw agent 2's writer lost (past the grace)
  net.Liveliness(1, 2, false);
  net.AdvanceTime(1.0);
  REQUIRE(net.agents.at(1)->Members().count(2) == 0);
  CHECK(net.agents.at(1)->MemberCount() == 2);  // itself and 3
  // WHEN a relay's history brings one of 2's old contributions
  net.agents.at(1)->OnContributions({{old, KeyOf(2)}}, net.now);
  // THEN 2 stays out; its liveliness brings it back
  CHECK(net.agents.at(1)->Members().count(2) == 0);
  CHECK(net.agents.at(1)->LostPeers().count(2) == 1);
  net.Liveliness(1, 2, true);
  CHECK(net.agents.at(1)->Members().count(2) == 1);
  CHECK(net.agents.at(1)->MemberCount() == 3);
  // A contribution straight from its writer still does, as before (all to all).
  net.Liveliness(1, 3, false);
  net.AdvanceTime(1.0);
  REQUIRE(net.agents.at(1)->Members().count(3) == 0);
  net.agents.at(1)->OnContribution(ValidContributionFrom(net, 3, 2), KeyOf(3), net.now);
  CHECK(net.agents.at(1)->Members().count(3) == 1);
}

TEST_CASE("A relayed contribution to a step begun after the peer was seen lost makes it a "
          "member again", "[protocol][tree]") {
  // Fast DDS can leave a live writer lost in a reader's view, its return never reported
  // (docs/FASTDDS_NOTES.md): a contribution nobody dead could have made proves it lives.
  ScriptedNetwork net(kThreeAgents);
  net.Start();
  net.RunUntil(3);
  // GIVEN agent 1 saw agent 2's writer lost (past the grace) after step w
  net.Liveliness(1, 2, false);
  net.AdvanceTime(1.0);
  REQUIRE(net.agents.at(1)->Members().count(2) == 0);
  const StepIndex w = net.agents.at(1)->last_written_step();
  // AND the run went on, agent 2's contributions to agent 1 held back (a relay brings them)
  const auto to1 = [](const Envelope& e) {
    return e.from == 2 && e.to == 1 && std::holds_alternative<protocol::ContributionMsg>(e.message);
  };
  for (int i = 0; i < 2000 && net.agents.at(1)->last_written_step() < w + 4; ++i) {
    net.Pump(to1);
    net.AdvanceTime(0.01);
  }
  REQUIRE(net.agents.at(1)->last_written_step() >= w + 4);
  REQUIRE(net.agents.at(1)->Members().count(2) == 0);  // nothing of it came
  const protocol::ContributionMsg before = ValidContributionFrom(net, 2, w);
  std::optional<protocol::ContributionMsg> after;
  for (const auto& c : net.ContributionsOf(2)) {
    if (c.step >= w + 3) {
      after = c;
      break;
    }
  }
  REQUIRE(after.has_value());
  // WHEN a relay brings its contribution to step w (begun before it was seen lost)
  net.agents.at(1)->OnContributions({{before, KeyOf(2)}}, net.now);
  // THEN it stays out
  CHECK(net.agents.at(1)->Members().count(2) == 0);
  // WHEN a relay brings a contribution to a step begun after agent 1 saw it lost
  net.DeliverBatch(1, {Envelope{2, 1, *after}});
  // THEN it is a member again, and the log says why
  CHECK(net.agents.at(1)->Members().count(2) == 1);
  const auto& log = net.logs.at(1);
  CHECK(std::any_of(log.begin(), log.end(), [&](const std::string& l) {
    return l.find("agent 2 is alive again: it contributed to step " + std::to_string(after->step)) !=
           std::string::npos;
  }));
}

TEST_CASE("The roll call a relay waits for is the one the protocol accepted", "[protocol][tree]") {
  ScriptedNetwork net(kThreeAgents);
  net.Start();
  net.RunUntil(3);
  const auto accepted = net.agents.at(1)->RollCallOf(3);
  REQUIRE(accepted.has_value());
  CHECK(*accepted == std::vector<AgentId>{1, 2, 3});
  CHECK_FALSE(net.agents.at(1)->RollCallOf(29).has_value());  // no range for it yet
}

TEST_CASE("Peers that become members together are logged in one line", "[protocol]") {
  // GIVEN three agents, and agent 1 that has heard no contribution of the others yet
  ScriptedNetwork net(kThreeAgents);
  HoldContributionsToAgent1(net);
  REQUIRE(net.agents.at(1)->Members() == std::set<AgentId>{1});
  std::vector<Envelope> batch;
  for (const Envelope& e : net.held) {
    if (std::get<protocol::ContributionMsg>(e.message).step == 1) batch.push_back(e);
  }
  REQUIRE(batch.size() == 2);
  const auto member_lines = [&net] {
    std::vector<std::string> out;
    for (const std::string& l : net.logs[1]) {
      if (l.find("member") != std::string::npos) out.push_back(l);
    }
    return out;
  };
  REQUIRE(member_lines().empty());
  // WHEN a relay's batch brings both at once
  net.DeliverBatch(1, batch);
  // THEN one line names both, with the count after them
  CHECK(net.agents.at(1)->Members() == std::set<AgentId>{1, 2, 3});
  const std::vector<std::string> lines = member_lines();
  REQUIRE(lines.size() == 1);
  const bool either_order = lines[0] == "agents 2 3 are members; members now 3" ||
                            lines[0] == "agents 3 2 are members; members now 3";
  CHECK(either_order);
}

TEST_CASE("A peer that becomes a member alone is logged as one", "[protocol]") {
  // GIVEN three agents, and agent 1 that has heard no contribution of the others yet
  ScriptedNetwork net(kThreeAgents);
  HoldContributionsToAgent1(net);
  // WHEN agent 2's contribution comes on its own
  for (const Envelope& e : net.held) {
    if (e.from == 2) {
      net.Deliver(e);
      break;
    }
  }
  // THEN the log says so in the singular, with the count
  const auto& log = net.logs[1];
  CHECK(std::count(log.begin(), log.end(), std::string("agent 2 is a member; members now 2")) == 1);
}

// ---------------------------------------------------------------------------------------
// Membership from the roll call (network.membership: roll_call, docs/PROTOCOL.md): no peer's
// liveliness reaches an agent; only the target hears the agents' writers.

namespace {

bool Logged(ScriptedNetwork& net, AgentId id, const std::string& text) {
  const auto& log = net.logs[id];
  return std::any_of(log.begin(), log.end(), [&](const std::string& l) { return l.find(text) != std::string::npos; });
}

}  // namespace

TEST_CASE("With membership from the roll call, a peer the target leaves out is lost at once and one "
          "it names again is back, the steps complete and the agents agree",
          "[protocol][roll_call]") {
  // GIVEN three agents in lock-step whose members follow the target's roll call
  ScriptedNetwork net(kThreeAgents);
  net.SetRollCallMembership();
  net.Start();
  net.RunUntil(4);
  REQUIRE(net.agents.at(1)->Members() == std::set<AgentId>{1, 2, 3});
  // WHEN the target alone stops hearing agent 3 (the peers still do) for longer than the grace
  const auto cut = [](const Envelope& e) { return e.from == 3 && e.to == deif::testing::kTarget; };
  net.Pump(cut);
  net.Liveliness(deif::testing::kTarget, 3, false);
  net.AdvanceTime(net.config.network.liveliness_grace_s + 0.01);
  net.RunUntil(7, cut);
  // THEN agents 1 and 2 lose it by the roll call that leaves it out, without any liveliness
  for (AgentId id : {1, 2}) {
    INFO("agent " << id);
    CHECK(Logged(net, id, "agent 3 lost (left out of the target's roll call of step "));
    CHECK(net.agents.at(id)->Members() == std::set<AgentId>{1, 2});
  }
  // ... and write the steps without it complete (nobody waits for it)
  CHECK(net.rows.at(1).back().fused == 2);
  CHECK(net.rows.at(1).back().complete);
  // WHEN the target hears it again
  net.held.clear();  // what it missed meanwhile is not repaired (a state is kept last only)
  net.Liveliness(deif::testing::kTarget, 3, true);
  net.RunUntil(14);
  // THEN the next roll call that names it makes it a member again, and all three agree
  CHECK(Logged(net, 1, "agent 3 is alive again (named again in the target's roll call of step "));
  CHECK(net.agents.at(1)->Members() == std::set<AgentId>{1, 2, 3});
  CHECK(net.rows.at(1).back().fused == 3);
  CHECK(AllAgreeAt(net, 14));
  // AND no step was written short of its roll call
  CHECK(net.agents.at(1)->counters().deadline_misses == 0);
  CHECK(net.agents.at(2)->counters().deadline_misses == 0);
}

TEST_CASE("With membership from the roll call, a restart the target never saw as a loss is taken "
          "once the old writer missed a step, and an impostor of a live peer is refused",
          "[protocol][roll_call]") {
  // GIVEN three agents in real time whose members follow the target's roll call
  ScriptedNetwork net(kThreeAgentsRealTime);
  net.SetRollCallMembership();
  net.Start();
  for (int i = 0; i < 3; ++i) {
    net.Pump();
    net.AdvanceTime(0.1);
  }
  net.Pump();
  const StepIndex now_step = net.agents.at(1)->last_written_step();
  REQUIRE(now_step >= 3);
  // WHEN another writer sends agent 3's contribution to a step agent 3 itself contributed to
  const protocol::ContributionMsg copy = ValidContributionFrom(net, 3, now_step);
  net.agents.at(1)->OnContribution(copy, KeyOf(3, 7), net.now);
  // THEN it is refused: agent 3's writer is bound and has missed no step
  CHECK(net.agents.at(1)->counters().by_reason.count("rejected: agent_id_clash") == 1);
  // WHEN agent 3 dies, and a new process takes its place within the grace of the lapse the
  // target sees (so the target takes the new writer at once, and every roll call names 3)
  net.Kill(3, /*lapse=*/false);
  for (int i = 0; i < 3; ++i) {
    net.AdvanceTime(0.1);
    net.Pump();
  }
  net.Liveliness(deif::testing::kTarget, 3, false);
  net.dead.erase(3);
  net.incarnation[3] = 1;
  net.agents[3] = net.MakeAgent(3, /*token=*/99);
  net.agents.at(3)->Start(net.now);
  for (int i = 0; i < 10; ++i) {
    net.AdvanceTime(0.1);
    net.Pump();
  }
  // THEN the peers take the new writer as agent 3 restarted, fuse it again and agree
  CHECK(Logged(net, 1, "agent 3 lost (a new writer speaks for it, and the old one missed a step)"));
  CHECK(Logged(net, 1, "agent 3 rejoined with a new writer"));
  CHECK(net.agents.at(1)->Members() == std::set<AgentId>{1, 2, 3});
  const StepIndex last = net.agents.at(1)->last_written_step();
  CHECK(net.rows.at(1).back().fused == 3);
  CHECK(AllAgreeAt(net, last));
}

TEST_CASE("With membership from the roll call, peers that leave the roll call together are logged "
          "in one line",
          "[protocol][roll_call]") {
  // GIVEN four agents in lock-step whose members follow the target's roll call
  ScriptedNetwork net("scenario: {steps: 30, dt_s: 0.1}\nagents: {count: 4}\n"
                      "network: {history_steps: 8, step_timeout_s: 0.5}\n");
  net.SetRollCallMembership();
  net.Start();
  net.RunUntil(3);
  // WHEN the target stops hearing agents 3 and 4 at once (a host cut off)
  const auto cut = [](const Envelope& e) {
    return (e.from == 3 || e.from == 4) && e.to == deif::testing::kTarget;
  };
  net.Pump(cut);
  net.Liveliness(deif::testing::kTarget, 3, false);
  net.Liveliness(deif::testing::kTarget, 4, false);
  net.AdvanceTime(net.config.network.liveliness_grace_s + 0.01);
  net.RunUntil(6, cut);
  // THEN agent 1 says so in one line, with the members left
  const auto& log = net.logs[1];
  const auto lost = std::count_if(log.begin(), log.end(), [](const std::string& l) {
    return l.find(" lost (left out of the target's roll call of step ") != std::string::npos;
  });
  CHECK(lost == 1);
  CHECK(Logged(net, 1, "agents 3 4 lost (left out of the target's roll call of step "));
  CHECK(Logged(net, 1, "); members now 2"));
  CHECK(net.agents.at(1)->Members() == std::set<AgentId>{1, 2});
}

TEST_CASE("In lock-step a member whose contribution the open step still lacks after a while is "
          "waited for (its process is looked at often), and no longer once it came",
          "[protocol]") {
  // GIVEN three agents in lock-step, and agent 3's contribution to step 1 held from agent 1
  ScriptedNetwork net(kThreeAgents);
  net.Start();
  const auto from3to1 = [](const Envelope& e) { return IsContribution(e, 3, 1, 1); };
  net.Pump(from3to1);
  REQUIRE(net.held.size() == 1);
  REQUIRE(net.agents.at(1)->last_written_step() == 0);
  // WHEN the step has just opened THEN nobody is waited for yet, from kSuspectAfterS on
  CHECK(net.agents.at(1)->MembersWaitedFor(net.now).empty());
  REQUIRE(net.agents.at(1)->WaitedForFromS());
  CHECK(*net.agents.at(1)->WaitedForFromS() == Approx(net.now + protocol::AgentProtocol::kSuspectAfterS));
  // WHEN it has waited for agent 3 longer than kSuspectAfterS (within its step timeout)
  net.AdvanceTime(protocol::AgentProtocol::kSuspectAfterS + 0.01);
  REQUIRE(net.agents.at(1)->last_written_step() == 0);
  // THEN agent 3 is waited for, and agent 2, whose contribution came, is not
  CHECK(net.agents.at(1)->MembersWaitedFor(net.now) == std::set<AgentId>{3});
  // WHEN the contribution comes THEN the step is written and nobody is waited for
  net.ReleaseHeld();
  net.Pump();
  CHECK(net.agents.at(1)->last_written_step() >= 1);
  CHECK(net.agents.at(1)->MembersWaitedFor(net.now + protocol::AgentProtocol::kSuspectAfterS / 2).empty());
}

TEST_CASE("In lock-step nobody is waited for while more than a few members' contributions are "
          "missing (a slow step, or a batch on its way), nor in real time",
          "[protocol]") {
  // GIVEN seven agents in lock-step, and every contribution to agent 1 held
  ScriptedNetwork net("scenario: {steps: 30, dt_s: 0.1}\nagents: {count: 7}\n"
                      "network: {history_steps: 8, step_timeout_s: 0.5}\n");
  HoldContributionsToAgent1(net);
  net.Pump([](const Envelope& e) { return e.to == 1 && std::holds_alternative<protocol::ContributionMsg>(e.message); });
  REQUIRE(net.held.size() == 6);
  // WHEN step 1 has waited longer than kSuspectAfterS for six members
  net.AdvanceTime(protocol::AgentProtocol::kSuspectAfterS + 0.01);
  REQUIRE(net.agents.at(1)->last_written_step() == 0);
  // THEN nobody is waited for (more than kMaxWaitedFor missing)
  CHECK_FALSE(net.agents.at(1)->WaitedForFromS());
  CHECK(net.agents.at(1)->MembersWaitedFor(net.now).empty());
  // AND GIVEN three agents in real time, one contribution to agent 1 late
  ScriptedNetwork rt(kThreeAgentsRealTime);
  rt.Start();
  rt.Pump([](const Envelope& e) { return IsContribution(e, 3, 1, 1); });
  // THEN nobody is waited for there either: the deadline ends the wait
  CHECK_FALSE(rt.agents.at(1)->WaitedForFromS());
  CHECK(rt.agents.at(1)->MembersWaitedFor(rt.now + 1.0).empty());
}

namespace {

// Whether a target that waits for its agents (two of three present) takes agent 2 for lost
// when agent 2's state writer lapses for 0.5 s, with Options::start_grace_s `start_grace_s`.
bool LostBeforeTheStart(double start_grace_s) {
  const deif::Config config = deif::ParseConfig("agents: {count: 3}\n", "inline");
  protocol::TargetProtocol::Options options;
  options.run = ScriptedNetwork::kRun;
  options.start_grace_s = start_grace_s;
  protocol::TargetProtocol target(config, options);
  target.Start(0.0);
  for (AgentId id : {1, 2}) target.OnState(StateOfAgent(id, 0, 3), KeyOf(id), 0.0);
  target.OnWriterLiveliness(KeyOf(2), false, 0.1);
  target.OnTimer(0.6);
  target.OnWriterLiveliness(KeyOf(2), true, 0.6);
  target.OnTimer(0.7);
  REQUIRE_FALSE(target.started());  // agent 3 never came
  for (const auto& action : target.TakeActions()) {
    const auto* log = std::get_if<protocol::Log>(&action);
    if (log != nullptr && log->text.find("agent 2 lost") != std::string::npos) return true;
  }
  return false;
}

}  // namespace

TEST_CASE("Before the run begins the target holds an agent's lapse for its start grace",
          "[protocol]") {
  // With the configured grace (0.2 s) a 0.5 s lapse is a loss; with a start grace of 1 s it
  // is forgiven (a renewal late in the start storm of a large run).
  CHECK(LostBeforeTheStart(-1.0));
  CHECK_FALSE(LostBeforeTheStart(1.0));
}
