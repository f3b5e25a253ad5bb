// The corpus of malformed configs (tests/config/corpus/): every file is refused with the
// line, key and reason its line of expected.tsv names.
#include <catch2/catch.hpp>

#include <filesystem>
#include <fstream>
#include <set>
#include <sstream>
#include <string>
#include <vector>

#include "common/config/config.hpp"
#include "config_test_support.hpp"

using deif::ConfigError;

namespace {

struct Expected {
  std::string file;
  int line = 0;
  std::string key;  // "" for a file-level error ("-" in the manifest)
  std::string reason;
};

std::string CorpusDir() { return deif_test::SourcePath("tests/config/corpus"); }

std::vector<Expected> Manifest() {
  std::ifstream in(CorpusDir() + "/expected.tsv");
  std::vector<Expected> out;
  std::string line;
  while (std::getline(in, line)) {
    if (line.empty() || line[0] == '#') continue;
    std::vector<std::string> fields;
    std::istringstream cells(line);
    std::string cell;
    while (std::getline(cells, cell, '\t')) fields.push_back(cell);
    REQUIRE(fields.size() == 4);
    out.push_back({fields[0], std::stoi(fields[1]), fields[2] == "-" ? "" : fields[2], fields[3]});
  }
  return out;
}

}  // namespace

TEST_CASE("Every malformed config of the corpus is refused as its manifest says", "[config][corpus]") {
  const std::vector<Expected> manifest = Manifest();
  CHECK(manifest.size() >= 80);
  for (const Expected& expected : manifest) {
    DYNAMIC_SECTION(expected.file) {
      const std::string path = CorpusDir() + "/" + expected.file;
      REQUIRE(std::filesystem::is_regular_file(path));
      try {
        deif::LoadConfig(path);
        FAIL("accepted: " << path);
      } catch (const ConfigError& e) {
        deif_test::CheckError(e, path, expected.line, expected.key, expected.reason);
      }
    }
  }
}

TEST_CASE("Every file of the corpus has its line in the manifest", "[config][corpus]") {
  std::set<std::string> listed;
  for (const Expected& expected : Manifest()) CHECK(listed.insert(expected.file).second);
  for (const auto& entry : std::filesystem::directory_iterator(CorpusDir())) {
    const std::string name = entry.path().filename().string();
    if (name == "expected.tsv" || name == "README.md") continue;
    INFO(name);
    CHECK(listed.count(name) == 1);
  }
}

TEST_CASE("A config nested 200 000 levels deep is refused without a crash", "[config][corpus]") {
  constexpr int kDepth = 200000;
  const deif_test::TempFile file(
      "deep", "agents:\n  initial_angles_rad: " + std::string(kDepth, '[') +
                  std::string(kDepth, ']') + "\n");
  try {
    deif::LoadConfig(file.path());
    FAIL("accepted");
  } catch (const ConfigError& e) {
    CHECK(e.line() == 2);
    CHECK_THAT(std::string(e.what()), Catch::Contains("nested deeper than 32 levels"));
    CHECK_THAT(e.key(), Catch::StartsWith("agents.initial_angles_rad[0][0]"));
  }
}
