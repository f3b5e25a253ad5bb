// Slow is not gone: a liveliness lapse reported by DDS counts as a loss only once the writer
// has stayed silent for network.liveliness_grace_s more (docs/PROTOCOL.md, "Slow is not
// gone"). A process starved of CPU fires its lease timers before it reads the assertions
// queued meanwhile, and a burst of lost packets can silence a live writer for a lease; both
// come back within moments, and excluding such a peer would change what is fused.
#pragma once

#include <map>
#include <optional>
#include <string>
#include <utility>
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
  // max_grace_s: how far the grace may grow after losses that were undone (below); at most
  // grace_s, it never grows.
  explicit BasicLapseFilter(double grace_s, double max_grace_s = 0.0)
      : grace_s_(grace_s), max_grace_s_(max_grace_s) {}

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

  // A loss that is undone: a writer whose lapse outlasted its grace (Due) and that is back
  // within kUndoneWithin x that grace (at least kUndoneWithinLeastS). Its process did not
  // die: the network lost its renewals, several in a row, which a lossy link does for some
  // pair of agents every few seconds. Each one doubles the grace of every writer from then
  // on, up to kMaxFactor times and to max_grace_s; kQuietS without one halves it again
  // (docs/PROTOCOL.md, "Losses that are undone").
  static constexpr double kMaxFactor = 8.0;
  static constexpr double kUndoneWithin = 4.0;
  static constexpr double kUndoneWithinLeastS = 1.0;
  static constexpr double kQuietS = 60.0;
  // How many times its grace a writer's lapse is now held (1, 2, 4 or 8; the cap
  // max_grace_s can make the grace itself shorter).
  double grace_factor() const { return factor_; }
  // Whether the factor grew since the last call (for the caller's one log line per doubling).
  bool TakeGrown() { return std::exchange(grown_, false); }
  long losses_undone() const { return undone_; }
  // A loss found undone by other means (the writer's owner was heard of meanwhile): as a
  // return within the window.
  void NoteUndone(double now_s);
  // The grace a writer whose own grace is grace_s has now.
  double GraceNow(double grace_s) const;

 private:
  struct Held {
    double due_s;
    double grace_s;  // as held (for the window in which its loss counts as undone)
  };
  struct Lost {
    double at_s;
    double window_s;
  };
  void Relax(double now_s);

  double grace_s_;
  double max_grace_s_;
  double hold_until_s_ = -1.0;
  std::map<Key, Held> held_;  // writer -> when its loss is due
  std::map<Key, Lost> lost_;  // writers whose loss came due, while a return would undo it
  long ignored_ = 0;
  double factor_ = 1.0;
  bool grown_ = false;
  double factor_since_s_ = 0.0;  // when the factor last changed
  long undone_ = 0;
};

using LapseFilter = BasicLapseFilter<SenderKey>;
extern template class BasicLapseFilter<SenderKey>;
extern template class BasicLapseFilter<AgentId>;

// What a process logs when a loss of `who` was undone and its grace grew to `factor` x
// (`grace_s` now for `who`'s kind of writer).
std::string GraceGrownLine(const std::string& who, double factor, double grace_s);

}  // namespace deif::protocol
