#include "common/protocol/lapse_filter.hpp"

#include <algorithm>
#include <utility>

namespace deif::protocol {

template <typename Key>
std::optional<bool> BasicLapseFilter<Key>::Report(const Key& writer, bool alive, double now_s,
                                                  double grace_s) {
  if (alive) {
    if (held_.erase(writer) > 0) {
      ++ignored_;
      return std::nullopt;  // back within the grace: it was never lost
    }
    return true;
  }
  const double due_s = std::max(now_s + grace_s, hold_until_s_);
  if (due_s <= now_s) return false;
  held_.emplace(writer, due_s);  // a second report keeps the first due time
  return std::nullopt;
}

template <typename Key>
void BasicLapseFilter<Key>::HoldUntil(double until_s) {
  hold_until_s_ = std::max(hold_until_s_, until_s);
  for (auto& entry : held_) entry.second = std::max(entry.second, hold_until_s_);
}

template <typename Key>
std::vector<Key> BasicLapseFilter<Key>::Due(double now_s) {
  std::vector<std::pair<double, Key>> due;
  for (auto it = held_.begin(); it != held_.end();) {
    if (it->second <= now_s) {
      due.emplace_back(it->second, it->first);
      it = held_.erase(it);
    } else {
      ++it;
    }
  }
  std::sort(due.begin(), due.end());
  std::vector<Key> out;
  out.reserve(due.size());
  for (auto& d : due) out.push_back(d.second);
  return out;
}

template <typename Key>
std::optional<double> BasicLapseFilter<Key>::NextDue() const {
  std::optional<double> t;
  for (const auto& [writer, due_s] : held_) t = t ? std::min(*t, due_s) : due_s;
  return t;
}

template class BasicLapseFilter<SenderKey>;
template class BasicLapseFilter<AgentId>;

}  // namespace deif::protocol
