// The live page's model (observer/live_model.hpp) driven by scripted samples, no DDS: what a
// page is told about losses, the end of a run, partitions, the ring and staleness.
#include <catch2/catch.hpp>

#include <cmath>
#include <string>

#include "common/config/config.hpp"
#include "observer/live_model.hpp"

namespace deif::observer {
namespace {

constexpr double kPi = 3.14159265358979323846;
constexpr protocol::RunToken kRun = 77;

Config ThreeAgents(int steps = 10) {
  return ParseConfig("agents:\n  count: 3\nscenario:\n  steps: " + std::to_string(steps) + "\n",
                     "inline");
}

protocol::SenderKey Writer(int n) {
  protocol::SenderKey key{};
  key[0] = static_cast<std::uint8_t>(n);
  return key;
}

protocol::StateMsg State(AgentId id, StepIndex step, double angle_rad) {
  protocol::StateMsg s;
  s.run = kRun;
  s.agent_id = id;
  s.instance_token = 1000 + static_cast<std::uint64_t>(id);
  s.step = step;
  s.angle_rad = angle_rad;
  s.position_m = Vector2(2.0 * std::cos(angle_rad), 2.0 * std::sin(angle_rad));
  s.covariance = Matrix2::Identity() * 1e-4;
  return s;
}

// Three agents at the given angles wrote `step`, each from its own writer 1..3.
void AllWrite(LiveModel& model, StepIndex step, double t_s, const double (&angles)[3]) {
  for (AgentId id = 1; id <= 3; ++id) {
    model.OnState(State(id, step, angles[id - 1]), Writer(id), 0.0, t_s);
  }
}

int CountMarks(const LiveModel& model, const std::string& kind, AgentId agent) {
  int n = 0;
  for (const Mark& m : model.marks()) n += m.kind == kind && m.agent == agent ? 1 : 0;
  return n;
}

TEST_CASE("live model: an agent whose writer loses liveliness mid-run is lost and marked") {
  // GIVEN three agents alive at step 3 of 10
  LiveModel model(ThreeAgents(), kRun, "r");
  AllWrite(model, 3, 0.1, {0.0, 2.0, 4.0});
  REQUIRE(model.AliveCount() == 3);
  // WHEN agent 2's state writer loses liveliness
  model.OnLiveliness(WriterKind::kState, Writer(2), false, 0.5);
  // THEN it is lost, two are alive, and there is one 'lost' mark for it
  CHECK(model.StatusOf(2) == "lost");
  CHECK(model.AliveCount() == 2);
  CHECK(CountMarks(model, "lost", 2) == 1);
  CHECK(CountMarks(model, "partition", 0) == 0);
  // and the next update carries the mark and the new count
  const auto update = model.TakeUpdate(1.0);
  REQUIRE(update);
  CHECK((*update)["alive"] == 2);
  bool marked = false;
  for (const auto& m : (*update)["marks"]) marked = marked || (m["kind"] == "lost" && m["agent"] == 2);
  CHECK(marked);
}

TEST_CASE("live model: an agent whose process ended is lost at once, the others not") {
  // GIVEN three agents alive at step 3 of 10 (writer n's participant: the same first bytes)
  LiveModel model(ThreeAgents(), kRun, "r");
  AllWrite(model, 3, 0.1, {0.0, 2.0, 4.0});
  REQUIRE(model.AliveCount() == 3);
  protocol::SenderKey participant_of_2 = Writer(2);
  participant_of_2[15] = 0xc1;  // another entity of the same participant
  // WHEN the process of an unknown participant ends, then agent 2's
  model.OnProcessEnded(Writer(9), 0.4);
  CHECK(model.AliveCount() == 3);
  model.OnProcessEnded(participant_of_2, 0.5);
  // THEN agent 2 is lost (marked once), with no lapse reported
  CHECK(model.StatusOf(2) == "lost");
  CHECK(model.AliveCount() == 2);
  CHECK(CountMarks(model, "lost", 2) == 1);
  // and its lapse, reported later, changes nothing
  model.OnLiveliness(WriterKind::kState, Writer(2), false, 1.0);
  CHECK(CountMarks(model, "lost", 2) == 1);
}

TEST_CASE("live model: the live agents the target's newest roll call leaves out") {
  LiveModel model(ThreeAgents(), kRun, "r");
  AllWrite(model, 3, 0.1, {0.0, 2.0, 4.0});
  CHECK(model.LiveOutOfRollCall().empty());  // no roll call yet
  protocol::RangeMsg range;
  range.run = kRun;
  range.agent_id = 1;
  range.step = 4;
  range.measured = true;
  range.p_sensor = Vector2(2.0, 0.0);
  range.roll_call = {1, 3};
  model.OnRange(range, Writer(7), 0.2);
  CHECK(model.LiveOutOfRollCall() == std::set<AgentId>{2});
  model.OnLiveliness(WriterKind::kState, Writer(2), false, 0.3);  // lost: no longer live
  CHECK(model.LiveOutOfRollCall().empty());
}

TEST_CASE("live model: agents that end after the last step are done, not lost") {
  LiveModel model(ThreeAgents(10), kRun, "r");
  AllWrite(model, 10, 0.1, {0.0, 2.0, 4.0});
  for (AgentId id = 1; id <= 3; ++id) model.OnLiveliness(WriterKind::kState, Writer(id), false, 0.2);
  for (AgentId id = 1; id <= 3; ++id) CHECK(model.StatusOf(id) == "done");
  CHECK(CountMarks(model, "lost", 1) + CountMarks(model, "lost", 2) + CountMarks(model, "lost", 3) == 0);
  CHECK(CountMarks(model, "partition", 0) == 0);
  CHECK(CountMarks(model, "done", 2) == 1);
}

TEST_CASE("live model: two agents lost within a second are marked as a possible partition") {
  LiveModel model(ThreeAgents(), kRun, "r");
  AllWrite(model, 4, 0.1, {0.0, 2.0, 4.0});
  model.OnLiveliness(WriterKind::kState, Writer(1), false, 1.0);
  model.OnLiveliness(WriterKind::kState, Writer(3), false, 1.4);
  CHECK(CountMarks(model, "partition", 0) == 1);
  // a return is 'back'
  model.OnLiveliness(WriterKind::kState, Writer(1), true, 3.0);
  CHECK(model.StatusOf(1) == "alive");
  CHECK(CountMarks(model, "back", 1) == 1);
}

TEST_CASE("live model: the ring's gaps are those of the live agents, against 2pi/n and pi/2 for two") {
  LiveModel model(ThreeAgents(), kRun, "r");
  AllWrite(model, 2, 0.1, {0.0, 1.0, 3.0});  // gaps 1, 2 and 2pi - 3
  nlohmann::json ring = model.Snapshot(0.2)["ring"];
  CHECK(ring["n"] == 3);
  CHECK(ring["optimal"].get<double>() == Approx(2.0 * kPi / 3.0).margin(1e-6));
  double sum = 0.0;
  for (const auto& g : ring["gaps"]) sum += g.get<double>();
  CHECK(sum == Approx(2.0 * kPi).margin(1e-5));
  // the largest deviation: |(2pi - 3) - 2pi/3| = 1.1887...
  CHECK(ring["max_error"].get<double>() == Approx(2.0 * kPi - 3.0 - 2.0 * kPi / 3.0).margin(1e-5));

  model.OnLiveliness(WriterKind::kState, Writer(3), false, 0.3);
  ring = model.Snapshot(0.4)["ring"];
  CHECK(ring["n"] == 2);
  CHECK(ring["optimal"].get<double>() == Approx(kPi / 2.0).margin(1e-6));
}

TEST_CASE("live model: another run's samples are ignored and counted, never shown") {
  LiveModel model(ThreeAgents(), kRun, "r");
  protocol::StateMsg stray = State(1, 3, 0.0);
  stray.run = kRun + 1;
  model.OnState(stray, Writer(9), 0.0, 0.1);
  model.OnState(stray, Writer(9), 0.0, 0.2);
  CHECK(model.ignored() == 2);
  CHECK(model.StatusOf(1) == "never");
  CHECK(CountMarks(model, "ignored", 0) == 1);  // one mark per reason
}

TEST_CASE("live model: a state its writer may not write is ignored and counted, never shown") {
  LiveModel model(ThreeAgents(), kRun, "r");
  model.OnUnauthorised(2, 0.1);
  model.OnUnauthorised(3, 0.2);
  CHECK(model.ignored() == 2);
  CHECK(model.StatusOf(2) == "never");
  CHECK(model.StatusOf(3) == "never");
  CHECK(CountMarks(model, "ignored", 0) == 1);
}

TEST_CASE("live model: an agent silent while the others go on becomes stale") {
  LiveModel model(ThreeAgents(100), kRun, "r");
  AllWrite(model, 5, 0.0, {0.0, 2.0, 4.0});
  model.OnState(State(1, 6, 0.0), Writer(1), 0.0, 2.5);
  model.OnState(State(2, 6, 2.0), Writer(2), 0.0, 2.5);
  model.OnTimer(2.6);  // agent 3 last wrote at 0.0 (> stale_after_s = 2 s ago) and is behind
  CHECK(model.StatusOf(3) == "stale");
  CHECK(model.StatusOf(1) == "alive");
}

TEST_CASE("live model: updates are throttled to min_update_interval_s") {
  LiveModel model(ThreeAgents(100), kRun, "r");
  AllWrite(model, 1, 0.0, {0.0, 2.0, 4.0});
  REQUIRE(model.UpdateDue(0.0));
  REQUIRE(model.TakeUpdate(0.0));
  AllWrite(model, 2, 0.01, {0.0, 2.0, 4.0});
  CHECK_FALSE(model.UpdateDue(0.02));  // 20 ms after the last one: too early
  CHECK(model.UpdateDue(0.05));
  const auto next = model.NextUpdateTime(0.02);
  REQUIRE(next);
  CHECK(*next == Approx(0.05));
}

}  // namespace
}  // namespace deif::observer

namespace deif::observer {
namespace {

protocol::TruthMsg Truth(StepIndex step) {
  protocol::TruthMsg t;
  t.run = kRun;
  t.step = step;
  t.t_s = 0.1 * static_cast<double>(step);
  t.p_true = Vector2(0.1 * static_cast<double>(step), 0.0);
  return t;
}

protocol::RangeMsg Range(StepIndex step, AgentId id) {
  protocol::RangeMsg r;
  r.run = kRun;
  r.agent_id = id;
  r.step = step;
  r.measured = true;
  r.range_m = 2.0;
  r.variance_m2 = 5.3e-4;
  const double angle = 2.0 * static_cast<double>(id);
  r.p_sensor = Vector2(2.0 * std::cos(angle), 2.0 * std::sin(angle));
  r.roll_call = {1, 2, 3};
  return r;
}

TEST_CASE("live model: a later step's truth read before a step's ranges does not cut the step short") {
  // GIVEN the same three steps, once step by step and once as one batch with every truth
  // first (how a lagging observer takes them: topic by topic)
  LiveModel in_order(ThreeAgents(), kRun, "r");
  LiveModel truth_first(ThreeAgents(), kRun, "r");
  for (StepIndex k = 1; k <= 3; ++k) {
    in_order.OnTruth(Truth(k), 0.0);
    for (AgentId id = 1; id <= 3; ++id) in_order.OnRange(Range(k, id), Writer(10), 0.0);
    in_order.OnTimer(0.0);
  }
  for (StepIndex k = 1; k <= 3; ++k) truth_first.OnTruth(Truth(k), 0.0);
  for (StepIndex k = 1; k <= 3; ++k) {
    for (AgentId id = 1; id <= 3; ++id) truth_first.OnRange(Range(k, id), Writer(10), 0.0);
  }
  truth_first.OnTimer(0.0);
  // THEN the bound of step 1 (finalised in both) is the same, with three sensors: the
  // optimality ratio is defined (it is NaN without sensors)
  REQUIRE(!in_order.series().empty());
  REQUIRE(!truth_first.series().empty());
  const SeriesPoint& a = in_order.series().front();
  const SeriesPoint& b = truth_first.series().front();
  CHECK(a.step == 1);
  CHECK(b.step == 1);
  CHECK(std::isfinite(b.ratio));
  CHECK(b.pcrlb_m == a.pcrlb_m);
}

TEST_CASE("live model: the target's writers of different agents' ranges are one target") {
  // GIVEN ranges of step 1 for agents 1..3, each from another writer of one participant
  // (the target writes each agent's ranges with a writer of their own, docs/PROTOCOL.md)
  LiveModel model(ThreeAgents(), kRun, "r");
  const auto target_writer = [](int participant, int agent) {
    protocol::SenderKey key = Writer(participant);  // the first 12 bytes: the participant
    key[15] = static_cast<std::uint8_t>(agent);     // the last 4: the writer in it
    return key;
  };
  for (AgentId id = 1; id <= 3; ++id) model.OnRange(Range(1, id), target_writer(20, id), 0.1);
  // THEN no target restart is seen
  CHECK(CountMarks(model, "target_restart", 0) == 0);
  // WHEN two of those writers lose liveliness, the target is lost, once
  model.OnLiveliness(WriterKind::kRange, target_writer(20, 2), false, 0.2);
  model.OnLiveliness(WriterKind::kRange, target_writer(20, 3), false, 0.2);
  CHECK(CountMarks(model, "target_lost", 0) == 1);
  // WHEN another participant writes ranges, that is a new target
  model.OnRange(Range(2, 1), target_writer(21, 1), 0.3);
  CHECK(CountMarks(model, "target_restart", 0) == 1);
}

}  // namespace
}  // namespace deif::observer
