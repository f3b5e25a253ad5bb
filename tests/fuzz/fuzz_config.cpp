// libFuzzer harness of the config parser (docs/TESTING.md, "Fuzzing").
//
// The input is a config text; NUL bytes split off `--set` overrides after it (a config file
// never holds one). What must hold for every input:
// - ParseConfig returns or throws ConfigError: no other exception, no crash, no hang, no
//   sanitizer report;
// - a refusal is one line (the executables print it as their one line on stderr) that
//   starts with the file it blames;
// - an accepted config written back by ToYaml reads back to the same config
//   (common/config/config.hpp).
#include <cstddef>
#include <cstdint>
#include <exception>
#include <string>
#include <vector>

#include "common/config/config.hpp"
#include "tests/fuzz/fuzz_input.hpp"

namespace {

constexpr std::size_t kMaxOverrides = 8;

void CheckRefusal(const deif::ConfigError& e) {
  const std::string what = e.what();
  if (what.find_first_of("\n\r") != std::string::npos) {
    deif::fuzz::Violation("a refusal of more than one line: " + what);
  }
  bool plain_file = true;  // no control character (what() shows those escaped)
  for (const char ch : e.file()) plain_file = plain_file && static_cast<unsigned char>(ch) >= 0x20 && ch != 0x7F;
  if (plain_file && !e.file().empty() && what.rfind(e.file(), 0) != 0) {
    deif::fuzz::Violation("a refusal that does not start with its file '" + e.file() + "': " + what);
  }
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  const std::string input(reinterpret_cast<const char*>(data), size);
  std::vector<std::string> parts;
  std::size_t start = 0;
  for (;;) {
    const std::size_t nul = input.find('\0', start);
    parts.push_back(input.substr(start, nul == std::string::npos ? std::string::npos : nul - start));
    if (nul == std::string::npos) break;
    start = nul + 1;
  }
  const std::string text = parts.front();
  std::vector<std::string> overrides(parts.begin() + 1, parts.end());
  if (overrides.size() > kMaxOverrides) overrides.resize(kMaxOverrides);

  deif::Config config;
  try {
    config = deif::ParseConfig(text, "fuzz", overrides);
  } catch (const deif::ConfigError& e) {
    CheckRefusal(e);
    return 0;
  } catch (const std::exception& e) {
    deif::fuzz::Violation(std::string("ParseConfig threw something else than ConfigError: ") + e.what());
  } catch (...) {
    deif::fuzz::Violation("ParseConfig threw something else than ConfigError");
  }

  const std::string yaml = deif::ToYaml(config);
  std::string again;
  try {
    again = deif::ToYaml(deif::ParseConfig(yaml, "fuzz-roundtrip"));
  } catch (const std::exception& e) {
    deif::fuzz::Violation(std::string("ToYaml of an accepted config is refused: ") + e.what() +
                          "\n--- ToYaml:\n" + yaml);
  }
  if (again != yaml) {
    deif::fuzz::Violation("ToYaml does not read back to the same config\n--- first:\n" + yaml +
                          "\n--- read back:\n" + again);
  }
  return 0;
}
