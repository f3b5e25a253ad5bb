// The DDS adapter's reader lifecycle (dds/node.hpp): two participants of one process on a
// DDS domain of this test's own (178).
#include <catch2/catch.hpp>

#include <chrono>
#include <functional>
#include <stdexcept>

#include "common/config/config.hpp"
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
