// The in-process simulation: deterministic for a seed, equal to a centralized EIF replayed
// from its own artefacts, fault tolerant with faults on their exact step, and the deif_sim
// executable around it.
#include <catch2/catch.hpp>

#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <cmath>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <map>
#include <sstream>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>

#include "common/artefacts/artefacts.hpp"
#include "common/config/config.hpp"
#include "common/core/filters.hpp"
#include "common/sim/simulation.hpp"

namespace fs = std::filesystem;
using deif::AgentRow;
using deif::Config;
using deif::kPi;
using deif::ParseConfig;
using deif::sim::RunSimulation;
using deif::sim::SimulationResult;

namespace {

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

std::string FirstLine(const fs::path& path) {
  std::ifstream in(path);
  std::string line;
  std::getline(in, line);
  return line;
}

// The exit status of a shell command.
int RunCommand(const std::string& command) {
  const int status = std::system(command.c_str());
  REQUIRE(WIFEXITED(status));
  return WEXITSTATUS(status);
}

SimulationResult Simulate(const std::string& yaml, const std::string& out_dir = "") {
  const Config config = ParseConfig(yaml, "inline");
  deif::sim::SimulationOptions options;
  options.out_dir = out_dir;
  return RunSimulation(config, options);
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
  const SimulationResult a = Simulate(kFourAgents);
  const SimulationResult b = Simulate(kFourAgents);
  const SimulationResult c = Simulate(std::string(kFourAgents) + "network_sim: {}\n" +
                                      "filter: {}\n", "");
  std::string other = kFourAgents;
  other.replace(other.find("seed: 7"), 7, "seed: 8");
  const SimulationResult d = Simulate(other);
  REQUIRE(a.run.agents.at(1).size() == 120);
  for (std::size_t i = 0; i < 120; ++i) {
    CHECK(a.run.agents.at(1)[i].estimate_m == b.run.agents.at(1)[i].estimate_m);
    CHECK(a.run.agents.at(1)[i].estimate_m == c.run.agents.at(1)[i].estimate_m);
  }
  CHECK(a.run.agents.at(1)[50].estimate_m != d.run.agents.at(1)[50].estimate_m);
}

TEST_CASE("The simulation writes every artefact with the documented headers", "[simulation]") {
  const fs::path dir = FreshDir("headers");
  Simulate(kFourAgents, dir.string());
  CHECK(FirstLine(dir / "target.csv") == "step,t,x_true,y_true");
  CHECK(FirstLine(dir / "ranges.csv") == "step,agent_id,range,variance,sensor_x,sensor_y");
  // The contract's 13 columns first, then the extras.
  CHECK(FirstLine(dir / "agent_1.csv").rfind(
            "step,t,x_est,y_est,p_xx,p_xy,p_yy,pos_x,pos_y,angle,alive,fused,rejected", 0) == 0);
  CHECK(FirstLine(dir / "metrics.csv").rfind("step,t,rows,", 0) == 0);
  CHECK(deif::ReadAgentCsv((dir / "agent_4.csv").string()).size() == 120);
  fs::remove_all(dir);
}

TEST_CASE("Every agent equals a centralized EIF replayed over ranges.csv", "[simulation]") {
  const Config config = ParseConfig(kFourAgents, "inline");
  const fs::path dir = FreshDir("central");
  deif::sim::SimulationOptions options;
  options.out_dir = dir.string();
  RunSimulation(config, options);
  // The ranges exactly as read back from disk, grouped by step, in ascending id.
  std::map<deif::StepIndex, std::vector<deif::RangeObservation>> by_step;
  for (const deif::RangeRow& row : deif::ReadRangesCsv((dir / "ranges.csv").string())) {
    deif::RangeObservation z;
    z.agent_id = row.agent_id;
    z.range_m = row.range_m;
    z.variance_m2 = row.variance_m2;
    z.p_sensor = row.p_sensor;
    by_step[row.step].push_back(z);
  }
  deif::CentralizedEif central(config.filter.motion_model, deif::InitialState(config),
                               deif::InitialCovariance(config), config.sensing);
  std::vector<deif::Vector2> central_estimates;
  for (deif::StepIndex k = 1; k <= config.scenario.steps; ++k) {
    central.Step(k, by_step[k]);
    central_estimates.push_back(central.filter().PositionEstimate());
  }
  for (int id = 1; id <= 4; ++id) {
    const std::vector<AgentRow> rows = deif::ReadAgentCsv((dir / deif::AgentCsvName(id)).string());
    REQUIRE(rows.size() == central_estimates.size());
    for (std::size_t i = 0; i < rows.size(); ++i) {
      INFO("agent " << id << " step " << i + 1);
      CHECK((rows[i].estimate_m - central_estimates[i]).cwiseAbs().maxCoeff() <= 1e-9);
      CHECK(rows[i].fused == 4);
    }
  }
  fs::remove_all(dir);
}

TEST_CASE("The metrics agree with the artefacts they summarise", "[simulation]") {
  const SimulationResult r = Simulate(kFourAgents);
  double sum_squared = 0.0;
  double max_error = 0.0;
  int samples = 0;
  for (const auto& [id, rows] : r.run.agents) {
    for (const AgentRow& row : rows) {
      const double e = (row.estimate_m - r.run.truth[static_cast<std::size_t>(row.step - 1)].p_true).norm();
      sum_squared += e * e;
      max_error = std::max(max_error, e);
      ++samples;
    }
  }
  const auto& m = r.metrics;
  CHECK(samples == 480);
  CHECK(m.last_step == 120);
  CHECK(m.final_agents == 4);
  CHECK(m.per_step.size() == 120);
  CHECK(m.rmse_m == Approx(std::sqrt(sum_squared / samples)).epsilon(1e-12));
  CHECK(m.max_error_m == Approx(max_error).epsilon(1e-12));
  CHECK(m.agreement_fraction == 1.0);  // a perfect network: every step bit-identical
  // The bound is below the achieved error, and the optimality ratio is a ratio.
  CHECK(m.pcrlb_rmse_m > 0.0);
  CHECK(m.pcrlb_rmse_m < m.rmse_m);
  CHECK(m.mean_optimality_ratio > 0.0);
  CHECK(m.mean_optimality_ratio <= 1.0);
}

TEST_CASE("After a kill at step 50 the three survivors fuse three from step 50 and spread to "
          "gaps of 2 pi / 3",
          "[simulation]") {
  const SimulationResult r = Simulate(
      "scenario: {steps: 250}\n"
      "target: {trajectory: static, start_m: [0, 0]}\n"
      "agents: {count: 4, control_law: voronoi}\n"
      "faults:\n"
      "  - {step: 50, action: kill, agent: 2}\n");
  // The fault lands on its exact step: agent 2 wrote its last row at step 49.
  REQUIRE_FALSE(r.run.agents.at(2).empty());
  CHECK(r.run.agents.at(2).back().step == 49);
  std::vector<double> final_angles;
  for (int id : {1, 3, 4}) {
    const auto& rows = r.run.agents.at(id);
    REQUIRE(rows.size() == 250);
    CHECK(rows[48].fused == 4);
    CHECK(rows[49].fused == 3);
    CHECK(rows[49].complete);
    CHECK(rows[60].alive == 3);
    final_angles.push_back(std::atan2(rows.back().position_m.y() - rows.back().estimate_m.y(),
                                      rows.back().position_m.x() - rows.back().estimate_m.x()));
  }
  std::sort(final_angles.begin(), final_angles.end());
  const double gaps[] = {final_angles[1] - final_angles[0], final_angles[2] - final_angles[1],
                         2 * kPi - (final_angles[2] - final_angles[0])};
  for (const double gap : gaps) CHECK(std::abs(gap - 2 * kPi / 3) < kPi / 180);
  CHECK(r.metrics.final_agents == 3);
  CHECK(r.metrics.final_max_gap_error_rad < kPi / 180);
  CHECK(r.exit_codes.at("agent-2") == -9);
  CHECK(r.exit_codes.at("target") == 0);
}

TEST_CASE("A frozen agent is left out while frozen and, resumed, catches up exactly", "[simulation]") {
  const SimulationResult r = Simulate(
      "scenario: {steps: 40}\n"
      "agents: {count: 4}\n"
      "faults:\n"
      "  - {step: 10, action: stop, agent: 3}\n"
      "  - {step: 20, action: cont, agent: 3}\n");
  for (const auto& row : r.run.ranges) {
    if (row.agent_id == 3) CHECK((row.step < 10 || row.step >= 20));
  }
  const auto& agent1 = r.run.agents.at(1);
  CHECK(agent1[8].fused == 4);   // step 9
  CHECK(agent1[9].fused == 3);   // step 10
  CHECK(agent1[19].fused == 4);  // step 20: measured again
  // Every agent agrees at every step they all wrote, the resumed one included.
  CHECK(r.metrics.agreement_fraction == 1.0);
  CHECK(r.counters.at(3).adoptions == 0);
  CHECK(r.metrics.final_agents == 4);
}

TEST_CASE("A target restart loses no step and changes no estimate", "[simulation]") {
  const std::string base = "scenario: {steps: 30}\nagents: {count: 3}\n";
  const SimulationResult plain = Simulate(base);
  const SimulationResult restarted =
      Simulate(base + "faults:\n  - {step: 12, action: restart_target}\n");
  for (int id = 1; id <= 3; ++id) {
    const auto& a = plain.run.agents.at(id);
    const auto& b = restarted.run.agents.at(id);
    REQUIRE(b.size() == 30);
    for (std::size_t i = 0; i < a.size(); ++i) CHECK(a[i].estimate_m == b[i].estimate_m);
  }
  CHECK(restarted.exit_codes.at("target") == 0);
}

TEST_CASE("An agent frozen while the target restarts takes the new target's ranges once resumed",
          "[simulation]") {
  const SimulationResult r = Simulate(
      "scenario: {steps: 40}\n"
      "agents: {count: 4}\n"
      "faults:\n"
      "  - {step: 10, action: stop, agent: 3}\n"
      "  - {step: 15, action: restart_target}\n"
      "  - {step: 20, action: cont, agent: 3}\n");
  // Every process ends as planned: agent 3 learns at its return that the old target is gone.
  for (const auto& [name, code] : r.exit_codes) {
    CAPTURE(name);
    CHECK(code == 0);
  }
  const auto& agent3 = r.run.agents.at(3);
  REQUIRE(!agent3.empty());
  CHECK(agent3.back().step == 40);
  CHECK(agent3.back().fused == 4);
  CHECK(r.metrics.final_agents == 4);
  CHECK(r.metrics.agreement_fraction == 1.0);
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
  CHECK(err.rfind("deif_sim: error: " + config.string() + ":4: key 'agents.count': ", 0) == 0);
  CHECK(std::count(err.begin(), err.end(), '\n') == 1);
  CHECK_FALSE(fs::exists(out));
  fs::remove_all(dir);
}

TEST_CASE("deif_sim refuses an output folder it cannot write, before running anything",
          "[simulation][deif_sim]") {
  const fs::path dir = FreshDir("cli_out");
  fs::create_directories(dir);
  const int status = RunCommand(std::string(DEIF_SIM_EXE) + " --config " + DEIF_SOURCE_DIR +
                                "/configs/default.yaml --out /proc/deif_x >" +
                                (dir / "out").string() + " 2>" + (dir / "err").string());
  CHECK(status == 2);
  CHECK(ReadText(dir / "err").find("cannot write to the folder '/proc/deif_x'") != std::string::npos);
  fs::remove_all(dir);
}

TEST_CASE("deif_sim runs a good config with overrides, exits 0 and writes every artefact",
          "[simulation][deif_sim]") {
  const fs::path dir = FreshDir("cli_good");
  fs::create_directories(dir);
  const fs::path config = dir / "good.yaml";
  std::ofstream(config) << "scenario: {steps: 40, seed: 3}\nagents: {count: 3}\n";
  const fs::path out = dir / "run" / "nested";
  const int status = RunCommand(std::string(DEIF_SIM_EXE) + " --config " + config.string() +
                                " --out " + out.string() +
                                " --seed 11 --steps 30 --set agents.count=4 --quiet >" +
                                (dir / "stdout").string() + " 2>&1");
  CHECK(status == 0);
  for (const char* file : {"target.csv", "ranges.csv", "agent_1.csv", "agent_4.csv",
                           "metrics.csv", "summary.json"}) {
    INFO(file);
    CHECK(fs::exists(out / file));
  }
  const nlohmann::json summary = nlohmann::json::parse(ReadText(out / "summary.json"));
  CHECK(summary.at("seeds").at("scenario") == 11);
  CHECK(summary.at("config").at("source") == config.string());
  CHECK(summary.at("ok") == true);
  // The YAML in the summary is a config that parses, with the overrides applied.
  const Config used = ParseConfig(summary.at("config").at("yaml").get<std::string>(), "summary");
  CHECK(used.scenario.steps == 30);
  CHECK(used.scenario.seed == 11U);
  CHECK(used.agents.count == 4);
  const auto& metrics = summary.at("metrics");
  for (const char* key : {"rmse_m", "max_error_m", "final_max_gap_error_rad",
                          "mean_optimality_ratio", "pcrlb_rmse_m", "anees", "agreement_fraction"}) {
    INFO(key);
    CHECK(metrics.at(key).is_number());
  }
  CHECK(metrics.at("final_agents") == 4);
  CHECK(metrics.at("last_step") == 30);
  CHECK(deif::ReadTargetCsv((out / "target.csv").string()).size() == 30);

  // --evaluate recomputes the same metrics from the artefacts alone.
  const int evaluated = RunCommand(std::string(DEIF_SIM_EXE) + " --config " + config.string() +
                                   " --set agents.count=4 --evaluate " + out.string() + " >" +
                                   (dir / "evaluated.json").string());
  CHECK(evaluated == 0);
  const nlohmann::json again = nlohmann::json::parse(ReadText(dir / "evaluated.json"));
  CHECK(again.at("rmse_m") == metrics.at("rmse_m"));
  CHECK(again.at("agreement_fraction") == metrics.at("agreement_fraction"));
  fs::remove_all(dir);
}

namespace {

// The survivor's position error after `from_step`: RMS and largest [m].
std::pair<double, double> ErrorAfter(const SimulationResult& r, deif::AgentId id,
                                     deif::StepIndex from_step) {
  std::map<deif::StepIndex, deif::Vector2> truth;
  for (const auto& row : r.run.truth) truth[row.step] = row.p_true;
  double sum_sq = 0.0, worst = 0.0;
  int n = 0;
  for (const auto& row : r.run.agents.at(id)) {
    if (row.step <= from_step) continue;
    const double e = (row.estimate_m - truth.at(row.step)).norm();
    sum_sq += e * e;
    worst = std::max(worst, e);
    ++n;
  }
  REQUIRE(n > 0);
  return {std::sqrt(sum_sq / n), worst};
}

}  // namespace

TEST_CASE("A lone survivor stands still and does not run off after a mirror image",
          "[simulation]") {
  // One range fixes only the distance: the estimate can slide to the mirror side of the
  // sensor, and a sensor that keeps its place on the ring about that estimate follows it
  // away. Doing so, one of these two runs reached an error of 7.7 m and ended 5.2 m from the
  // origin (with configs/default.yaml, seed 5: 33 m), where every point of the figure eight
  // lies within 1.7 m of it.
  for (const int seed : {2, 5}) {
    const SimulationResult r = Simulate("scenario: {seed: " + std::to_string(seed) +
                                        ", steps: 400}\n"
                                        "agents: {count: 2, control_law: voronoi}\n"
                                        "faults:\n"
                                        "  - {step: 50, action: kill, agent: 2}\n");
    const auto& rows = r.run.agents.at(1);
    REQUIRE(rows.size() == 400);
    CHECK(rows.back().alive == 1);
    // It stands where it was at the kill: its last move was at step 50, the kill's step.
    for (std::size_t i = 50; i < rows.size(); ++i) CHECK(rows[i].position_m == rows[49].position_m);
    // The error stays within the scene: the circle of its range about a sensor that stands
    // 2 m from the figure eight.
    CHECK(ErrorAfter(r, 1, 50).second < 5.0);
  }
}

TEST_CASE("Two agents frozen while the third is alone: once back, the three track the target again",
          "[simulation]") {
  // configs/default.yaml, three agents; agents 1 and 2 frozen from step 50 to step 130:
  // agent 3 is alone for 80 steps, then the three fuse again. Had agent 3 circled its
  // estimate meanwhile (a first version), its error had reached 8 m by step 129; the three
  // fused into a mirror image that the gate then kept (agent 1's range rejected at 28 sigma),
  // and ran off with it, 34 m at step 300.
  const std::string file = std::string(DEIF_SOURCE_DIR) + "/configs/default.yaml";
  const std::vector<std::string> three = {"agents.count=3", "scenario.steps=300"};
  std::vector<std::string> frozen = three;
  frozen.push_back(
      "faults=[{step: 50, action: stop, agent: 1}, {step: 50, action: stop, agent: 2}, "
      "{step: 130, action: cont, agent: 1}, {step: 130, action: cont, agent: 2}]");
  const SimulationResult r = RunSimulation(deif::LoadConfig(file, frozen));
  const SimulationResult undisturbed = RunSimulation(deif::LoadConfig(file, three));
  const auto& rows = r.run.agents.at(3);
  REQUIRE(rows.size() == 300);
  CHECK(rows[100].alive == 1);
  CHECK(rows.back().alive == 3);
  CHECK(ErrorAfter(r, 3, 49).second < 2.5);
  // From 50 steps after the others are back, the error is that of the same run without the
  // faults (its RMS over those steps within 1.5 x).
  const auto rms_from = [](const SimulationResult& run, std::size_t from) {
    double sum_sq = 0.0;
    for (std::size_t i = from; i < run.metrics.per_step.size(); ++i) {
      sum_sq += run.metrics.per_step[i].max_error_m * run.metrics.per_step[i].max_error_m;
    }
    return std::sqrt(sum_sq / static_cast<double>(run.metrics.per_step.size() - from));
  };
  CHECK(rms_from(r, 180) < 1.5 * rms_from(undisturbed, 180));
}
