// The deif_config executable (built next to deif_sim in build/bin): its commands and exit
// statuses.
#include <catch2/catch.hpp>

#include <sys/wait.h>

#include <cstdlib>
#include <filesystem>
#include <string>

#include "common/config/config.hpp"
#include "common/config/reference.hpp"
#include "config_test_support.hpp"

namespace {

struct Result {
  int status = -1;
  std::string out;
  std::string err;
};

std::string Executable() {
  return (std::filesystem::path(DEIF_SIM_EXE).parent_path() / "deif_config").string();
}

// Runs deif_config with the arguments (shell words), capturing stdout and stderr.
Result Run(const std::string& arguments) {
  REQUIRE(std::filesystem::exists(Executable()));  // scripts/build builds it
  const deif_test::TempFile out("cli_out", "");
  const std::string out_path = out.dir() + "/stdout";
  const std::string err_path = out.dir() + "/stderr";
  const int raw = std::system((Executable() + " " + arguments + " >" + out_path + " 2>" + err_path).c_str());
  Result result;
  result.status = WIFEXITED(raw) ? WEXITSTATUS(raw) : -1;
  result.out = deif_test::ReadFile(out_path);
  result.err = deif_test::ReadFile(err_path);
  return result;
}

}  // namespace

TEST_CASE("deif_config --check accepts a good config with overrides", "[config][cli]") {
  const Result r = Run("--config " + deif_test::SourcePath("configs/default.yaml") +
                       " --set agents.count=6 --check");
  CHECK(r.status == 0);
  CHECK(r.out.empty());
  CHECK(r.err.empty());
}

TEST_CASE("deif_config --check refuses a bad config with one line and status 2", "[config][cli]") {
  const std::string path = deif_test::SourcePath("tests/config/corpus/count_one.yaml");
  const Result r = Run("--config " + path + " --check");
  CHECK(r.status == 2);
  CHECK(r.err == "deif_config: error: " + path + ":2: key 'agents.count': must be in 2..512 (got 1)\n");
  const Result o = Run("--config " + deif_test::SourcePath("configs/default.yaml") +
                       " --set scenario.steps=0 --check");
  CHECK(o.status == 2);
  CHECK(o.err == "deif_config: error: --set scenario.steps: key 'scenario.steps': must be in "
                 "1..10000000 (got 0)\n");
}

TEST_CASE("deif_config --print yaml prints the effective config", "[config][cli]") {
  const Result r = Run("--config " + deif_test::SourcePath("configs/default.yaml") +
                       " --set network.domain_id=7 --print yaml");
  REQUIRE(r.status == 0);
  const deif::Config c = deif::ParseConfig(r.out, "printed");
  CHECK(c.network.domain_id == 7);
  CHECK(c.filter.motion_model.process_noise == 3e-3);
}

TEST_CASE("deif_config --print json prints every section", "[config][cli]") {
  const Result r = Run("--config " + deif_test::SourcePath("configs/default.yaml") +
                       " --set 'faults=[{step: 3, action: restart_target}]' --print json");
  REQUIRE(r.status == 0);
  CHECK_THAT(r.out, Catch::Contains("\"count\": 4"));
  CHECK_THAT(r.out, Catch::Contains("\"r1_m\": \".inf\""));
  CHECK_THAT(r.out, Catch::Contains("\"action\": \"restart_target\""));
  CHECK_THAT(r.out, Catch::Contains("\"name\": \"default\""));
  CHECK_THAT(r.out, Catch::Contains("\"ros2_naming\": false"));
}

TEST_CASE("deif_config prints the references the library renders", "[config][cli]") {
  CHECK(Run("--reference-md").out == deif::RenderMarkdownReference());
  CHECK(Run("--reference-yaml").out == deif::RenderReferenceYaml());
}

TEST_CASE("deif_config refuses a command line that asks for nothing", "[config][cli]") {
  const Result r = Run("--config " + deif_test::SourcePath("configs/default.yaml"));
  CHECK(r.status == 2);
  CHECK_THAT(r.err, Catch::StartsWith("deif_config: error: "));
  CHECK(Run("--print xml --config x.yaml").status == 2);
}
