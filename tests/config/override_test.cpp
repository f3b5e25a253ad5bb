// Command-line overrides: "dotted.key=YAML value", applied to the document before it is
// checked, so they are checked like the file; an error in one names "--set dotted.key".
#include <catch2/catch.hpp>

#include <string>
#include <vector>

#include "common/config/config.hpp"
#include "config_test_support.hpp"

using deif::Config;
using deif::ConfigError;
using deif::ParseConfig;
using deif_test::CheckError;
using deif_test::ErrorOf;

namespace {

const char* const kFile =
    "scenario:\n"
    "  steps: 100\n"
    "agents:\n"
    "  count: 4\n"
    "  initial_angles_rad: [0.1, 0.2, 0.3, 0.4]\n"
    "faults:\n"
    "  - {step: 50, action: kill, agent: 4}\n";

}  // namespace

TEST_CASE("An override sets a scalar key", "[config][override]") {
  const Config c = ParseConfig(kFile, "f.yaml", {"network.domain_id=7", "scenario.seed=42"});
  CHECK(c.network.domain_id == 7);
  CHECK(c.scenario.seed == 42U);
  CHECK(c.scenario.steps == 100);  // the rest of the file stays
  CHECK(c.source == "f.yaml");
}

TEST_CASE("An override replaces a list", "[config][override]") {
  const Config c = ParseConfig(kFile, "f.yaml", {"faults=[{step: 10, action: stop, agent: 2}, "
                                                 "{step: 20, action: cont, agent: 2}]"});
  REQUIRE(c.faults.size() == 2);
  CHECK(c.faults[0].action == deif::FaultAction::kStop);
  CHECK(c.faults[1].step == 20);
  CHECK(ParseConfig(kFile, "f.yaml", {"faults=[]"}).faults.empty());
}

TEST_CASE("An override creates sections and keys the file does not have", "[config][override]") {
  const Config c = ParseConfig("", "empty.yaml", {"network_sim.loss=0.25", "target.start_m=[1, 2]"});
  CHECK(c.network_sim.loss == 0.25);
  CHECK(c.target.trajectory.start_m == deif::Vector2(1.0, 2.0));
}

TEST_CASE("A later override of the same key wins", "[config][override]") {
  CHECK(ParseConfig("", "x", {"agents.count=3", "agents.count=5"}).agents.count == 5);
}

TEST_CASE("An override's value is checked like the file, naming --set as the file", "[config][override]") {
  CheckError(ErrorOf(kFile, {"agents.count=1"}), "--set agents.count", 0, "agents.count",
             "must be in 2..512 (got 1)");
  CheckError(ErrorOf(kFile, {"scenario.steps=yes"}), "--set scenario.steps", 0, "scenario.steps",
             "expected an integer (got 'yes')");
  CHECK(std::string(ErrorOf(kFile, {"agents.count=1"}).what()) ==
        "--set agents.count: key 'agents.count': must be in 2..512 (got 1)");
}

TEST_CASE("An unknown key in an override is refused, naming the allowed keys", "[config][override]") {
  CheckError(ErrorOf(kFile, {"agents.cuont=3"}), "--set agents.cuont", 0, "agents.cuont",
             "unknown key; allowed: count, initial_angles_rad");
  CheckError(ErrorOf(kFile, {"agent.count=3"}), "--set agent.count", 0, "agent",
             "unknown key; allowed: scenario");
}

TEST_CASE("An override's own YAML errors name --set", "[config][override]") {
  CheckError(ErrorOf(kFile, {"faults=[{step: 1"}), "--set faults", 0, "", "YAML syntax error");
  CheckError(ErrorOf(kFile, {"scenario.steps=\t5"}), "--set scenario.steps", 0, "", "tab character");
  CheckError(ErrorOf(kFile, {"faults=[{step: 10, action: kill}]"}), "--set faults", 0,
             "faults[0].agent", "missing (action kill needs an agent id)");
}

TEST_CASE("A malformed override is refused", "[config][override]") {
  CheckError(ErrorOf(kFile, {"agents.count"}), "--set agents.count", 0, "",
             "expected dotted.key=value");
  CheckError(ErrorOf(kFile, {"=3"}), "--set =3", 0, "", "expected dotted.key=value");
  CheckError(ErrorOf(kFile, {"agents..count=3"}), "--set agents..count", 0, "",
             "not a dotted key");
  CheckError(ErrorOf(kFile, {"faults[0].step=3"}), "--set faults[0].step", 0, "",
             "not a dotted key");
}

TEST_CASE("An override below a key that is not a mapping is refused", "[config][override]") {
  CheckError(ErrorOf("network: 5\n", {"network.domain_id=3"}), "--set network.domain_id", 0,
             "network.domain_id", "cannot set it: network (bad.yaml:1) is '5', not a mapping");
  CheckError(ErrorOf("- a\n", {"agents.count=3"}), "bad.yaml", 1, "",
             "the top level must be a mapping");
}

TEST_CASE("Changing agents.count drops the file's angles of another length", "[config][override]") {
  const Config c = ParseConfig(kFile, "f.yaml", {"agents.count=6"});
  CHECK(c.agents.count == 6);
  CHECK(c.agents.initial_angles_rad.empty());  // evenly spaced
  CHECK(deif::InitialAngle(c, 2) == Approx(2.0 * 3.14159265358979323846 / 6.0));
}

TEST_CASE("Changing agents.count keeps the file's angles of the same length", "[config][override]") {
  const Config c = ParseConfig(kFile, "f.yaml", {"agents.count=4"});
  CHECK(c.agents.initial_angles_rad == std::vector<double>{0.1, 0.2, 0.3, 0.4});
}

TEST_CASE("Angles given with the count are kept and checked", "[config][override]") {
  const Config c =
      ParseConfig(kFile, "f.yaml", {"agents.count=5", "agents.initial_angles_rad=[1, 2, 3, 4, 5]"});
  CHECK(c.agents.initial_angles_rad == std::vector<double>{1.0, 2.0, 3.0, 4.0, 5.0});
  CheckError(ErrorOf(kFile, {"agents.count=5", "agents.initial_angles_rad=[1, 2]"}),
             "--set agents.initial_angles_rad", 0, "agents.initial_angles_rad",
             "length must equal agents.count = 5 (got 2)");
}

TEST_CASE("A limit lowered on the command line is blamed, not the file", "[config][override]") {
  CheckError(ErrorOf(kFile, {"scenario.steps=10"}), "--set scenario.steps", 0, "scenario.steps",
             "a step 50 lies beyond scenario.steps = 10 (faults[0].step at bad.yaml:7)");
  CheckError(ErrorOf(kFile, {"agents.count=3"}), "--set agents.count", 0, "agents.count",
             "agent 4 does not exist with agents.count = 3 (faults[0].agent at bad.yaml:7)");
  CheckError(ErrorOf("network:\n  participant_announcement_s: 1\n", {"network.participant_lease_s=0.5"}),
             "--set network.participant_lease_s", 0, "network.participant_lease_s",
             "participant_announcement_s must be < participant_lease_s");
}

TEST_CASE("A section given as a mapping replaces the whole section", "[config][override]") {
  const Config c = ParseConfig(kFile, "f.yaml", {"agents={count: 5, radius_m: 1.5}"});
  CHECK(c.agents.count == 5);
  CHECK(c.agents.radius_m == 1.5);
  CHECK(c.agents.initial_angles_rad.empty());
}

TEST_CASE("A multi-line override value names its own lines", "[config][override]") {
  CheckError(ErrorOf(kFile, {"faults=\n- {step: 1, action: kill, agent: 1}\n- {step: 0, action: kill, agent: 2}\n"}),
             "--set faults", 3, "faults[1].step", "must be in 1..10000000 (got 0)");
}

TEST_CASE("LoadConfig applies overrides to a file", "[config][override]") {
  const Config c = deif::LoadConfig(deif_test::SourcePath("configs/default.yaml"),
                                    {"agents.count=6", "scenario.steps=20"});
  CHECK(c.agents.count == 6);
  CHECK(c.scenario.steps == 20);
  CHECK(c.agents.initial_angles_rad.empty());
}
