#include "dds/counters.hpp"

#include <atomic>
#include <filesystem>
#include <fstream>

namespace deif::dds {

nlohmann::json EarlierCounters(const std::string& path, spdlog::logger& log) {
  if (!std::filesystem::exists(path)) return nlohmann::json::object();
  std::ifstream in(path);
  nlohmann::json earlier = nlohmann::json::parse(in, nullptr, /*allow_exceptions=*/false);
  if (!earlier.is_object()) {
    log.warn("{}: not a JSON object; the counts of the earlier process are lost", path);
    return nlohmann::json::object();
  }
  return earlier;
}

nlohmann::json AddEarlierCounters(const nlohmann::json& earlier, nlohmann::json now) {
  if (!earlier.is_object() || !now.is_object()) return now;
  for (auto& [key, value] : now.items()) {
    const auto before = earlier.find(key);
    if (before == earlier.end()) continue;
    if (value.is_number_integer() && before->is_number_integer()) {
      value = value.get<std::int64_t>() + before->get<std::int64_t>();
    } else if (key == "by_reason" && value.is_object() && before->is_object()) {
      for (const auto& [reason, count] : before->items()) {
        if (!count.is_number_integer()) continue;
        const std::int64_t here = value.contains(reason) && value[reason].is_number_integer()
                                      ? value[reason].get<std::int64_t>()
                                      : 0;
        value[reason] = here + count.get<std::int64_t>();
      }
    }
  }
  return now;
}

void WriteCounters(const std::string& path, const nlohmann::json& counters, spdlog::logger& log) {
  // Written once a second: a folder that cannot be written is said once, not every second.
  static std::atomic<bool> said{false};
  const std::string temporary = path + ".part";
  {
    std::ofstream out(temporary, std::ios::trunc);
    out << counters.dump(2) << "\n";
    out.flush();
    if (!out) {
      if (!said.exchange(true)) log.warn("{}: cannot write the counters (said once)", temporary);
      return;
    }
  }
  std::error_code error;
  std::filesystem::rename(temporary, path, error);
  if (error && !said.exchange(true)) {
    log.warn("{}: cannot rename it to {}: {} (said once)", temporary, path, error.message());
  }
}

}  // namespace deif::dds
