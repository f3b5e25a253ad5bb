// Counters carried across a process's restarts (dds/counters.hpp, docs/ARTEFACTS.md).
#include <catch2/catch.hpp>

#include <cstdio>
#include <filesystem>
#include <fstream>

#include <sstream>

#include <spdlog/sinks/null_sink.h>
#include <spdlog/sinks/ostream_sink.h>

#include "dds/counters.hpp"

using deif::dds::AddEarlierCounters;
using deif::dds::EarlierCounters;
using nlohmann::json;

TEST_CASE("A process started again adds its counts to those of its earlier process", "[counters]") {
  const json earlier = {{"deadline_misses", 60},  {"late", 3},
                        {"grace_factor", 2.0},     {"adoptions", 0},
                        {"by_reason", {{"dropped: too_old", 5}, {"rejected: second_target", 1}}},
                        {"delivery_ms", {{"range", {{"count", 90}, {"p50", 1.5}}}}}};
  const json now = {{"deadline_misses", 2},  {"late", 0},
                    {"grace_factor", 1.0},   {"adoptions", 1},
                    {"by_reason", {{"dropped: too_old", 7}, {"dropped: skipped_step", 4}}},
                    {"delivery_ms", {{"range", {{"count", 20}, {"p50", 0.9}}}}}};
  const json sum = AddEarlierCounters(earlier, now);
  CHECK(sum["deadline_misses"] == 62);
  CHECK(sum["late"] == 3);
  CHECK(sum["adoptions"] == 1);
  CHECK(sum["by_reason"]["dropped: too_old"] == 12);
  CHECK(sum["by_reason"]["dropped: skipped_step"] == 4);
  CHECK(sum["by_reason"]["rejected: second_target"] == 1);
  // The state at the end and the percentiles are the new process's own.
  CHECK(sum["grace_factor"] == 1.0);
  CHECK(sum["delivery_ms"]["range"]["count"] == 20);
}

TEST_CASE("Earlier counters that are missing or unreadable count as none", "[counters]") {
  auto log = std::make_shared<spdlog::logger>("test", std::make_shared<spdlog::sinks::null_sink_mt>());
  const std::filesystem::path dir = std::filesystem::temp_directory_path() / "deif_counters_test";
  std::filesystem::create_directories(dir);
  const std::string path = (dir / "agent_1.counters.json").string();
  std::filesystem::remove(path);
  CHECK(EarlierCounters(path, *log) == json::object());
  std::ofstream(path) << "{\"deadline_misses\": 6";  // cut short, as by a kill mid-write
  CHECK(EarlierCounters(path, *log) == json::object());
  std::ofstream(path) << "[1, 2]";
  CHECK(EarlierCounters(path, *log) == json::object());
  std::ofstream(path) << "{\"deadline_misses\": 6}";
  CHECK(EarlierCounters(path, *log)["deadline_misses"] == 6);
  // A count that is not a number in either file is left as the new process has it.
  CHECK(AddEarlierCounters(json{{"late", "x"}}, json{{"late", 2}})["late"] == 2);
  std::filesystem::remove_all(dir);
}

TEST_CASE("Counters are written whole, over the ones written before", "[counters]") {
  auto log = std::make_shared<spdlog::logger>("test", std::make_shared<spdlog::sinks::null_sink_mt>());
  const std::filesystem::path dir = std::filesystem::temp_directory_path() / "deif_counters_write_test";
  std::filesystem::remove_all(dir);
  std::filesystem::create_directories(dir);
  const std::string path = (dir / "agent_1.counters.json").string();
  deif::dds::WriteCounters(path, json{{"late", 1}, {"deadline_misses", 9}}, *log);
  CHECK(EarlierCounters(path, *log) == json{{"late", 1}, {"deadline_misses", 9}});
  deif::dds::WriteCounters(path, json{{"late", 2}}, *log);
  CHECK(EarlierCounters(path, *log) == json{{"late", 2}});
  // Nothing but the file is left beside it.
  int files = 0;
  for (const auto& entry : std::filesystem::directory_iterator(dir)) {
    CHECK(entry.path().filename() == "agent_1.counters.json");
    ++files;
  }
  CHECK(files == 1);
  // A folder that is gone: said once (not at every write), not thrown, and nothing is written.
  std::ostringstream said;
  auto told = std::make_shared<spdlog::logger>("told", std::make_shared<spdlog::sinks::ostream_sink_mt>(said));
  const std::string nowhere = (dir / "gone" / "agent_1.counters.json").string();
  CHECK_NOTHROW(deif::dds::WriteCounters(nowhere, json{{"late", 3}}, *told));
  CHECK_NOTHROW(deif::dds::WriteCounters(nowhere, json{{"late", 4}}, *told));
  CHECK_FALSE(std::filesystem::exists(nowhere));
  const std::string text = said.str();
  std::size_t times = 0;
  for (std::size_t at = text.find("cannot write"); at != std::string::npos; at = text.find("cannot write", at + 1)) {
    ++times;
  }
  CHECK(times == 1);
  std::filesystem::remove_all(dir);
}
