#include "dds/delivery.hpp"

#include <chrono>
#include <type_traits>
#include <variant>

#include <nlohmann/json.hpp>
#include <spdlog/fmt/fmt.h>

namespace deif::dds {

namespace {

template <typename Msg>
const char* KindOf(const Msg& msg) {
  if constexpr (std::is_same_v<Msg, protocol::RangeMsg>) return "range";
  if constexpr (std::is_same_v<Msg, protocol::ContributionMsg>) return "contribution";
  if constexpr (std::is_same_v<Msg, protocol::StateMsg>) return "state";
  if constexpr (std::is_same_v<Msg, protocol::TruthMsg>) return "truth";
  if constexpr (std::is_same_v<Msg, protocol::BatchMsg>) return msg.down ? "relay_down" : "relay_up";
  return nullptr;
}

}  // namespace

void DeliveryDelays::Record(const std::vector<Event>& events) {
  if (events.empty()) return;
  const double now_unix_s =
      std::chrono::duration<double>(std::chrono::system_clock::now().time_since_epoch()).count();
  for (const Event& event : events) {
    std::visit(
        [&](const auto& e) {
          using E = std::decay_t<decltype(e)>;
          if constexpr (!std::is_same_v<E, LivelinessChange>) {
            if (const char* kind = KindOf(e.msg)) kinds_[kind].Add(now_unix_s - e.written_unix_s);
          }
        },
        event);
  }
}

nlohmann::json DeliveryDelays::ToJson() const {
  nlohmann::json out = nlohmann::json::object();
  for (const auto& [kind, h] : kinds_) {
    out[kind] = {{"count", h.count()},
                 {"p50", 1e3 * h.Quantile(0.5)},
                 {"p90", 1e3 * h.Quantile(0.9)},
                 {"p99", 1e3 * h.Quantile(0.99)},
                 {"max", 1e3 * h.max_s()}};
  }
  return out;
}

std::string DeliveryDelays::Summary() const {
  std::string text;
  for (const auto& [kind, h] : kinds_) {
    text += fmt::format("{}{} {:.1f} / {:.1f}", text.empty() ? "" : ", ", kind, 1e3 * h.Quantile(0.5),
                        1e3 * h.Quantile(0.99));
  }
  return text;
}

}  // namespace deif::dds
