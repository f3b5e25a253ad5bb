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

#include <optional>
#include <set>
#include <string>
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
  std::vector<int> Replaced() const;
  // Checks (Replaced) and returns the ports replaced since hold_s ago or longer, at every
  // check since: empty while none is lost. now_s: any steady clock, in seconds.
  std::vector<int> Lost(double now_s);
  const std::vector<int>& ports() const { return ports_; }

 private:
  std::vector<int> ports_;
  double hold_s_;
  std::string dir_;
  std::optional<double> replaced_since_;
};

}  // namespace deif::dds
