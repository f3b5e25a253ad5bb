// The schema is the one place a key is declared: the struct defaults, the YAML output, the
// reference documentation (docs/CONFIG.md) and configs/default.yaml must agree with it.
#include <catch2/catch.hpp>

#include <filesystem>
#include <map>
#include <set>
#include <sstream>
#include <string>
#include <vector>

#include "common/config/config.hpp"
#include "common/config/document.hpp"
#include "common/config/reference.hpp"
#include "common/config/schema.hpp"
#include "common/config/schema_access.hpp"
#include "config_test_support.hpp"

using deif::Config;
using deif::KeySpec;
using deif::KeyType;
using deif::ParseConfig;
using deif_test::Fingerprint;
using deif_test::ReadFile;
using deif_test::SourcePath;

namespace {

// Every shipped config: configs/, configs/thesis/, configs/beyond/, the multi-process tests'.
std::vector<std::string> ShippedConfigs() {
  std::vector<std::string> paths;
  for (const char* dir : {"configs", "configs/thesis", "configs/beyond", "tests/multiprocess/configs"}) {
    for (const auto& entry : std::filesystem::directory_iterator(SourcePath(dir))) {
      if (entry.path().extension() == ".yaml") paths.push_back(entry.path().string());
    }
  }
  return paths;
}

// The value of the dotted key (section.name, section.nested.name, or a top-level name) in a
// document, or nullptr.
const deif::DocNode* Lookup(const deif::DocNode& root, const KeySpec& spec) {
  const deif::DocNode* node = &root;
  for (const std::string& part : deif::KeyPath(spec)) {
    node = node->Find(part);
    if (node == nullptr) return nullptr;
  }
  return node;
}

template <typename Record>
void CheckRecordDefaults(const KeySpec& list) {
  const Record element{};
  for (const KeySpec& field : list.fields) {
    if (field.default_yaml.empty()) continue;
    INFO(field.key);
    const auto value = field.access->get(&element);
    REQUIRE(value.has_value());
    CHECK(deif::ValueYaml(field, *value) == field.default_yaml);
  }
}

}  // namespace

TEST_CASE("The struct defaults are the schema's defaults", "[config][schema]") {
  const Config defaults{};
  int keys = 0;
  deif::VisitConfig(defaults, [&](const KeySpec& spec, const std::string& yaml) {
    INFO(spec.key);
    CHECK(yaml == spec.default_yaml);
    ++keys;
  });
  CHECK(keys == static_cast<int>(deif::Schema().size()));
  CheckRecordDefaults<deif::FaultConfig>(*deif::FindKey("faults"));
  CheckRecordDefaults<deif::PartitionConfig>(*deif::FindKey("network_sim.partitions"));
  // The defaults this project chose on purpose (see the descriptions).
  CHECK(defaults.network.participant_lease_s == 5.0);
  CHECK(defaults.network.participant_announcement_s == 0.5);
}

TEST_CASE("An empty document parses to the struct defaults", "[config][schema]") {
  CHECK(Fingerprint(ParseConfig("", "empty")) == Fingerprint(Config{}));
}

TEST_CASE("Every key is documented", "[config][schema]") {
  std::set<std::string> seen;
  const auto check = [&](const KeySpec& spec) {
    INFO(spec.key);
    CHECK(seen.insert(spec.key).second);
    CHECK(deif::FindKey(spec.key) == &spec);
    CHECK(spec.description.size() > 10);
    CHECK(spec.description.back() == '.');
    CHECK(spec.description.find_first_of("|\n") == std::string::npos);  // a Markdown cell
    CHECK(spec.range_note.find('|') == std::string::npos);
    CHECK_FALSE(spec.TypeText().empty());
    CHECK((spec.required || !spec.default_yaml.empty() || !spec.range_note.empty()));
  };
  for (const KeySpec& spec : deif::Schema()) {
    check(spec);
    for (const KeySpec& field : spec.fields) check(field);
  }
  CHECK(seen.size() >= 60);
}

TEST_CASE("Every number has a range, and every duration is at most a day", "[config][schema]") {
  const auto check = [](const KeySpec& spec) {
    INFO(spec.key);
    switch (spec.type) {
      case KeyType::kDouble:
      case KeyType::kVector2:
      case KeyType::kDoubleList:
        CHECK(spec.min.has_value());
        CHECK(spec.max.has_value());
        break;
      case KeyType::kInt:
      case KeyType::kInt64:
      case KeyType::kIntList:
        // Agent ids are bounded by agents.count, a rule after the table (and said so).
        if (!spec.min || !spec.max) {
          CHECK_THAT(spec.range_note, Catch::Contains("1..agents.count"));
        } else {
          CHECK(spec.min->value >= -2147483648.0);
          CHECK(spec.max->value <= 2147483647.0);
        }
        break;
      default:
        break;
    }
    if (spec.name.size() > 2 && spec.name.compare(spec.name.size() - 2, 2, "_s") == 0) {
      REQUIRE(spec.max.has_value());
      CHECK(spec.max->value <= 86400.0);
      CHECK(spec.unit == "s");
    }
  };
  for (const KeySpec& spec : deif::Schema()) {
    check(spec);
    for (const KeySpec& field : spec.fields) check(field);
  }
}

TEST_CASE("Enum keys list their enum's names, and the names round-trip", "[config][schema]") {
  CHECK(deif::FindKey("scenario.mode")->enum_names == deif::EnumNames<deif::StepMode>());
  CHECK(deif::FindKey("network.transport")->enum_names == deif::EnumNames<deif::TransportKind>());
  CHECK(deif::FindKey("network.discovery")->enum_names == deif::EnumNames<deif::DiscoveryKind>());
  CHECK(deif::FindKey("faults[].action")->enum_names == deif::EnumNames<deif::FaultAction>());
  for (const auto& entry : deif::EnumTable<deif::TrajectoryKind>()) {
    deif::TrajectoryKind kind{};
    REQUIRE(deif::FromString(entry.name, &kind));
    CHECK(kind == entry.value);
    CHECK(std::string(deif::ToString(kind)) == entry.name);
  }
  deif::ControlLawKind law = deif::ControlLawKind::kMidpoint;
  CHECK_FALSE(deif::FromString("fastest", &law));
  CHECK(law == deif::ControlLawKind::kMidpoint);
  CHECK(std::string(deif::ToString(deif::TransportKind::kShm)) == "shm");
  CHECK(std::string(deif::ToString(deif::DiscoveryKind::kServer)) == "server");
}

TEST_CASE("Every shipped config round-trips through ToYaml to an identical Config", "[config][schema]") {
  const std::vector<std::string> paths = ShippedConfigs();
  CHECK(paths.size() >= 40);
  for (const std::string& path : paths) {
    INFO(path);
    const Config a = deif::LoadConfig(path);
    const std::string yaml = deif::ToYaml(a);
    const Config b = ParseConfig(yaml, "again");
    CHECK(Fingerprint(b) == Fingerprint(a));
    CHECK(deif::ToYaml(b) == yaml);
  }
}

TEST_CASE("ToYaml writes every key of the schema", "[config][schema]") {
  const deif::DocNode root = deif::ReadDocument(deif::ToYaml(Config{}), "out");
  REQUIRE(root.IsMap());
  std::size_t sections = 0;
  for (const deif::SectionSpec& section : deif::Sections()) {
    INFO(section.name);
    CHECK(root.Find(section.name) != nullptr);
    ++sections;
    for (const KeySpec* spec : section.keys) {
      INFO(spec->key);
      CHECK(Lookup(root, *spec) != nullptr);
    }
  }
  CHECK(root.entries.size() == sections);
}

TEST_CASE("ToYaml writes strings so that they read back exactly", "[config][schema]") {
  for (const std::string name : {"round: trip", "# not a comment", "  spaces  ", "quote \" and \\",
                                 "'single'", "yes", "123", "~", "[1, 2]", "Zürich ✓", "- dash"}) {
    INFO(name);
    Config c;
    c.scenario.name = name;
    c.network.discovery_server = "[::1]:11811";
    const Config back = ParseConfig(deif::ToYaml(c), "again");
    CHECK(back.scenario.name == name);
    CHECK(back.network.discovery_server == "[::1]:11811");
  }
}

TEST_CASE("VisitConfig gives every key once, in schema order, as one line of YAML", "[config][schema]") {
  Config c;
  c.faults.push_back({3, deif::FaultAction::kKill, 2});
  c.faults.push_back({4, deif::FaultAction::kRestartTarget, -1});
  c.network_sim.partitions.push_back({2, 5, {1, 3}, true});
  std::vector<std::string> keys;
  std::string faults;
  std::string partitions;
  deif::VisitConfig(c, [&](const KeySpec& spec, const std::string& yaml) {
    keys.push_back(spec.key);
    CHECK(yaml.find('\n') == std::string::npos);
    if (spec.key == "faults") faults = yaml;
    if (spec.key == "network_sim.partitions") partitions = yaml;
  });
  REQUIRE(keys.size() == deif::Schema().size());
  for (std::size_t i = 0; i < keys.size(); ++i) CHECK(keys[i] == deif::Schema()[i].key);
  CHECK(faults == "[{step: 3, action: kill, agent: 2}, {step: 4, action: restart_target}]");
  CHECK(partitions == "[{from_step: 2, to_step: 5, group: [1, 3], with_target: true}]");
}

TEST_CASE("The reference YAML sets every key to its default", "[config][schema]") {
  const std::string text = deif::RenderReferenceYaml();
  CHECK(Fingerprint(ParseConfig(text, "reference")) == Fingerprint(Config{}));
  const deif::DocNode root = deif::ReadDocument(text, "reference");
  for (const KeySpec& spec : deif::Schema()) {
    INFO(spec.key);
    CHECK(Lookup(root, spec) != nullptr);
  }
}

TEST_CASE("docs/CONFIG.md's reference is the one the schema renders", "[config][schema]") {
  const std::string doc = ReadFile(SourcePath("docs/CONFIG.md"));
  const std::string begin = std::string(deif::kReferenceBeginMarker) + "\n";
  const std::string end = std::string("\n") + deif::kReferenceEndMarker;
  const std::size_t from = doc.find(begin);
  const std::size_t to = doc.find(end);
  REQUIRE(from != std::string::npos);
  REQUIRE(to != std::string::npos);
  REQUIRE(from < to);
  INFO("regenerate it: build/bin/deif_config --reference-md, between the markers");
  CHECK(doc.substr(from + begin.size(), to + 1 - from - begin.size()) ==
        deif::RenderMarkdownReference());
}

TEST_CASE("The Markdown reference has one table row per key", "[config][schema]") {
  const std::string md = deif::RenderMarkdownReference();
  for (const KeySpec& spec : deif::Schema()) {
    CHECK_THAT(md, Catch::Contains("| `" + spec.key + "` |"));
    for (const KeySpec& field : spec.fields) CHECK_THAT(md, Catch::Contains("| `" + field.key + "` |"));
  }
  for (const deif::SectionSpec& section : deif::Sections()) {
    CHECK_THAT(md, Catch::Contains("### `" + section.name + "`"));
  }
}

TEST_CASE("configs/default.yaml sets every key and restates no default", "[config][schema]") {
  const std::string path = SourcePath("configs/default.yaml");
  const std::string text = ReadFile(path);
  CHECK_NOTHROW(deif::LoadConfig(path));  // so every key in it is in the schema
  const deif::DocNode root = deif::ReadDocument(text, path);
  for (const KeySpec& spec : deif::Schema()) {
    INFO(spec.key);
    CHECK(Lookup(root, spec) != nullptr);
  }
  // The defaults, ranges and units live in the schema (docs/CONFIG.md); the file's comments
  // explain, they do not restate a default.
  std::istringstream lines(text);
  std::string line;
  int number = 0;
  while (std::getline(lines, line)) {
    ++number;
    INFO("configs/default.yaml:" << number << ": " << line);
    CHECK(line.find("default:") == std::string::npos);
    CHECK(line.find("default (") == std::string::npos);
  }
}

TEST_CASE("configs/default.yaml differs from the defaults only where it says why", "[config][schema]") {
  const Config file = deif::LoadConfig(SourcePath("configs/default.yaml"));
  std::vector<std::string> differ;
  std::map<std::string, std::string> defaults;
  deif::VisitConfig(Config{}, [&](const KeySpec& spec, const std::string& yaml) {
    defaults[spec.key] = yaml;
  });
  deif::VisitConfig(file, [&](const KeySpec& spec, const std::string& yaml) {
    if (defaults[spec.key] != yaml) differ.push_back(spec.key);
  });
  CHECK(differ == std::vector<std::string>{"filter.process_noise", "agents.initial_angles_rad"});
}
