// The command-line options every DDS executable shares, and the config they select.
#pragma once

#include <cstdint>
#include <optional>
#include <string>

#include <CLI/CLI.hpp>

#include "common/config/config.hpp"

namespace deif::dds {

struct ProcessOptions {
  std::string config_path;
  std::string log_dir;
  std::string out_dir;
  std::optional<int> domain;
  std::optional<std::uint64_t> seed;
};

// Adds --config, --log-dir, --domain, --out and --seed. log_name is the process's logger
// name (the log file is <log-dir>/<log_name>.log); out_what says what --out receives.
void AddProcessOptions(CLI::App& cli, ProcessOptions& options, const std::string& log_name,
                       const std::string& out_what);

// Loads the config and applies --domain and --seed. Throws ConfigError naming the file or
// option, the key and the reason.
Config LoadProcessConfig(const ProcessOptions& options);

// Prints "<program>: error: <what>" on stderr and returns code.
int FailWith(const char* program, int code, const std::string& what);

}  // namespace deif::dds
