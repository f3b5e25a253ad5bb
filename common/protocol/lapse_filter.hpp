// Slow is not gone: a liveliness lapse reported by DDS counts as a loss only once the writer
// has stayed silent for network.liveliness_grace_s more (docs/PROTOCOL.md, "Slow is not
// gone"). A process starved of CPU fires its lease timers before it reads the assertions
// queued meanwhile, and a burst of lost packets can silence a live writer for a lease; both
// come back within moments, and excluding such a peer would change what is fused.
#pragma once

#include <map>
#include <optional>
#include <vector>

#include "common/protocol/messages.hpp"

namespace deif::protocol {

// What a loss line says when the transport saw the peer's process end instead of a lapse
// (docs/PROTOCOL.md, "A process that ended").
inline constexpr const char* kProcessEnded = "its process ended: the locks of its shared-memory ports were released";

// Keyed by whatever names a writer: its key (a peer's or the target's writer), or the agent
// whose writer it is (a parent's relay writer, TreeExchange).
template <typename Key>
class BasicLapseFilter {
 public:
  explicit BasicLapseFilter(double grace_s) : grace_s_(grace_s) {}

  // A liveliness change as DDS reported it. Returns the change to act on now: a loss is
  // held for the grace (nullopt); a return within the grace cancels it (nullopt).
  std::optional<bool> Report(const Key& writer, bool alive, double now_s) {
    return Report(writer, alive, now_s, grace_s_);
  }
  // The same, with a grace of its own for this writer's loss.
  std::optional<bool> Report(const Key& writer, bool alive, double now_s, double grace_s);
  // The held losses whose grace is over, oldest first: act on each as a loss.
  std::vector<Key> Due(double now_s);
  // Ends the grace of `writer`'s held loss at once (another writer took its identity, so it
  // is gone). True if one was held: act on it as a loss.
  bool Confirm(const Key& writer) { return held_.erase(writer) > 0; }
  // When the next held loss is due (nullopt: none held).
  std::optional<double> NextDue() const;
  // This process itself was away (frozen, starved) until now: its peers' writers lapse in
  // its view because it read nothing, not because they are gone. Every loss held or reported
  // before `until_s` is due no sooner than then.
  void HoldUntil(double until_s);
  // Lapses that ended within the grace (never acted on).
  long ignored() const { return ignored_; }

 private:
  double grace_s_;
  double hold_until_s_ = -1.0;
  std::map<Key, double> held_;  // writer -> when its loss is due
  long ignored_ = 0;
};

using LapseFilter = BasicLapseFilter<SenderKey>;
extern template class BasicLapseFilter<SenderKey>;
extern template class BasicLapseFilter<AgentId>;

}  // namespace deif::protocol
