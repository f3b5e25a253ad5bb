// deif_config: the configuration schema on the command line.
//
//   deif_config --reference-md       the reference tables (docs/CONFIG.md's generated part)
//   deif_config --reference-yaml     every key at its default, commented
//   deif_config --config FILE [--set key=value ...] --check
//   deif_config --config FILE [--set key=value ...] --print yaml|json
//
// Exit status: 0 ok, 2 bad configuration or command line (one line on stderr), 1 any other
// error.
#include <CLI/CLI.hpp>
#include <nlohmann/json.hpp>

#include <cstdio>
#include <exception>
#include <iostream>
#include <string>
#include <vector>

#include "common/config/config.hpp"
#include "common/config/document.hpp"
#include "common/config/reference.hpp"
#include "common/config/schema.hpp"

namespace {

constexpr int kExitOk = 0;
constexpr int kExitRuntimeError = 1;
constexpr int kExitConfigError = 2;

struct Options {
  bool reference_md = false;
  bool reference_yaml = false;
  std::string config_path;
  std::vector<std::string> overrides;
  bool check = false;
  std::string print;
};

using Json = nlohmann::ordered_json;  // keys in schema order

Json Number(const std::string& text) {
  if (text == ".inf" || text == "-.inf" || text == ".nan") return text;  // not in JSON
  return std::stod(text);
}

// One value, written by VisitConfig as YAML, as JSON of the key's type.
Json ToJson(const deif::KeySpec& spec, const deif::DocNode& node) {
  using deif::KeyType;
  switch (spec.type) {
    case KeyType::kDouble:
      return Number(node.text);
    case KeyType::kInt:
    case KeyType::kInt64:
      return std::stoll(node.text);
    case KeyType::kUint64:
      return std::stoull(node.text);
    case KeyType::kBool:
      return node.text == "true";
    case KeyType::kString:
    case KeyType::kEnum:
      return node.text;
    case KeyType::kVector2:
    case KeyType::kDoubleList: {
      Json list = Json::array();
      for (const deif::DocNode& item : node.items) list.push_back(Number(item.text));
      return list;
    }
    case KeyType::kIntList: {
      Json list = Json::array();
      for (const deif::DocNode& item : node.items) list.push_back(std::stoll(item.text));
      return list;
    }
    case KeyType::kRecordList: {
      Json list = Json::array();
      for (const deif::DocNode& item : node.items) {
        Json record = Json::object();
        for (const deif::DocEntry& entry : item.entries) {
          const deif::KeySpec* field = deif::FindKey(spec.key + "[]." + entry.key);
          if (field != nullptr) record[entry.key] = ToJson(*field, entry.value);
        }
        list.push_back(record);
      }
      return list;
    }
  }
  return nullptr;
}

Json ConfigJson(const deif::Config& config) {
  Json out = Json::object();
  deif::VisitConfig(config, [&](const deif::KeySpec& spec, const std::string& yaml) {
    const Json value = ToJson(spec, deif::ReadDocument(yaml, spec.key));
    const std::vector<std::string> path = deif::KeyPath(spec);  // nested: network.security
    Json* node = &out;
    for (std::size_t i = 0; i + 1 < path.size(); ++i) node = &(*node)[path[i]];
    (*node)[path.back()] = value;
  });
  return out;
}

int Run(const Options& options) {
  if (options.reference_md) {
    std::cout << deif::RenderMarkdownReference();
    return kExitOk;
  }
  if (options.reference_yaml) {
    std::cout << deif::RenderReferenceYaml();
    return kExitOk;
  }
  deif::Config config;
  try {
    config = deif::LoadConfig(options.config_path, options.overrides);
  } catch (const deif::ConfigError& e) {
    std::fprintf(stderr, "deif_config: error: %s\n", e.what());
    return kExitConfigError;
  }
  if (options.print == "yaml") std::cout << deif::ToYaml(config);
  if (options.print == "json") std::cout << ConfigJson(config).dump(2) << "\n";
  return kExitOk;
}

}  // namespace

int main(int argc, char** argv) {
  CLI::App app{"deif_config: check, print and document the scenario configuration"};
  Options options;
  auto* md = app.add_flag("--reference-md", options.reference_md,
                          "print the reference tables (the generated part of docs/CONFIG.md)");
  auto* yaml = app.add_flag("--reference-yaml", options.reference_yaml,
                            "print every key at its default as commented YAML");
  auto* config = app.add_option("--config", options.config_path, "scenario YAML file");
  app.add_option("--set", options.overrides,
                 "override a key: dotted.key=YAML value (repeatable), e.g. agents.count=6")
      ->needs(config);
  auto* check = app.add_flag("--check", options.check,
                             "only check the config (exit 0 if good, 2 with the reason if not)")
                    ->needs(config);
  auto* print = app.add_option("--print", options.print,
                               "print the effective config (every key) as yaml or json")
                    ->check(CLI::IsMember({"yaml", "json"}))
                    ->needs(config);
  md->excludes(yaml)->excludes(config);
  yaml->excludes(config);
  check->excludes(print);
  try {
    app.parse(argc, argv);
    if (!options.reference_md && !options.reference_yaml && !options.check &&
        options.print.empty()) {
      throw CLI::ValidationError(
          "nothing to do: give --reference-md, --reference-yaml, or --config with --check "
          "or --print");
    }
  } catch (const CLI::CallForHelp& e) {
    return app.exit(e);
  } catch (const CLI::ParseError& e) {
    std::fprintf(stderr, "deif_config: error: %s\n", e.what());
    return kExitConfigError;
  }
  try {
    return Run(options);
  } catch (const std::exception& e) {
    std::fprintf(stderr, "deif_config: error: %s\n", e.what());
    return kExitRuntimeError;
  }
}
