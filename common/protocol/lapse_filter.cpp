#include "common/protocol/lapse_filter.hpp"

#include <algorithm>
#include <utility>

namespace deif::protocol {

std::optional<bool> LapseFilter::Report(const SenderKey& writer, bool alive, double now_s) {
  if (alive) {
    if (held_.erase(writer) > 0) {
      ++ignored_;
      return std::nullopt;  // back within the grace: it was never lost
    }
    return true;
  }
  const double due_s = std::max(now_s + grace_s_, hold_until_s_);
  if (due_s <= now_s) return false;
  held_.emplace(writer, due_s);  // a second report keeps the first due time
  return std::nullopt;
}

void LapseFilter::HoldUntil(double until_s) {
  hold_until_s_ = std::max(hold_until_s_, until_s);
  for (auto& entry : held_) entry.second = std::max(entry.second, hold_until_s_);
}

std::vector<SenderKey> LapseFilter::Due(double now_s) {
  std::vector<std::pair<double, SenderKey>> due;
  for (auto it = held_.begin(); it != held_.end();) {
    if (it->second <= now_s) {
      due.emplace_back(it->second, it->first);
      it = held_.erase(it);
    } else {
      ++it;
    }
  }
  std::sort(due.begin(), due.end());
  std::vector<SenderKey> out;
  out.reserve(due.size());
  for (auto& d : due) out.push_back(d.second);
  return out;
}

std::optional<double> LapseFilter::NextDue() const {
  std::optional<double> t;
  for (const auto& [writer, due_s] : held_) t = t ? std::min(*t, due_s) : due_s;
  return t;
}

}  // namespace deif::protocol
