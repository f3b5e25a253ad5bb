// The run artefacts (docs/ARTEFACTS.md): exact headers, rows flushed as written, and numbers
// that read back to the same doubles.
#include <catch2/catch.hpp>

#include <unistd.h>

#include <cmath>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <string>
#include <vector>

#include "common/artefacts/artefacts.hpp"
#include "common/artefacts/delay_histogram.hpp"

namespace fs = std::filesystem;

namespace {

// A fresh, empty folder for one test.
fs::path FreshDir(const std::string& name) {
  const fs::path dir = fs::temp_directory_path() /
                       ("deif_artefacts_test_" + name + "_" + std::to_string(::getpid()));
  fs::remove_all(dir);
  fs::create_directories(dir);
  return dir;
}

std::vector<std::string> ReadLines(const fs::path& path) {
  std::ifstream in(path);
  std::vector<std::string> lines;
  for (std::string line; std::getline(in, line);) lines.push_back(line);
  return lines;
}

}  // namespace

TEST_CASE("CSV headers are the documented ones (the agent csv's extras after its 13 columns)",
          "[artefacts]") {
  const fs::path dir = FreshDir("headers");
  {
    deif::TargetCsv target((dir / "target.csv").string());
    deif::RangesCsv ranges((dir / "ranges.csv").string());
    deif::AgentCsv agent((dir / deif::AgentCsvName(1)).string());
  }
  CHECK(ReadLines(dir / "target.csv") == std::vector<std::string>{"step,t,x_true,y_true"});
  CHECK(ReadLines(dir / "ranges.csv") ==
        std::vector<std::string>{"step,agent_id,range,variance,sensor_x,sensor_y"});
  CHECK(ReadLines(dir / "agent_1.csv") ==
        std::vector<std::string>{"step,t,x_est,y_est,p_xx,p_xy,p_yy,pos_x,pos_y,angle,alive,"
                                 "fused,rejected,dropped,late,misses,complete"});
  fs::remove_all(dir);
}

TEST_CASE("Agent csv files are named agent_<id>.csv", "[artefacts]") {
  CHECK(deif::AgentCsvName(1) == "agent_1.csv");
  CHECK(deif::AgentCsvName(12) == "agent_12.csv");
}

TEST_CASE("A row is on disk as soon as it is written, before the writer closes",
          "[artefacts]") {
  const fs::path dir = FreshDir("flush");
  deif::TargetCsv target((dir / "target.csv").string());
  target.Write({2, 0.5, deif::Vector2(1.5, -0.25)});
  // Read through a separate stream while the writer is still open.
  CHECK(ReadLines(dir / "target.csv") ==
        std::vector<std::string>{"step,t,x_true,y_true", "2,0.5,1.5,-0.25"});
  fs::remove_all(dir);
}

TEST_CASE("Rows list the fields in header order", "[artefacts]") {
  const fs::path dir = FreshDir("rows");
  {
    deif::RangesCsv ranges((dir / "ranges.csv").string());
    ranges.Write({3, 2, 1.25, 0.5, deif::Vector2(-1.0, 2.0)});
    deif::AgentCsv agent((dir / "agent_2.csv").string());
    deif::AgentRow row;
    row.step = 3;
    row.t_s = 0.75;
    row.estimate_m = deif::Vector2(0.25, -0.5);
    row.covariance << 1.0, 0.125, 0.125, 2.0;
    row.position_m = deif::Vector2(3.0, 4.0);
    row.angle_rad = -1.5;
    row.alive = 4;
    row.fused = 3;
    row.rejected = 7;
    row.dropped = 9;
    row.late = 5;
    row.deadline_misses = 2;
    row.complete = true;
    agent.Write(row);
  }
  CHECK(ReadLines(dir / "ranges.csv").at(1) == "3,2,1.25,0.5,-1,2");
  CHECK(ReadLines(dir / "agent_2.csv").at(1) ==
        "3,0.75,0.25,-0.5,1,0.125,2,3,4,-1.5,4,3,7,9,5,2,1");
  fs::remove_all(dir);
}

TEST_CASE("Append mode keeps the rows a killed process wrote and adds no second header",
          "[artefacts]") {
  const fs::path dir = FreshDir("append");
  {
    deif::TargetCsv first((dir / "target.csv").string());
    first.Write({1, 0.1, deif::Vector2(1.0, 2.0)});
  }
  {
    deif::TargetCsv restarted((dir / "target.csv").string(), deif::CsvMode::kAppend);
    restarted.Write({2, 0.2, deif::Vector2(3.0, 4.0)});
  }
  CHECK(ReadLines(dir / "target.csv") ==
        std::vector<std::string>{"step,t,x_true,y_true", "1,0.10000000000000001,1,2",
                                 "2,0.20000000000000001,3,4"});
  fs::remove_all(dir);
}

TEST_CASE("The readers return what the writers wrote and skip a torn final row", "[artefacts]") {
  const fs::path dir = FreshDir("read");
  {
    deif::AgentCsv agent((dir / "agent_1.csv").string());
    deif::AgentRow row;
    row.step = 4;
    row.estimate_m = deif::Vector2(0.1, -0.2);
    row.covariance << 1.0, 0.5, 0.5, 3.0;
    row.late = 6;
    row.complete = true;
    agent.Write(row);
  }
  std::ofstream(dir / "agent_1.csv", std::ios::app) << "5,0.5,0.1";  // a kill -9 mid-row
  const std::vector<deif::AgentRow> rows = deif::ReadAgentCsv((dir / "agent_1.csv").string());
  REQUIRE(rows.size() == 1);
  CHECK(rows[0].step == 4);
  CHECK(rows[0].estimate_m == deif::Vector2(0.1, -0.2));
  CHECK(rows[0].covariance(1, 0) == 0.5);
  CHECK(rows[0].late == 6);
  CHECK(rows[0].complete);
  CHECK(deif::ReadTargetCsv((dir / "missing.csv").string()).empty());
  std::ofstream(dir / "bad.csv") << "step,t,x_true,y_true\n1,x,2,3\n";
  CHECK_THROWS_WITH(deif::ReadTargetCsv((dir / "bad.csv").string()), Catch::Contains("bad.csv:2"));
  fs::remove_all(dir);
}

TEST_CASE("FormatDouble writes 17 significant digits that read back exactly", "[artefacts]") {
  // 0.1 is 0x3FB999999999999A = 0.1000000000000000055511151231257827...
  CHECK(deif::FormatDouble(0.1) == "0.10000000000000001");
  CHECK(deif::FormatDouble(2.0) == "2");
  for (const double value : {1.0 / 3.0, -2.5e-300, 6.02214076e23, 0.1 + 0.2, 1e-17}) {
    CHECK(std::strtod(deif::FormatDouble(value).c_str(), nullptr) == value);
  }
}

TEST_CASE("A CSV that cannot be created throws naming the path", "[artefacts]") {
  const std::string path = "/nonexistent_dir_for_deif/target.csv";
  CHECK_THROWS_WITH(deif::TargetCsv(path), Catch::Contains(path));
}

TEST_CASE("A delay histogram's quantiles are within one bin above the true ones", "[artefacts]") {
  deif::DelayHistogram h;
  CHECK(h.count() == 0);
  CHECK(h.Quantile(0.5) == 0.0);
  // 1, 2, ..., 1000 ms: the true p50 is 500 ms, p99 990 ms.
  for (int ms = 1; ms <= 1000; ++ms) h.Add(1e-3 * ms);
  CHECK(h.count() == 1000);
  CHECK(h.max_s() == Approx(1.0));
  CHECK(h.Quantile(0.5) >= 0.500);
  CHECK(h.Quantile(0.5) <= 0.500 * 1.13);
  CHECK(h.Quantile(0.99) >= 0.990);
  CHECK(h.Quantile(0.99) <= 1.0);  // never above the largest delay seen
  CHECK(h.Quantile(1.0) == Approx(1.0));
}

TEST_CASE("A delay histogram counts negative, tiny and huge delays at its ends", "[artefacts]") {
  deif::DelayHistogram h;
  h.Add(-0.5);  // two hosts' clocks
  h.Add(std::nan(""));
  h.Add(1e-9);
  CHECK(h.count() == 3);
  CHECK(h.max_s() == 1e-9);
  CHECK(h.Quantile(1.0) <= 1e-5 * std::pow(10.0, 1.0 / 20));
  h.Add(1e6);  // beyond the last bin: counted there, its max kept
  CHECK(h.count() == 4);
  CHECK(h.max_s() == 1e6);
  CHECK(h.Quantile(1.0) == Approx(100.0));  // the last bin's upper edge
}
