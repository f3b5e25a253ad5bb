// The in-process simulation: deterministic for a seed, equal to a centralized EIF replayed
// from its own artefacts, fault tolerant, and the deif_sim executable around it.
#include <catch2/catch.hpp>

#include <sys/wait.h>
#include <unistd.h>

#include <cmath>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <map>
#include <sstream>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>

#include "common/config/config.hpp"
#include "common/core/filters.hpp"
#include "common/sim/simulation.hpp"

namespace fs = std::filesystem;
using deif::Config;
using deif::ParseConfig;
using deif::RunSimulation;
using deif::SimulationMetrics;

namespace {

constexpr double kPi = 3.14159265358979323846;

fs::path FreshDir(const std::string& name) {
  const fs::path dir = fs::temp_directory_path() /
                       ("deif_simulation_test_" + name + "_" + std::to_string(::getpid()));
  fs::remove_all(dir);
  return dir;
}

std::string ReadText(const fs::path& path) {
  std::ifstream in(path, std::ios::binary);
  std::ostringstream text;
  text << in.rdbuf();
  return text.str();
}

// A CSV read back from disk: the header's columns and every row's fields as numbers.
struct Csv {
  std::vector<std::string> header;
  std::vector<std::vector<double>> rows;
  std::size_t Column(const std::string& name) const {
    for (std::size_t i = 0; i < header.size(); ++i) {
      if (header[i] == name) return i;
    }
    FAIL("no column " << name);
    return 0;
  }
};

std::vector<std::string> SplitComma(const std::string& line) {
  std::vector<std::string> fields;
  std::stringstream stream(line);
  for (std::string field; std::getline(stream, field, ',');) fields.push_back(field);
  return fields;
}

Csv ReadCsv(const fs::path& path) {
  std::ifstream in(path);
  REQUIRE(in.good());
  Csv csv;
  std::string line;
  std::getline(in, line);
  csv.header = SplitComma(line);
  while (std::getline(in, line)) {
    std::vector<double> row;
    for (const std::string& field : SplitComma(line)) row.push_back(std::strtod(field.c_str(), nullptr));
    REQUIRE(row.size() == csv.header.size());
    csv.rows.push_back(row);
  }
  return csv;
}

// The exit status of a shell command.
int RunCommand(const std::string& command) {
  const int status = std::system(command.c_str());
  REQUIRE(WIFEXITED(status));
  return WEXITSTATUS(status);
}

const char* const kFourAgents =
    "scenario: {seed: 7, steps: 120}\n"
    "agents:\n"
    "  count: 4\n"
    "  initial_angles_rad: [2.1818, 2.4500, 3.7160, 4.5167]\n"
    "  control_law: voronoi\n";

}  // namespace

TEST_CASE("The simulation is deterministic for a seed and differs for another seed",
          "[simulation]") {
  const Config config = ParseConfig(kFourAgents, "inline");
  const fs::path a = FreshDir("det_a");
  const fs::path b = FreshDir("det_b");
  const SimulationMetrics ma = RunSimulation(config, a.string());
  const SimulationMetrics mb = RunSimulation(config, b.string());
  for (const char* file :
       {"target.csv", "ranges.csv", "agent_1.csv", "agent_2.csv", "agent_3.csv", "agent_4.csv"}) {
    INFO(file);
    CHECK(ReadText(a / file) == ReadText(b / file));
  }
  CHECK(ma.rmse_m == mb.rmse_m);
  CHECK(ma.anees == mb.anees);
  CHECK(ma.pcrlb_rmse_m == mb.pcrlb_rmse_m);
  CHECK(ma.error_m == mb.error_m);

  Config other = config;
  other.scenario.seed = 8;
  const fs::path c = FreshDir("det_c");
  const SimulationMetrics mc = RunSimulation(other, c.string());
  CHECK(ReadText(a / "ranges.csv") != ReadText(c / "ranges.csv"));
  CHECK(ma.rmse_m != mc.rmse_m);
  fs::remove_all(a);
  fs::remove_all(b);
  fs::remove_all(c);
}

TEST_CASE("The simulation writes every artefact with the DESIGN.md headers", "[simulation]") {
  const Config config = ParseConfig("scenario: {steps: 5}\nagents: {count: 3}\n", "inline");
  const fs::path dir = FreshDir("headers");
  RunSimulation(config, dir.string());
  const auto first_line = [](const fs::path& p) {
    std::ifstream in(p);
    std::string line;
    std::getline(in, line);
    return line;
  };
  CHECK(first_line(dir / "target.csv") == "step,t,x_true,y_true");
  CHECK(first_line(dir / "ranges.csv") == "step,agent_id,range,variance,sensor_x,sensor_y");
  for (const char* agent : {"agent_1.csv", "agent_2.csv", "agent_3.csv"}) {
    CHECK(first_line(dir / agent) ==
          "step,t,x_est,y_est,p_xx,p_xy,p_yy,pos_x,pos_y,angle,alive,fused,rejected,dropped");
  }
  // One row per step in target.csv and every agent file; one range per agent and step.
  CHECK(ReadCsv(dir / "target.csv").rows.size() == 5);
  CHECK(ReadCsv(dir / "agent_2.csv").rows.size() == 5);
  CHECK(ReadCsv(dir / "ranges.csv").rows.size() == 15);
  fs::remove_all(dir);
}

TEST_CASE("Every agent equals a centralized EIF replayed over ranges.csv", "[simulation]") {
  const Config config = ParseConfig(kFourAgents, "inline");
  const fs::path dir = FreshDir("central");
  RunSimulation(config, dir.string());

  // Group the ranges by step, exactly as read back from disk.
  const Csv ranges = ReadCsv(dir / "ranges.csv");
  std::map<deif::StepIndex, std::vector<deif::RangeObservation>> by_step;
  for (const auto& row : ranges.rows) {
    deif::RangeObservation z;
    z.agent_id = static_cast<int>(row[ranges.Column("agent_id")]);
    z.range_m = row[ranges.Column("range")];
    z.variance_m2 = row[ranges.Column("variance")];
    z.p_sensor = deif::Vector2(row[ranges.Column("sensor_x")], row[ranges.Column("sensor_y")]);
    by_step[static_cast<deif::StepIndex>(row[ranges.Column("step")])].push_back(z);
  }
  deif::CentralizedEif central(config.filter.motion_model, deif::InitialState(config),
                               deif::InitialCovariance(config), config.sensing);
  std::vector<deif::Vector2> central_estimates;
  for (deif::StepIndex k = 1; k <= config.scenario.steps; ++k) {
    central.Step(k, by_step[k]);
    central_estimates.push_back(central.filter().PositionEstimate());
  }

  for (int id = 1; id <= 4; ++id) {
    const Csv agent = ReadCsv(dir / ("agent_" + std::to_string(id) + ".csv"));
    REQUIRE(agent.rows.size() == central_estimates.size());
    for (std::size_t i = 0; i < agent.rows.size(); ++i) {
      INFO("agent " << id << " step " << i + 1);
      CHECK(agent.rows[i][agent.Column("x_est")] ==
            Approx(central_estimates[i].x()).margin(1e-9).epsilon(0));
      CHECK(agent.rows[i][agent.Column("y_est")] ==
            Approx(central_estimates[i].y()).margin(1e-9).epsilon(0));
      CHECK(agent.rows[i][agent.Column("fused")] == 4);
    }
  }
  fs::remove_all(dir);
}

TEST_CASE("The metrics agree with the artefacts they summarise", "[simulation]") {
  const Config config = ParseConfig(kFourAgents, "inline");
  const fs::path dir = FreshDir("metrics");
  const SimulationMetrics m = RunSimulation(config, dir.string());
  const Csv target = ReadCsv(dir / "target.csv");
  double sum_squared = 0.0;
  double max_error = 0.0;
  int samples = 0;
  for (int id = 1; id <= 4; ++id) {
    const Csv agent = ReadCsv(dir / ("agent_" + std::to_string(id) + ".csv"));
    for (std::size_t i = 0; i < agent.rows.size(); ++i) {
      const double dx = agent.rows[i][agent.Column("x_est")] - target.rows[i][2];
      const double dy = agent.rows[i][agent.Column("y_est")] - target.rows[i][3];
      sum_squared += dx * dx + dy * dy;
      max_error = std::max(max_error, std::hypot(dx, dy));
      ++samples;
    }
  }
  CHECK(m.steps == 120);
  CHECK(m.final_alive == 4);
  CHECK(m.error_m.size() == 120);
  CHECK(m.pcrlb_m.size() == 120);
  CHECK(m.rmse_m == Approx(std::sqrt(sum_squared / samples)).epsilon(1e-12));
  CHECK(m.max_error_m == Approx(max_error).epsilon(1e-12));
  // The bound is below the achieved error, and the optimality ratio is a ratio.
  CHECK(m.pcrlb_rmse_m > 0.0);
  CHECK(m.pcrlb_rmse_m < m.rmse_m);
  CHECK(m.mean_optimality_ratio > 0.0);
  CHECK(m.mean_optimality_ratio <= 1.0);
  fs::remove_all(dir);
}

TEST_CASE("After a kill the three survivors spread to gaps of 2 pi / 3", "[simulation]") {
  // GIVEN four agents around a static target, agent 2 killed at step 50.
  const Config config = ParseConfig(
      "scenario: {steps: 250}\n"
      "target: {trajectory: static, start_m: [0, 0]}\n"
      "agents: {count: 4, control_law: voronoi}\n"
      "faults:\n"
      "  - {step: 50, action: kill, agent: 2}\n",
      "inline");
  const fs::path dir = FreshDir("kill");
  // WHEN the scenario runs to the end
  const SimulationMetrics m = RunSimulation(config, dir.string());
  // THEN agent 2 wrote its last row at step 49, and the others saw three members from 50.
  const Csv killed = ReadCsv(dir / "agent_2.csv");
  REQUIRE_FALSE(killed.rows.empty());
  CHECK(killed.rows.back()[0] == 49);
  std::vector<double> final_angles;
  for (int id : {1, 3, 4}) {
    const Csv agent = ReadCsv(dir / ("agent_" + std::to_string(id) + ".csv"));
    REQUIRE(agent.rows.size() == 250);
    CHECK(agent.rows[48][agent.Column("alive")] == 4);
    CHECK(agent.rows[49][agent.Column("alive")] == 3);
    CHECK(agent.rows[49][agent.Column("fused")] == 3);
    // The angle about the estimate, recomputed from the written position and estimate.
    const auto& last = agent.rows.back();
    final_angles.push_back(std::atan2(last[agent.Column("pos_y")] - last[agent.Column("y_est")],
                                      last[agent.Column("pos_x")] - last[agent.Column("x_est")]));
  }
  std::sort(final_angles.begin(), final_angles.end());
  const double gaps[] = {final_angles[1] - final_angles[0], final_angles[2] - final_angles[1],
                         2 * kPi - (final_angles[2] - final_angles[0])};
  for (const double gap : gaps) CHECK(std::abs(gap - 2 * kPi / 3) < kPi / 180);
  CHECK(m.final_alive == 3);
  CHECK(m.final_max_gap_error_rad < kPi / 180);
  fs::remove_all(dir);
}

TEST_CASE("A stopped agent is absent until it continues", "[simulation]") {
  const Config config = ParseConfig(
      "scenario: {steps: 30}\n"
      "agents: {count: 4}\n"
      "faults:\n"
      "  - {step: 10, action: stop, agent: 3}\n"
      "  - {step: 20, action: cont, agent: 3}\n",
      "inline");
  const fs::path dir = FreshDir("stop");
  const SimulationMetrics m = RunSimulation(config, dir.string());
  const Csv agent3 = ReadCsv(dir / "agent_3.csv");
  CHECK(agent3.rows.size() == 20);  // steps 1..9 and 20..30
  for (const auto& row : agent3.rows) CHECK((row[0] < 10 || row[0] >= 20));
  for (const auto& row : ReadCsv(dir / "ranges.csv").rows) {
    if (row[1] == 3) CHECK((row[0] < 10 || row[0] >= 20));
  }
  const Csv agent1 = ReadCsv(dir / "agent_1.csv");
  CHECK(agent1.rows[8][agent1.Column("alive")] == 4);   // step 9
  CHECK(agent1.rows[9][agent1.Column("alive")] == 3);   // step 10
  CHECK(agent1.rows[19][agent1.Column("alive")] == 4);  // step 20
  CHECK(m.final_alive == 4);
  fs::remove_all(dir);
}

TEST_CASE("A target restart drops every range of its step", "[simulation]") {
  const Config config = ParseConfig(
      "scenario: {steps: 10}\nagents: {count: 3}\nfaults:\n"
      "  - {step: 5, action: restart_target}\n",
      "inline");
  const fs::path dir = FreshDir("restart");
  RunSimulation(config, dir.string());
  int ranges_at_5 = 0;
  for (const auto& row : ReadCsv(dir / "ranges.csv").rows) ranges_at_5 += row[0] == 5 ? 1 : 0;
  CHECK(ranges_at_5 == 0);
  const Csv agent = ReadCsv(dir / "agent_1.csv");
  CHECK(agent.rows[4][agent.Column("fused")] == 0);  // step 5
  CHECK(agent.rows[5][agent.Column("fused")] == 3);  // step 6
  fs::remove_all(dir);
}

TEST_CASE("deif_sim rejects a bad config with exit 2, one line, and writes nothing",
          "[simulation][deif_sim]") {
  const fs::path dir = FreshDir("cli_bad");
  fs::create_directories(dir);
  const fs::path config = dir / "bad.yaml";
  std::ofstream(config) << "scenario:\n  steps: 10\nagents:\n  count: 1\n";
  const fs::path out = dir / "out";
  const int status = RunCommand(std::string(DEIF_SIM_EXE) + " --config " + config.string() +
                                " --out " + out.string() + " >" + (dir / "stdout").string() +
                                " 2>" + (dir / "stderr").string());
  CHECK(status == 2);
  const std::string err = ReadText(dir / "stderr");
  CHECK(err == "deif_sim: error: " + config.string() +
                   ":4: key 'agents.count': must be >= 2 (got 1)\n");
  CHECK_FALSE(fs::exists(out));
  fs::remove_all(dir);
}

TEST_CASE("deif_sim runs a good config, exits 0 and writes every artefact",
          "[simulation][deif_sim]") {
  const fs::path dir = FreshDir("cli_good");
  fs::create_directories(dir);
  const fs::path config = dir / "good.yaml";
  std::ofstream(config) << "scenario: {steps: 40, seed: 3}\nagents: {count: 3}\n";
  const fs::path out = dir / "run" / "nested";
  const int status = RunCommand(std::string(DEIF_SIM_EXE) + " --config " + config.string() +
                                " --out " + out.string() + " --seed 11 --steps 30 --quiet >" +
                                (dir / "stdout").string() + " 2>&1");
  CHECK(status == 0);
  for (const char* file : {"target.csv", "ranges.csv", "agent_1.csv", "agent_2.csv",
                           "agent_3.csv", "summary.json"}) {
    INFO(file);
    CHECK(fs::exists(out / file));
  }
  const nlohmann::json summary = nlohmann::json::parse(ReadText(out / "summary.json"));
  CHECK(summary.at("seed") == 11);
  CHECK(summary.at("config").at("source") == config.string());
  // The YAML in the summary is a config that parses, with the overrides applied.
  const Config used = ParseConfig(summary.at("config").at("yaml").get<std::string>(), "summary");
  CHECK(used.scenario.steps == 30);
  CHECK(used.scenario.seed == 11U);
  CHECK(summary.at("processes").at(0).at("name") == "deif_sim");
  CHECK(summary.at("processes").at(0).at("exit_status") == 0);
  const auto& metrics = summary.at("metrics");
  for (const char* key : {"rmse_m", "max_error_m", "final_max_gap_error_rad",
                          "mean_optimality_ratio", "pcrlb_rmse_m", "anees"}) {
    INFO(key);
    CHECK(metrics.at(key).is_number());
  }
  CHECK(metrics.at("final_alive") == 3);
  CHECK(metrics.at("steps") == 30);
  CHECK(ReadCsv(out / "target.csv").rows.size() == 30);
  fs::remove_all(dir);
}
