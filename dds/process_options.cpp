#include "dds/process_options.hpp"

#include <cstdio>

namespace deif::dds {

void AddProcessOptions(CLI::App& cli, ProcessOptions& options, const std::string& log_name,
                       const std::string& out_what) {
  cli.add_option("--config", options.config_path, "Scenario YAML file (see configs/default.yaml)")
      ->required();
  cli.add_option("--log-dir", options.log_dir, "Also write the log to DIR/" + log_name + ".log")
      ->check(CLI::ExistingDirectory);
  cli.add_option("--domain", options.domain, "DDS domain id (0..232); overrides network.domain_id");
  cli.add_option("--out", options.out_dir, "Run folder for " + out_what + " (none written if omitted)")
      ->check(CLI::ExistingDirectory);
  cli.add_option("--seed", options.seed, "Overrides scenario.seed");
}

Config LoadProcessConfig(const ProcessOptions& options) {
  Config config = LoadConfig(options.config_path);
  if (options.domain) {
    if (*options.domain < 0 || *options.domain > 232) {  // Fast DDS calls exit() above 232
      throw ConfigError("--domain", "network.domain_id", 0,
                        "must be in 0..232 (got " + std::to_string(*options.domain) + ")");
    }
    config.network.domain_id = *options.domain;
  }
  if (options.seed) config.scenario.seed = *options.seed;
  return config;
}

int FailWith(const char* program, int code, const std::string& what) {
  std::fprintf(stderr, "%s: error: %s\n", program, what.c_str());
  return code;
}

}  // namespace deif::dds
