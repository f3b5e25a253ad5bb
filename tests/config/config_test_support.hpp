// Helpers shared by the config tests (include after catch.hpp).
#pragma once

#include <catch2/catch.hpp>
#include <unistd.h>

#include <filesystem>
#include <fstream>
#include <string>
#include <vector>

#include "common/config/config.hpp"
#include "common/config/schema.hpp"
#include "common/config/schema_access.hpp"

namespace deif_test {

// Every key's effective value as VisitConfig writes it, plus the derived filter dt: two
// configs with the same fingerprint are identical (doubles are written exactly).
inline std::string Fingerprint(const deif::Config& config) {
  std::string out;
  deif::VisitConfig(config, [&](const deif::KeySpec& spec, const std::string& yaml) {
    out += spec.key + ": " + yaml + "\n";
  });
  out += "filter.motion_model.dt_s: " + deif::FormatNumber(config.filter.motion_model.dt_s) + "\n";
  return out;
}

// The ConfigError that parsing yaml (as bad.yaml, with the overrides) throws; fails the test
// when it parses.
inline deif::ConfigError ErrorOf(const std::string& yaml,
                                 const std::vector<std::string>& overrides = {}) {
  try {
    deif::ParseConfig(yaml, "bad.yaml", overrides);
  } catch (const deif::ConfigError& e) {
    return e;
  }
  FAIL("accepted: " << yaml);
  return deif::ConfigError("", "", 0, "");  // not reached: FAIL throws
}

// Checks a ConfigError's file, line, key and reason fragment, and the message's format.
inline void CheckError(const deif::ConfigError& e, const std::string& file, int line,
                       const std::string& key, const std::string& fragment) {
  const std::string message = e.what();
  INFO(message);
  CHECK(e.file() == file);
  CHECK(e.line() == line);
  CHECK(e.key() == key);
  CHECK_THAT(message, Catch::Contains(fragment));
  std::string prefix = file + (line > 0 ? ":" + std::to_string(line) : "") + ": ";
  if (!key.empty()) prefix += "key '" + key + "': ";
  CHECK_THAT(message, Catch::StartsWith(prefix));
}

// Parsing yaml fails at bad.yaml:line, naming key, with the fragment in the reason.
inline void ExpectError(const std::string& yaml, int line, const std::string& key,
                        const std::string& fragment) {
  CheckError(ErrorOf(yaml), "bad.yaml", line, key, fragment);
}

inline std::string SourcePath(const std::string& relative) {
  return (std::filesystem::path(DEIF_SOURCE_DIR) / relative).string();
}

inline std::string ReadFile(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  return std::string(std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>());
}

// A file in a fresh temporary directory, removed with it.
class TempFile {
 public:
  TempFile(const std::string& name, const std::string& content)
      : dir_(std::filesystem::temp_directory_path() /
             ("deif_config_test_" + std::to_string(::getpid()) + "_" + name)) {
    std::filesystem::create_directories(dir_);
    std::ofstream(path(), std::ios::binary) << content;
  }
  ~TempFile() {
    std::error_code ignored;
    std::filesystem::remove_all(dir_, ignored);
  }
  TempFile(const TempFile&) = delete;
  TempFile& operator=(const TempFile&) = delete;
  std::string path() const { return (dir_ / "config.yaml").string(); }
  std::string dir() const { return dir_.string(); }

 private:
  std::filesystem::path dir_;
};

}  // namespace deif_test
