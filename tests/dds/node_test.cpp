// The DDS adapter's reader lifecycle (dds/node.hpp): two participants of one process on a
// DDS domain of this test's own (178).
#include <catch2/catch.hpp>

#include <algorithm>
#include <chrono>
#include <functional>
#include <future>
#include <sstream>
#include <cstdlib>
#include <stdexcept>
#include <string>
#include <variant>
#include <vector>

#include "common/config/config.hpp"
#include <fastdds/dds/domain/DomainParticipant.hpp>
#include <fastdds/dds/domain/DomainParticipantFactory.hpp>
#include <fastdds/dds/log/Log.hpp>
#include <fastdds/dds/subscriber/DataReader.hpp>
#include <fastdds/dds/subscriber/Subscriber.hpp>
#include <fastdds/dds/topic/Topic.hpp>

#include "deifPubSubTypes.h"

#include "dds/node.hpp"

namespace {

using deif::dds::Clock;
using deif::dds::Topic;

bool Within(double seconds, deif::dds::Node& waiter, const std::function<bool()>& done) {
  const auto deadline = Clock::now() + std::chrono::duration_cast<Clock::duration>(
                                           std::chrono::duration<double>(seconds));
  while (!done()) {
    if (Clock::now() >= deadline) return false;
    waiter.Wait(Clock::now() + std::chrono::milliseconds(20));
  }
  return true;
}

// Two parents of the tree exchange writing down into sub-partitions down.a and down.b, and a
// child reading down.a (docs/SCALING.md), in run `run`.
struct TwoParentsAndAChild {
  TwoParentsAndAChild(const deif::Config& config, const std::string& run)
      : parent_a(config, "node-test-" + run + "-a", run),
        parent_b(config, "node-test-" + run + "-b", run),
        child(config, "node-test-" + run + "-child", run) {
    parent_a.SetSubPartitions(Topic::kRelayDown, "down.a", "unused");
    parent_a.AddWriter(Topic::kRelayDown);
    parent_b.SetSubPartitions(Topic::kRelayDown, "down.b", "unused");
    parent_b.AddWriter(Topic::kRelayDown);
    child.SetSubPartitions(Topic::kRelayDown, "unused", "down.a");
    child.AddReader({Topic::kRelayDown, {}});
    parent_a.StartLiveliness();
    parent_b.StartLiveliness();
  }
  deif::dds::Node parent_a, parent_b, child;
};

// A batch sent down by relay `sender` of run `run`.
deif::protocol::BatchMsg DownBatch(const std::string& run, deif::AgentId sender, deif::StepIndex step) {
  deif::protocol::BatchMsg batch;
  batch.run = deif::protocol::RunTokenOf(run);
  batch.sender_id = sender;
  batch.step = step;
  batch.down = true;
  return batch;
}

}  // namespace

TEST_CASE("a removed reader is no longer matched by the peers' writers", "[dds][node]") {
  const deif::Config config = deif::ParseConfig(
      "agents: {count: 3}\nnetwork: {domain_id: 178, transport: udp}\n", "node_test");
  deif::dds::Node writer(config, "node-test-writer", "node_test");
  deif::dds::Node reader(config, "node-test-reader", "node_test");
  writer.AddWriter(Topic::kAgentState);
  reader.AddReader({Topic::kAgentState, deif::AgentId{2}});  // filtered to one id

  REQUIRE(Within(10.0, reader, [&] { return writer.MatchedReaders(Topic::kAgentState) == 1; }));
  reader.RemoveReader(Topic::kAgentState);
  CHECK(Within(10.0, reader, [&] { return writer.MatchedReaders(Topic::kAgentState) == 0; }));
  reader.RemoveReader(Topic::kAgentState);  // none left: nothing to do

  // The same reader (and its content filter's name) can be made again, and matches again.
  reader.AddReader({Topic::kAgentState, deif::AgentId{2}});
  CHECK(Within(10.0, reader, [&] { return writer.MatchedReaders(Topic::kAgentState) == 1; }));
  CHECK_THROWS_AS(reader.AddReader({Topic::kAgentState, deif::AgentId{3}}), std::logic_error);
}

TEST_CASE("each agent's reader gets its own ranges; a reader of all ranges gets every one",
          "[dds][node]") {
  const deif::Config config = deif::ParseConfig(
      "agents: {count: 3}\nnetwork: {domain_id: 178, transport: udp}\n", "node_test");
  deif::dds::Node target(config, "node-test-target", "node_ranges");
  deif::dds::Node agent(config, "node-test-agent-2", "node_ranges");
  deif::dds::Node observer(config, "node-test-observer", "node_ranges");
  target.AddWriter(Topic::kRange);
  agent.AddReader({Topic::kRange, deif::AgentId{2}});
  observer.AddReader({Topic::kRange, {}});
  target.StartLiveliness();
  // The target's writers of agents 1..3 all match the observer; only agent 2's the agent.
  REQUIRE(Within(10.0, agent, [&] {
    return agent.MatchedWriters(Topic::kRange) >= 1 && observer.MatchedWriters(Topic::kRange) >= 3 &&
           target.MatchedReaders(Topic::kRange) >= 2;
  }));
  CHECK(agent.MatchedWriters(Topic::kRange) == 1);
  CHECK(observer.MatchedWriters(Topic::kRange) == 3);
  CHECK(target.MatchedReaders(Topic::kRange) == 2);  // the agent's and the observer's
  // Agents 1..3, and an id no agent of the run has (only a test tool writes one).
  for (deif::AgentId id : {1, 2, 3, 7}) {
    deif::protocol::RangeMsg range;
    range.run = deif::protocol::RunTokenOf("node_ranges");
    range.agent_id = id;
    range.step = 1;
    target.Write(range);
  }
  std::vector<deif::AgentId> agent_got, observer_got;
  const auto take = [](deif::dds::Node& node, std::vector<deif::AgentId>& got) {
    for (const auto& event : node.Wait(Clock::now() + std::chrono::milliseconds(20))) {
      if (const auto* r = std::get_if<deif::dds::Received<deif::protocol::RangeMsg>>(&event)) {
        got.push_back(r->msg.agent_id);
      }
    }
  };
  REQUIRE(Within(10.0, agent, [&] {
    take(agent, agent_got);
    take(observer, observer_got);
    return observer_got.size() >= 4 && !agent_got.empty();
  }));
  take(agent, agent_got);  // nothing more comes for it
  CHECK(agent_got == std::vector<deif::AgentId>{2});
  std::sort(observer_got.begin(), observer_got.end());
  CHECK(observer_got == std::vector<deif::AgentId>{1, 2, 3, 7});
}

TEST_CASE("endpoints in different sub-partitions do not match; in the same one they do", "[dds][node]") {
  const deif::Config config = deif::ParseConfig(
      "agents: {count: 3}\nnetwork: {domain_id: 178, transport: udp}\n", "node_test");
  // One writer into sub-partition "a"; a reader of "a", a reader of "b", and a reader in
  // the run's own partition: only the first may match (the tree exchange's up and down
  // links, docs/SCALING.md).
  deif::dds::Node writer(config, "node-test-sub-writer", "node_sub");
  deif::dds::Node in_a(config, "node-test-sub-a", "node_sub");
  deif::dds::Node in_b(config, "node-test-sub-b", "node_sub");
  deif::dds::Node plain(config, "node-test-sub-plain", "node_sub");
  writer.SetSubPartitions(Topic::kContribution, "a", "unused");
  writer.AddWriter(Topic::kContribution);
  in_a.SetSubPartition(Topic::kContribution, "a");
  in_a.AddReader({Topic::kContribution, {}});
  in_b.SetSubPartitions(Topic::kContribution, "unused", "b");
  in_b.AddReader({Topic::kContribution, {}});
  plain.AddReader({Topic::kContribution, {}});
  writer.StartLiveliness();

  REQUIRE(Within(10.0, in_a, [&] { return in_a.MatchedWriters(Topic::kContribution) == 1; }));
  CHECK(writer.MatchedReaders(Topic::kContribution) == 1);
  // Give the other two the time a match takes, then check that none came.
  Within(1.0, in_b, [] { return false; });
  CHECK(in_b.MatchedWriters(Topic::kContribution) == 0);
  CHECK(plain.MatchedWriters(Topic::kContribution) == 0);
  CHECK(writer.MatchedReaders(Topic::kContribution) == 1);

  deif::protocol::ContributionMsg msg;
  msg.run = deif::protocol::RunTokenOf("node_sub");
  msg.agent_id = 1;
  msg.step = 1;
  writer.Write(msg);
  bool got = false;
  CHECK(Within(10.0, in_a, [&] {
    for (const auto& event : in_a.Wait(Clock::now() + std::chrono::milliseconds(20))) {
      got = got || std::holds_alternative<deif::dds::Received<deif::protocol::ContributionMsg>>(event);
    }
    return got;
  }));
  for (auto* other : {&in_b, &plain}) {
    for (const auto& event : other->Wait(Clock::now() + std::chrono::milliseconds(200))) {
      CHECK_FALSE(std::holds_alternative<deif::dds::Received<deif::protocol::ContributionMsg>>(event));
    }
  }
}

TEST_CASE("a reader moved to another sub-partition matches its new writer and keeps what it held",
          "[dds][node]") {
  const deif::Config config = deif::ParseConfig(
      "agents: {count: 3}\nnetwork: {domain_id: 178, transport: udp}\n", "node_test");
  // A child of the tree exchange moving from parent a to parent b (docs/SCALING.md): the
  // batch of a that arrived before the move is handed out after it, and b's batches come.
  TwoParentsAndAChild nodes(config, "node_move");
  deif::dds::Node& parent_a = nodes.parent_a;  // references, not a structured binding: the
  deif::dds::Node& parent_b = nodes.parent_b;  // lambdas below capture them (C++17)
  deif::dds::Node& child = nodes.child;
  // The child does not Wait() before the move, so the batch stays in its reader.
  REQUIRE(Within(10.0, parent_a, [&] { return parent_a.MatchedReaders(Topic::kRelayDown) == 1; }));
  parent_a.Write(DownBatch("node_move", 1, 7));
  REQUIRE(parent_a.WaitForAcknowledgments(10.0));  // it is in the child's reader

  child.MoveSubPartitions(Topic::kRelayDown, "unused", "down.b");
  // At once, without waiting for anything to arrive: the batch taken from the old reader.
  const auto t0 = Clock::now();
  const auto first = child.Wait(Clock::now() + std::chrono::seconds(5));
  CHECK(Clock::now() - t0 < std::chrono::seconds(1));
  std::vector<std::pair<deif::AgentId, deif::StepIndex>> got;
  const auto note = [&got](const std::vector<deif::dds::Event>& events) {
    for (const auto& event : events) {
      if (const auto* r = std::get_if<deif::dds::Received<deif::protocol::BatchMsg>>(&event)) {
        CHECK(r->msg.down);
        got.emplace_back(r->msg.sender_id, r->msg.step);
      }
    }
  };
  note(first);
  CHECK(got == std::vector<std::pair<deif::AgentId, deif::StepIndex>>{{1, 7}});

  REQUIRE(Within(10.0, child, [&] { return parent_b.MatchedReaders(Topic::kRelayDown) == 1; }));
  CHECK(Within(10.0, child, [&] { return parent_a.MatchedReaders(Topic::kRelayDown) == 0; }));
  parent_b.Write(DownBatch("node_move", 2, 8));
  CHECK(Within(10.0, parent_b, [&] {
    note(child.Wait(Clock::now() + std::chrono::milliseconds(20)));
    return got.size() >= 2;
  }));
  CHECK(got == std::vector<std::pair<deif::AgentId, deif::StepIndex>>{{1, 7}, {2, 8}});
}

TEST_CASE("a reader moved with a watch: the watch hears the old partition's writers' liveliness and hands "
          "out nothing",
          "[dds][node]") {
  const deif::Config config = deif::ParseConfig(
      "agents: {count: 3}\nnetwork: {domain_id: 178, transport: udp}\n", "node_test");
  // A child of the tree exchange leaving a parent that fell silent (docs/SCALING.md, "A
  // parent heard again"): its reader of a's partition stays as a watch.
  TwoParentsAndAChild nodes(config, "node_watch");
  deif::dds::Node& parent_a = nodes.parent_a;  // as above
  deif::dds::Node& parent_b = nodes.parent_b;
  deif::dds::Node& child = nodes.child;
  REQUIRE(Within(10.0, child, [&] { return parent_a.MatchedReaders(Topic::kRelayDown) == 1; }));
  CHECK(child.Watches(Topic::kRelayDown) == 0);

  child.MoveSubPartitions(Topic::kRelayDown, "unused", "down.b", /*keep_watch=*/true);
  CHECK(child.Watches(Topic::kRelayDown) == 1);
  REQUIRE(Within(10.0, child, [&] { return parent_b.MatchedReaders(Topic::kRelayDown) == 1; }));
  // The reader's side of the match may come a moment after the writer's: b's writer only.
  CHECK(Within(10.0, child, [&] { return child.MatchedWriters(Topic::kRelayDown) == 1; }));
  // a's writer still matches the watch, and what it writes comes out nowhere.
  Within(1.0, child, [] { return false; });
  CHECK(parent_a.MatchedReaders(Topic::kRelayDown) == 1);
  parent_a.Write(DownBatch("node_watch", 1, 7));
  REQUIRE(parent_a.WaitForAcknowledgments(10.0));  // it reached the watch
  parent_b.Write(DownBatch("node_watch", 2, 8));
  std::vector<deif::AgentId> senders;
  std::vector<deif::dds::LivelinessChange> changes;
  const auto note = [&](const std::vector<deif::dds::Event>& events) {
    for (const auto& event : events) {
      if (const auto* r = std::get_if<deif::dds::Received<deif::protocol::BatchMsg>>(&event)) {
        senders.push_back(r->msg.sender_id);
      } else if (const auto* l = std::get_if<deif::dds::LivelinessChange>(&event)) {
        changes.push_back(*l);
      }
    }
  };
  REQUIRE(Within(10.0, parent_b, [&] {
    note(child.Wait(Clock::now() + std::chrono::milliseconds(20)));
    return !senders.empty();
  }));
  note(child.Wait(Clock::now() + std::chrono::milliseconds(300)));
  CHECK(senders == std::vector<deif::AgentId>{2});

  // A writer that comes alive in a's partition is heard on the watch.
  deif::dds::Node parent_a2(config, "node-test-watch-a2", "node_watch");
  parent_a2.SetSubPartitions(Topic::kRelayDown, "down.a", "unused");
  parent_a2.AddWriter(Topic::kRelayDown);
  parent_a2.StartLiveliness();
  const deif::protocol::SenderKey a2 = parent_a2.WriterKey(Topic::kRelayDown);
  CHECK(Within(10.0, parent_a2, [&] {  // the child's events are taken by `note` alone
    note(child.Wait(Clock::now() + std::chrono::milliseconds(20)));
    return std::any_of(changes.begin(), changes.end(), [&](const deif::dds::LivelinessChange& c) {
      return c.topic == Topic::kRelayDown && c.writer == a2 && c.alive;
    });
  }));
  CHECK(senders == std::vector<deif::AgentId>{2});

  // Dropped, the watch is no longer matched.
  child.DropWatches(Topic::kRelayDown);
  CHECK(child.Watches(Topic::kRelayDown) == 0);
  CHECK(Within(10.0, child, [&] {
    return parent_a.MatchedReaders(Topic::kRelayDown) == 0 && parent_a2.MatchedReaders(Topic::kRelayDown) == 0;
  }));
  CHECK(parent_b.MatchedReaders(Topic::kRelayDown) == 1);
}

TEST_CASE("a writer moved to another sub-partition is a new writer, matched there only", "[dds][node]") {
  const deif::Config config = deif::ParseConfig(
      "agents: {count: 3}\nnetwork: {domain_id: 178, transport: udp}\n", "node_test");
  // A child of the tree exchange moving its writer up from parent a to parent b
  // (docs/SCALING.md; docs/FASTDDS_NOTES.md, "A reader moved and moved back").
  deif::dds::Node parent_a(config, "node-test-wmove-a", "node_wmove");
  deif::dds::Node parent_b(config, "node-test-wmove-b", "node_wmove");
  deif::dds::Node child(config, "node-test-wmove-child", "node_wmove");
  parent_a.SetSubPartitions(Topic::kRelayUp, "unused", "up.a");
  parent_a.AddReader({Topic::kRelayUp, {}});
  parent_b.SetSubPartitions(Topic::kRelayUp, "unused", "up.b");
  parent_b.AddReader({Topic::kRelayUp, {}});
  child.SetSubPartitions(Topic::kRelayUp, "up.a", "unused");
  child.AddWriter(Topic::kRelayUp);
  REQUIRE(Within(10.0, child, [&] { return child.MatchedReaders(Topic::kRelayUp) == 1; }));
  const deif::protocol::SenderKey before = child.WriterKey(Topic::kRelayUp);

  child.MoveSubPartitions(Topic::kRelayUp, "up.b", "unused");
  CHECK(child.WriterKey(Topic::kRelayUp) != before);
  CHECK(Within(10.0, child, [&] { return parent_b.MatchedWriters(Topic::kRelayUp) == 1; }));
  CHECK(Within(10.0, child, [&] { return parent_a.MatchedWriters(Topic::kRelayUp) == 0; }));
  // b's, as the new writer sees it (its side of the match may come a moment after b's).
  CHECK(Within(10.0, child, [&] { return child.MatchedReaders(Topic::kRelayUp) == 1; }));
  deif::protocol::BatchMsg batch;
  batch.run = deif::protocol::RunTokenOf("node_wmove");
  batch.sender_id = 3;
  batch.step = 9;
  child.Write(batch);
  std::vector<std::pair<deif::dds::Node*, deif::StepIndex>> got;
  CHECK(Within(10.0, child, [&] {
    for (deif::dds::Node* parent : {&parent_a, &parent_b}) {
      for (const auto& event : parent->Wait(Clock::now() + std::chrono::milliseconds(10))) {
        if (const auto* r = std::get_if<deif::dds::Received<deif::protocol::BatchMsg>>(&event)) {
          got.emplace_back(parent, r->msg.step);
        }
      }
    }
    return !got.empty();
  }));
  CHECK(got == std::vector<std::pair<deif::dds::Node*, deif::StepIndex>>{{&parent_b, 9}});
}

TEST_CASE("sub-partitions are refused with security or ROS 2 naming", "[dds][node]") {
  const deif::Config config = deif::ParseConfig(
      "agents: {count: 3}\nnetwork: {domain_id: 178, transport: udp, ros2_naming: true}\n", "node_test");
  deif::dds::Node node(config, "node-test-sub-ros2", "node_sub_ros2");
  CHECK_THROWS_AS(node.SetSubPartition(Topic::kContribution, "a"), std::logic_error);
}

namespace {

// What Fast DDS 2.9.1's shared-memory receive thread logs each time it fails on a message
// (SharedMemChannelResource::Receive): a warning of category RTPS_MSG_OUT.
void LogReceiveError() {
  using eprosima::fastdds::dds::Log;
  Log::QueueLog("Error receiving data: No such file or directory - 0x1 (0x2)",
                Log::Context{__FILE__, __LINE__, __func__, "RTPS_MSG_OUT"}, Log::Kind::Warning);
}

}  // namespace

TEST_CASE("a loop of shared-memory receive errors marks the process deaf; a few do not",
          "[dds][node]") {
  const deif::Config config = deif::ParseConfig(
      "agents: {count: 3}\nnetwork: {domain_id: 178, transport: udp}\n", "node_test");
  deif::dds::Node node(config, "node-test-deaf", "node_deaf");  // installs the log consumer
  using eprosima::fastdds::dds::Log;
  // Fast DDS formats warnings only when its verbosity lets them through.
  CHECK(Log::GetVerbosity() >= Log::Kind::Warning);

  for (int i = 0; i < 50; ++i) LogReceiveError();  // a socket closed, a peer gone: a handful
  Log::QueueLog("something else", Log::Context{__FILE__, __LINE__, __func__, "RTPS_MSG_OUT"},
                Log::Kind::Warning);
  Log::Flush();
  CHECK_FALSE(deif::dds::Node::ReceiveStuck());

  for (int i = 0; i < 2000; ++i) LogReceiveError();  // the stuck loop logs tens of thousands a second
  Log::Flush();
  CHECK(deif::dds::Node::ReceiveStuck());
}

namespace {

// What Fast DDS 2.9.1 logs each time a keyed reader's history misses a change it removes
// (DataReaderHistory::remove_change_sub): an error of category SUBSCRIBER.
void LogLostChange() {
  using eprosima::fastdds::dds::Log;
  Log::QueueLog("Change not found on this key, something is wrong",
                Log::Context{__FILE__, __LINE__, __func__, "SUBSCRIBER"}, Log::Kind::Error);
}

int g_reader_loops = 0;
void CountReaderLoop() { ++g_reader_loops; }

}  // namespace

TEST_CASE("a loop of lost-change errors calls the reader-loop handler once; a few do not",
          "[dds][node]") {
  const deif::Config config = deif::ParseConfig(
      "agents: {count: 3}\nnetwork: {domain_id: 178, transport: udp}\n", "node_test");
  deif::dds::Node node(config, "node-test-reader-loop", "node_reader_loop");  // installs the log consumer
  using eprosima::fastdds::dds::Log;
  g_reader_loops = 0;
  deif::dds::SetReaderLoopHandler(CountReaderLoop);

  for (int i = 0; i < 50; ++i) LogLostChange();  // a one-off, as a writer restarting can cause
  Log::Flush();
  CHECK(g_reader_loops == 0);

  for (int i = 0; i < 2000; ++i) LogLostChange();  // the loop logs thousands a second
  Log::Flush();
  CHECK(g_reader_loops == 1);
  for (int i = 0; i < 2000; ++i) LogLostChange();
  Log::Flush();
  CHECK(g_reader_loops == 1);  // once
  deif::dds::SetReaderLoopHandler(nullptr);
}

TEST_CASE("a reader made anew is reported once and gets its writer's history and new samples",
          "[dds][node]") {
  const deif::Config config = deif::ParseConfig(
      "agents: {count: 3}\nnetwork: {domain_id: 178, transport: udp}\n", "node_test");
  deif::dds::Node writer(config, "node-test-anew-writer", "node_anew");
  deif::dds::Node reader(config, "node-test-anew-reader", "node_anew");
  writer.AddWriter(Topic::kAgentState);  // transient local: a new reader gets what it holds
  reader.AddReader({Topic::kAgentState, {}});
  writer.StartLiveliness();
  std::vector<deif::StepIndex> got;
  const auto take = [&](deif::dds::Node& waiter) {
    for (const auto& event : waiter.Wait(Clock::now() + std::chrono::milliseconds(20))) {
      if (const auto* r = std::get_if<deif::dds::Received<deif::protocol::StateMsg>>(&event)) {
        got.push_back(r->msg.step);
      }
    }
  };
  REQUIRE(Within(10.0, reader, [&] { return writer.MatchedReaders(Topic::kAgentState) == 1; }));
  deif::protocol::StateMsg state;
  state.run = deif::protocol::RunTokenOf("node_anew");
  state.agent_id = 2;
  state.step = 7;
  writer.Write(state);
  REQUIRE(Within(10.0, writer, [&] {
    take(reader);
    return !got.empty();
  }));
  CHECK(reader.ReadersMadeAnew().empty());

  reader.MakeReaderAnewForTest(Topic::kAgentState);
  take(reader);
  CHECK(reader.ReadersMadeAnew() == std::vector<Topic>{Topic::kAgentState});
  CHECK(reader.ReadersMadeAnew().empty());  // reported once
  // The new reader matches, gets the writer's history again (as a late joiner) and what
  // is written since. (Written only once the history came: a writer keeps the newest
  // sample of an agent, and a newer one would take its place.)
  REQUIRE(Within(10.0, writer, [&] {
    take(reader);
    return got.size() >= 2;
  }));
  state.step = 8;
  writer.Write(state);
  CHECK(Within(10.0, writer, [&] {
    take(reader);
    return got.size() >= 3;
  }));
  CHECK(got == std::vector<deif::StepIndex>{7, 7, 8});

  // RemakeReader (a child of the tree that hears nothing from its parent) does the same,
  // and is not reported as a reader that handed out a sample twice.
  reader.RemakeReader(Topic::kAgentState);
  REQUIRE(Within(10.0, writer, [&] {
    take(reader);
    return got.size() >= 4;
  }));
  CHECK(got.back() == 8);  // the writer's history again
  CHECK(reader.ReadersMadeAnew().empty());
  CHECK(Within(10.0, writer, [&] { return writer.MatchedReaders(Topic::kAgentState) == 1; }));  // the old one gone
}

TEST_CASE("a node sees its run's target up before the target has any endpoint, and not another "
          "run's; nor once the target is gone", "[dds][node]") {
  const deif::Config config = deif::ParseConfig(
      "agents: {count: 3}\nnetwork: {domain_id: 178, transport: udp}\n", "node_test");
  deif::dds::Node agent(config, "agent-1", "node_target_a");
  deif::dds::Node stranger(config, "agent-1", "node_target_b");
  CHECK_FALSE(agent.TargetUp());
  {
    deif::dds::Node target(config, "target", "node_target_a");  // no writer, no reader
    deif::dds::Node not_a_target(config, "observer-1", "node_target_a");
    CHECK(Within(10.0, agent, [&] { return agent.TargetUp(); }));
    // The other run's agent, on the same domain, discovers it too, and does not take it.
    CHECK_FALSE(Within(1.0, stranger, [&] { return stranger.TargetUp(); }));
  }
  // Deleted: it said goodbye.
  CHECK(Within(10.0, agent, [&] { return !agent.TargetUp(); }));
}

TEST_CASE("a participant started again in place takes none of its predecessor's shared-memory ports",
          "[dds][node]") {
  // docs/FASTDDS_NOTES.md, "A port replaced under its listener": the ports listened on before
  // the restart are listed in DEIF_SHM_PORTS_USED, whether or not their files still exist.
  const deif::Config config = deif::ParseConfig(
      "agents: {count: 3}\nnetwork: {domain_id: 178, transport: shm}\n", "node_test");
  ::unsetenv(deif::dds::kShmPortsUsedVariable);
  std::vector<int> first;
  std::string used;
  {
    deif::dds::Node node(config, "node-test-agent-1", "node_ports");
    first = node.ShmPortsListened();
    used = deif::dds::ShmPortsUsedSoFar();
  }  // deleted: its port files are gone, so the lowest free id is its own again
  REQUIRE(first.size() == 2);  // metatraffic and user unicast
  CHECK(used == std::to_string(first[0]) + "," + std::to_string(first[1]));
  {
    deif::dds::Node again(config, "node-test-agent-1", "node_ports");
    CHECK(again.ShmPortsListened() == first);  // without the list: the same ports
  }
  ::setenv(deif::dds::kShmPortsUsedVariable, used.c_str(), 1);
  {
    deif::dds::Node again(config, "node-test-agent-1", "node_ports");
    const std::vector<int> ports = again.ShmPortsListened();
    REQUIRE(ports.size() == 2);
    CHECK(std::find(ports.begin(), ports.end(), first[0]) == ports.end());
    CHECK(std::find(ports.begin(), ports.end(), first[1]) == ports.end());
    // The next restart avoids both participants' ports.
    const std::string next = deif::dds::ShmPortsUsedSoFar();
    for (int port : {first[0], first[1], ports[0], ports[1]}) {
      CHECK(next.find(std::to_string(port)) != std::string::npos);
    }
  }
  ::unsetenv(deif::dds::kShmPortsUsedVariable);
}

TEST_CASE("the last wait for acknowledgements is bounded in all, not once per writer", "[dds][node]") {
  // A reader that stops acknowledging, as one of an agent that left without a goodbye: its
  // listener holds the receive thread from its first sample on, so the rest wait unread and
  // unacknowledged. It matches every one of the target's 16 writers of ranges (the run's
  // partition).
  namespace fdds = eprosima::fastdds::dds;
  struct Holding final : fdds::DataReaderListener {
    std::promise<void> release;
    std::shared_future<void> released = release.get_future().share();
    void on_data_available(fdds::DataReader*) override { released.wait(); }
  } holding;
  const deif::Config config = deif::ParseConfig(
      "agents: {count: 16}\nnetwork: {domain_id: 178, transport: udp}\n", "node_test");
  deif::dds::Node target(config, "node-test-target", "node_acks");
  target.AddWriter(Topic::kRange);
  target.StartLiveliness();

  auto* factory = fdds::DomainParticipantFactory::get_instance();
  // A GUID prefix of another process: within one process Fast DDS hands samples over directly
  // and counts them acknowledged whatever the reader does with them.
  fdds::DomainParticipantQos participant_qos = fdds::PARTICIPANT_QOS_DEFAULT;
  std::istringstream("01.0f.de.1f.ac.c5.00.01.00.00.00.01") >> participant_qos.wire_protocol().prefix;
  fdds::DomainParticipant* participant = factory->create_participant(178, participant_qos);
  REQUIRE(participant != nullptr);
  bool released = false;
  const auto release_and_delete = [&] {  // also when a REQUIRE below ends the test
    if (!released) holding.release.set_value();
    released = true;
    if (participant == nullptr) return;
    participant->delete_contained_entities();
    factory->delete_participant(participant);
    participant = nullptr;
  };
  struct AtExit {
    std::function<void()> run;
    ~AtExit() { run(); }
  } at_exit{release_and_delete};
  fdds::TypeSupport type(new deif_msgs::RangePubSubType());
  type.register_type(participant);
  fdds::Topic* topic = participant->create_topic("deif/range", type.get_type_name(), fdds::TOPIC_QOS_DEFAULT);
  fdds::SubscriberQos subscriber_qos = fdds::SUBSCRIBER_QOS_DEFAULT;
  subscriber_qos.partition().push_back("deif.node_acks");
  fdds::Subscriber* subscriber = participant->create_subscriber(subscriber_qos);
  fdds::DataReaderQos reader_qos = fdds::DATAREADER_QOS_DEFAULT;
  reader_qos.reliability().kind = fdds::RELIABLE_RELIABILITY_QOS;
  fdds::DataReader* stuck = subscriber->create_datareader(topic, reader_qos, &holding);
  REQUIRE(stuck != nullptr);
  // Both sides: each learns of a match from the other's announcement. The target's
  // participant matches a new reader with all its writers at once.
  REQUIRE(Within(10.0, target, [&] {
    fdds::SubscriptionMatchedStatus matched;
    stuck->get_subscription_matched_status(matched);
    return matched.current_count == 16 && target.MatchedReaders(Topic::kRange) == 1;
  }));

  for (deif::AgentId id = 1; id <= 16; ++id) {
    deif::protocol::RangeMsg range;
    range.run = deif::protocol::RunTokenOf("node_acks");
    range.agent_id = id;
    range.step = 1;
    target.Write(range);
  }
  // One at a time, writer by writer, this took at least 15 x 0.3 s.
  const auto start = Clock::now();
  CHECK_FALSE(target.WaitForAcknowledgments(0.3));
  const double waited_s = std::chrono::duration<double>(Clock::now() - start).count();
  CHECK(waited_s >= 0.3);
  CHECK(waited_s < 3.0);

  // Once that reader is gone, what is left is acknowledged.
  release_and_delete();
  CHECK(Within(10.0, target, [&] { return target.MatchedReaders(Topic::kRange) == 0; }));
  CHECK(target.WaitForAcknowledgments(0.3));
}
