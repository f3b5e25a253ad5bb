// Endpoint discovery that stops short (docs/FASTDDS_NOTES.md, "Endpoint discovery that stops
// short"): a process sees its peers' participants but never matches some of their endpoints.
// Fast DDS 2.9.1 as a Discovery Server client does this now and then when many clients start
// at once, and does not repair it: the peers' writers stay unknown to this process for the
// whole run. Matching still under way changes as it goes; matching that stopped short stays
// the same. Only a new participant learns the endpoints again.
#pragma once

#include <cstdint>
#include <optional>

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

// A Discovery Server client the server took for gone while this client still lists the server
// (docs/FASTDDS_NOTES.md, "Forgotten by the server"): the server told every other process to
// drop it, so nobody sends it anything, while its own view still lists them all (a client
// leaves the other clients' leases to the server). Fast DDS 2.9.1 did not discover it again
// for as long as the runs lasted; a new participant is discovered afresh. From the client's
// side that silence looks like a host cut off, but for one thing: the client drops the server
// when the server's lease runs out (the server no longer sends to it), and finds it again at
// once, and still nothing comes. A host cut off finds the server again only at the heal, and
// its peers soon after.
class SilenceWatch {
 public:
  // A sample came from the network at now_s.
  void Heard(double now_s) { heard_s_ = now_s; }
  // True when the server was found again after the last sample (listed_since_s, since when
  // it and the processes this one should hear from are listed up; nullopt if they are not),
  // and nothing came for more than patience_s after that. Never before the first sample, nor
  // twice for one silence, nor once GaveUp.
  bool Forgotten(double now_s, double patience_s, std::optional<double> listed_since_s);
  void GiveUp() { given_up_ = true; }
  double silent_s(double now_s) const { return heard_s_ < 0.0 ? 0.0 : now_s - heard_s_; }

 private:
  double heard_s_ = -1.0;
  double said_for_s_ = -1.0;  // the sample whose silence Forgotten already reported
  bool given_up_ = false;
};

}  // namespace deif::protocol
