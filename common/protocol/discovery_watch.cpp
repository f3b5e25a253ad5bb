#include "common/protocol/discovery_watch.hpp"

namespace deif::protocol {

bool DiscoveryWatch::Due(double now_s) {
  if (given_up_ || now_s < next_check_s_) return false;
  next_check_s_ = now_s + kCheckPeriodS;
  return true;
}

bool DiscoveryWatch::Stalled(int expected, int matched, std::uint64_t heard, double now_s) {
  if (expected != expected_ || matched != matched_ || heard != heard_) {
    expected_ = expected;
    matched_ = matched;
    heard_ = heard;
    since_s_ = now_s;
  }
  return matched < expected && now_s - since_s_ >= patience_s_;
}

bool SilenceWatch::Forgotten(double now_s, double patience_s, std::optional<double> listed_since_s) {
  if (given_up_ || heard_s_ < 0.0 || said_for_s_ == heard_s_ || !listed_since_s) return false;
  if (*listed_since_s <= heard_s_ || now_s - *listed_since_s <= patience_s) return false;
  said_for_s_ = heard_s_;
  return true;
}

}  // namespace deif::protocol
