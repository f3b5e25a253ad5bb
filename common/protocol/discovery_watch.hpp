// Endpoint discovery that stops short (docs/FASTDDS_NOTES.md, "Endpoint discovery that stops
// short"): a process sees its peers' participants but never matches some of their endpoints.
// Fast DDS 2.9.1 as a Discovery Server client does this now and then when many clients start
// at once, and does not repair it: the peers' writers stay unknown to this process for the
// whole run. Matching still under way changes as it goes; matching that stopped short stays
// the same. Only a new participant learns the endpoints again.
#pragma once

#include <cstdint>

namespace deif::protocol {

class DiscoveryWatch {
 public:
  // patience_s: how long matching may stay short of what is up, unchanged, before it counts
  // as stopped.
  explicit DiscoveryWatch(double patience_s) : patience_s_(patience_s) {}

  // Whether to look at the transport now: at most every kCheckPeriodS (counting the matches
  // costs), and never again once it GaveUp.
  bool Due(double now_s);
  // A process that may not start again any more goes on as it is: no more checks.
  void GiveUp() { given_up_ = true; }
  double patience_s() const { return patience_s_; }

  // What the transport reports at now_s: `expected` endpoints of the participants that are
  // up, `matched` of them matched, and `heard`, how many endpoints it has discovered so far
  // anywhere (it grows while a peer is still creating its endpoints: a target making one
  // writer of ranges per agent under a storm of discovery took 105 s for 128). True once
  // matched < expected and none of the three has changed for patience_s.
  bool Stalled(int expected, int matched, std::uint64_t heard, double now_s);

 private:
  double patience_s_;
  int expected_ = -1;
  int matched_ = -1;
  std::uint64_t heard_ = 0;
  double since_s_ = 0.0;  // when the numbers last changed
  double next_check_s_ = 0.0;
  bool given_up_ = false;
  static constexpr double kCheckPeriodS = 0.5;
};

}  // namespace deif::protocol
