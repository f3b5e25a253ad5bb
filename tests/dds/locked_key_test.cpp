// Key hashes computed by several threads at once (docs/FASTDDS_NOTES.md, "Key hashes").
#include <catch2/catch.hpp>

#include <atomic>
#include <set>
#include <thread>
#include <vector>

#include "dds/locked_key.hpp"
#include "deifPubSubTypes.h"

namespace {

using eprosima::fastrtps::rtps::InstanceHandle_t;

InstanceHandle_t KeyOf(deif_msgs::ContributionPubSubType& type, int agent_id) {
  deif_msgs::Contribution sample;
  sample.agent_id(agent_id);
  InstanceHandle_t handle;
  type.getKey(&sample, &handle, /*force_md5=*/true);  // as Fast DDS does with security
  return handle;
}

}  // namespace

TEST_CASE("dds: key hashes computed on four threads at once are each sample's own") {
  constexpr int kIds = 8;
  deif::dds::LockedKey<deif_msgs::ContributionPubSubType> type;
  // The hash of each id, one at a time: an MD5 of the id, a different one per id.
  std::vector<InstanceHandle_t> expected;
  for (int id = 1; id <= kIds; ++id) expected.push_back(KeyOf(type, id));
  std::set<InstanceHandle_t> distinct(expected.begin(), expected.end());
  REQUIRE(distinct.size() == static_cast<std::size_t>(kIds));

  std::atomic<long> wrong{0};
  std::vector<std::thread> threads;
  for (int t = 0; t < 4; ++t) {
    threads.emplace_back([&, t] {
      for (int i = 0; i < 20000; ++i) {
        const int id = (t * 3 + i) % kIds + 1;
        if (!(KeyOf(type, id) == expected[static_cast<std::size_t>(id - 1)])) ++wrong;
      }
    });
  }
  for (std::thread& thread : threads) thread.join();
  CHECK(wrong.load() == 0);
}
