#include "common/protocol/lapse_filter.hpp"

#include <algorithm>
#include <cstdio>
#include <iterator>
#include <utility>

namespace deif::protocol {

template <typename Key>
double BasicLapseFilter<Key>::GraceNow(double grace_s) const {
  return std::min(grace_s * factor_, std::max(grace_s, max_grace_s_));
}

template <typename Key>
void BasicLapseFilter<Key>::Relax(double now_s) {
  while (factor_ > 1.0 && now_s - factor_since_s_ >= kQuietS) {
    factor_ /= 2.0;
    factor_since_s_ += kQuietS;
  }
}

template <typename Key>
std::optional<bool> BasicLapseFilter<Key>::Report(const Key& writer, bool alive, double now_s,
                                                  double grace_s) {
  Relax(now_s);
  if (alive) {
    if (held_.erase(writer) > 0) {
      ++ignored_;
      return std::nullopt;  // back within the grace: it was never lost
    }
    if (auto lost = lost_.find(writer); lost != lost_.end()) {
      if (now_s - lost->second.at_s <= lost->second.window_s) NoteUndone(now_s);
      lost_.erase(lost);
    }
    return true;
  }
  const double held_grace_s = GraceNow(grace_s);
  const double due_s = std::max(now_s + held_grace_s, hold_until_s_);
  if (due_s <= now_s) return false;
  held_.emplace(writer, Held{due_s, held_grace_s});  // a second report keeps the first due time
  return std::nullopt;
}

template <typename Key>
void BasicLapseFilter<Key>::NoteUndone(double now_s) {
  Relax(now_s);
  ++undone_;
  grown_ = grown_ || factor_ < kMaxFactor;
  factor_ = std::min(kMaxFactor, factor_ * 2.0);
  factor_since_s_ = now_s;  // quiet counts from the last one
}

template <typename Key>
void BasicLapseFilter<Key>::HoldUntil(double until_s) {
  hold_until_s_ = std::max(hold_until_s_, until_s);
  for (auto& entry : held_) entry.second.due_s = std::max(entry.second.due_s, hold_until_s_);
}

template <typename Key>
std::vector<Key> BasicLapseFilter<Key>::Due(double now_s) {
  Relax(now_s);
  for (auto it = lost_.begin(); it != lost_.end();) {
    it = now_s - it->second.at_s > it->second.window_s ? lost_.erase(it) : std::next(it);
  }
  std::vector<std::pair<double, Key>> due;
  for (auto it = held_.begin(); it != held_.end();) {
    if (it->second.due_s <= now_s) {
      due.emplace_back(it->second.due_s, it->first);
      lost_[it->first] = Lost{now_s, std::max(kUndoneWithinLeastS, kUndoneWithin * it->second.grace_s)};
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
  for (const auto& [writer, held] : held_) t = t ? std::min(*t, held.due_s) : held.due_s;
  return t;
}

std::string GraceGrownLine(const std::string& who, double factor, double grace_s) {
  char text[256];
  std::snprintf(text, sizeof text,
                "%s, taken for lost by its liveliness, is back: the network loses renewals, so a lapse is now "
                "held for %g x the grace (%.2f s) before it counts (docs/PROTOCOL.md, \"Losses that are undone\")",
                who.c_str(), factor, grace_s);
  return text;
}

template class BasicLapseFilter<SenderKey>;
template class BasicLapseFilter<AgentId>;

}  // namespace deif::protocol
