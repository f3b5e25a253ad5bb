// Whether this process still reads the shared-memory ports it listens on.
//
// A Fast DDS 2.9.1 shared-memory port is a segment /dev/shm/fastrtps_port<P> that its
// listening process maps, with a lock file (fastrtps_port<P>_el for a unicast port) that the
// listener holds. A peer that finds the port broken or takes it for a
// dead process's ("Zombie. Reset the port", "NOT Healthy ... Removed") removes the segment's
// name and creates a new segment under it. The listener keeps the old mapping: if Fast DDS
// does not move it to the new segment (it does when the old one was marked broken, not when
// it was reset as a zombie's), every peer that opens the port from then on writes where
// nobody reads, and the process never hears them (docs/FASTDDS_NOTES.md, "A port replaced
// under its listener"). This is seen from outside Fast DDS: the file named /dev/shm/...portP
// is no longer one this process maps (/proc/self/maps gives the inode of each mapping).
// No Fast DDS header: /proc and the file system only.
#pragma once

#include <array>
#include <cstdint>
#include <iterator>
#include <map>
#include <optional>
#include <set>
#include <string>
#include <utility>
#include <vector>

namespace deif::dds {

// The port number P of a unicast port's lock file fastrtps_port<P>_el in `dir` that a process
// holds open (a link of /proc/<pid>/fd, possibly ending in " (deleted)"); nullopt for any other
// file. Not the discovery multicast port (_sl, shared by every process): its announcements
// also travel over UDPv4 multicast, while a peer on the same host reaches a unicast port
// over shared memory only.
std::optional<int> ListenedPort(const std::string& fd_target, const std::string& dir);
// The inodes of the mappings of `path` in a /proc/<pid>/maps text (those of a removed file
// included: " (deleted)").
std::set<unsigned long> MappedInodes(const std::string& maps, const std::string& path);

class ShmPortWatch {
 public:
  // Watches `ports` in `dir`; a port counts as lost once it has been replaced for hold_s
  // without a break (Fast DDS moves a listener to the new segment by itself within a third
  // of its port check timeout when it can: that is not a loss).
  ShmPortWatch(std::vector<int> ports, double hold_s, std::string dir = "/dev/shm");
  // The unicast ports this process listens on now: the lock files of `dir` it holds open.
  static std::vector<int> ListenedPorts(const std::string& dir = "/dev/shm");
  // The watched ports whose file in `dir` is gone or is not a segment this process maps.
  // /proc/self/maps is read only when a port's file is not the one found mapped at the
  // check before (a peer replaces a port by making a new file under its name): at 64 agents
  // it has 330 lines, about 1.2 ms to read on a busy host, once a second in every process.
  std::vector<int> Replaced();
  // Checks (Replaced) and returns the ports replaced since hold_s ago or longer, at every
  // check since: empty while none is lost. now_s: any steady clock, in seconds.
  std::vector<int> Lost(double now_s);
  const std::vector<int>& ports() const { return ports_; }

 private:
  std::vector<int> ports_;
  double hold_s_;
  std::string dir_;
  std::optional<double> replaced_since_;
  std::map<int, unsigned long> mapped_;  // port -> inode of its file, found mapped at the last check
};

// Whether a process listens on unicast port P in `dir`: its listener holds the port's lock
// file fastrtps_port<P>_el (an exclusive flock) for as long as the port lives, and the kernel
// lets go of it when the process ends, however it ends (kill -9 included). A process that is
// frozen or starved keeps it. kAbsent: no such file (never made on this host, or removed by
// a peer that found it free). The probe takes a shared lock for a moment, never the file.
enum class PortListener { kHeld, kFree, kAbsent };
PortListener ListenerOf(int port, const std::string& dir = "/dev/shm");

// Tells when the process behind a peer participant on this host has ended, from its
// shared-memory ports' lock files rather than from its silence: a starved process is slow,
// one whose locks the kernel released is gone (docs/PROTOCOL.md, "A process that ended").
// Keyed by whatever names the participant.
template <typename Key>
class BasicEndedProcessWatch {
 public:
  explicit BasicEndedProcessWatch(std::string dir = "/dev/shm") : dir_(std::move(dir)) {}
  // The participants to watch now and the unicast ports each listens on; one missing from
  // `ports` is no longer watched (an ended one is never reported twice).
  void Watch(const std::map<Key, std::vector<int>>& ports);
  // Probes the watched ports; returns the participants found ended since the last call: a
  // port of it was held at some probe, and none was at two probes in a row (a listener that
  // makes its own port anew lets go of the lock for a moment). A participant whose first
  // port is held costs one probe.
  std::vector<Key> Check();
  // The same for the watched participants in `only` alone, ended after `looks` free probes
  // in a row (1: another process, which looked twice, already said so).
  std::vector<Key> Check(const std::set<Key>& only, int looks = 2);

 private:
  struct Watched {
    std::vector<int> ports;
    bool held = false;   // a port seen held at least once
    int free_checks = 0;  // probes in a row at which none was held
    bool ended = false;
  };
  std::string dir_;
  std::map<Key, Watched> watched_;
};
using EndedProcessWatch = BasicEndedProcessWatch<std::array<std::uint8_t, 16>>;

template <typename Key>
void BasicEndedProcessWatch<Key>::Watch(const std::map<Key, std::vector<int>>& ports) {
  for (auto it = watched_.begin(); it != watched_.end();) {
    it = ports.count(it->first) == 0 ? watched_.erase(it) : std::next(it);
  }
  for (const auto& [key, list] : ports) {
    if (list.empty()) continue;
    Watched& w = watched_[key];
    if (w.ports != list) w = Watched{list};
  }
}

template <typename Key>
std::vector<Key> BasicEndedProcessWatch<Key>::Check() {
  std::set<Key> all;
  for (const auto& entry : watched_) all.insert(entry.first);
  return Check(all);
}

template <typename Key>
std::vector<Key> BasicEndedProcessWatch<Key>::Check(const std::set<Key>& only, int looks) {
  std::vector<Key> ended;
  for (auto& [key, w] : watched_) {
    if (w.ended || only.count(key) == 0) continue;
    bool held = false;  // one port held is enough: the process lives (one probe, mostly)
    for (int port : w.ports) {
      held = ListenerOf(port, dir_) == PortListener::kHeld;
      if (held) break;
    }
    w.held = w.held || held;
    w.free_checks = held ? 0 : w.free_checks + 1;
    if (w.held && w.free_checks >= looks) {
      w.ended = true;
      ended.push_back(key);
    }
  }
  return ended;
}

}  // namespace deif::dds
